import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from codeslam.geometry.quaternion import quat_slerp, quat_xyzw_to_rotmat, rotmat_to_quat_xyzw


def _random_quats(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return q / q.norm(dim=-1, keepdim=True)


def test_rotmat_is_rotation():
    R = quat_xyzw_to_rotmat(_random_quats(500))
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(R @ R.transpose(-1, -2), eye.expand_as(R), atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(500, dtype=torch.float64), atol=1e-12)


def test_round_trip_up_to_sign():
    q = _random_quats(1000, seed=1)
    q2 = rotmat_to_quat_xyzw(quat_xyzw_to_rotmat(q))
    sign = torch.sign((q * q2).sum(-1, keepdim=True))
    assert torch.allclose(q, sign * q2, atol=1e-12)
    assert (q2[:, 3] >= 0).all()


def test_known_rotation_about_z():
    # 90 degrees about z: x -> y
    q = torch.tensor([0.0, 0.0, 2**-0.5, 2**-0.5], dtype=torch.float64)
    R = quat_xyzw_to_rotmat(q)
    assert torch.allclose(R @ torch.tensor([1.0, 0, 0], dtype=torch.float64),
                          torch.tensor([0.0, 1, 0], dtype=torch.float64), atol=1e-12)


def test_near_180_degree_rotations():
    # trace close to -1 is where naive conversions break
    for axis in torch.eye(3, dtype=torch.float64):
        q = torch.cat([axis * torch.sin(torch.tensor(0.5 * (torch.pi - 1e-9))),
                       torch.cos(torch.tensor([0.5 * (torch.pi - 1e-9)], dtype=torch.float64))])
        R = quat_xyzw_to_rotmat(q)
        assert torch.allclose(quat_xyzw_to_rotmat(rotmat_to_quat_xyzw(R)), R, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(0, 10_000))
def test_slerp_endpoints_and_constant_speed(t, seed):
    q0, q1 = _random_quats(2, seed)
    assert torch.allclose(quat_slerp(q0, q1, torch.tensor(0.0, dtype=torch.float64)), q0, atol=1e-9)
    qt = quat_slerp(q0, q1, torch.tensor(t, dtype=torch.float64))
    # the angle from q0 grows linearly with t (on the short arc)
    q1s = q1 if (q0 * q1).sum() >= 0 else -q1
    total = 2 * torch.arccos((q0 * q1s).sum().abs().clamp(max=1))
    part = 2 * torch.arccos((q0 * qt).sum().abs().clamp(max=1))
    assert abs(float(part - t * total)) < 1e-6
