"""SO(3)/SE(3): group laws on random elements and every analytic Jacobian against autograd in float64."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.autograd.functional import jacobian

from codeslam.geometry.lie import (
    hat,
    se3_act,
    se3_act_jac_point,
    se3_act_jac_pose,
    se3_act_jac_pose_right,
    se3_adjoint,
    se3_compose,
    se3_exp,
    se3_exp_host,
    se3_inverse,
    se3_log,
    se3_log_host,
    so3_angle_host,
    so3_exp,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_log,
    vee,
)

F64 = torch.float64
EYE3 = torch.eye(3, dtype=F64)
# Angles that exercise every branch: 0, the Taylor branch, both sides of the series threshold, large, near pi.
ANGLES = [0.0, 1e-9, 5e-7, 1.01e-6, 1e-4, 0.05, 0.0999, 0.1001, 0.7, 2.0, math.pi - 1e-3, math.pi - 1e-7]


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _axes(n: int, seed: int) -> torch.Tensor:
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=_gen(seed), dtype=F64), dim=-1)


def _phis(seed: int = 0) -> torch.Tensor:
    """(len(ANGLES), 3) rotation vectors with the test angles about random axes."""
    return _axes(len(ANGLES), seed) * torch.tensor(ANGLES, dtype=F64)[:, None]


def _xis(n: int, seed: int) -> torch.Tensor:
    """(n, 6) random tangents with angles in [0, pi)."""
    g = _gen(seed)
    rho = torch.randn(n, 3, generator=g, dtype=F64)
    angle = torch.rand(n, 1, generator=g, dtype=F64) * (math.pi - 1e-3)
    return torch.cat([rho, _axes(n, seed + 1) * angle], dim=-1)


def _batched_jacobian(f, x: torch.Tensor) -> torch.Tensor:
    """f: (B, n) -> (B, m) acting row by row; returns (B, m, n) per-row Jacobians."""
    J = jacobian(f, x)  # (B, m, B, n)
    return torch.diagonal(J, dim1=0, dim2=2).permute(2, 0, 1)


# ------------------------------------------------------------------------------------------------- so(3)


def test_hat_is_cross_product_and_vee_inverts_it():
    w, x = torch.randn(2, 20, 3, generator=_gen(0), dtype=F64)
    assert torch.allclose((hat(w) @ x[..., None])[..., 0], torch.linalg.cross(w, x), atol=1e-14)
    assert torch.allclose(vee(hat(w)), w)
    assert torch.allclose(hat(w), -hat(w).transpose(-1, -2))


def test_so3_exp_is_a_rotation_and_matches_matrix_exp():
    phi = _phis()
    R = so3_exp(phi)
    assert torch.allclose(R @ R.transpose(-1, -2), EYE3.expand_as(R), atol=1e-13)
    assert torch.allclose(torch.linalg.det(R), torch.ones(len(ANGLES), dtype=F64), atol=1e-13)
    assert torch.allclose(R, torch.linalg.matrix_exp(hat(phi)), atol=1e-13)


def test_so3_log_inverts_exp_near_zero_and_pi():
    phi = _phis(1)
    back = so3_log(so3_exp(phi))
    assert torch.allclose(back, phi, atol=1e-12, rtol=0)
    # Exactly pi: the axis sign is ambiguous, the rotation is not.
    phi_pi = _axes(10, 2) * math.pi
    R = so3_exp(phi_pi)
    back = so3_log(R)
    assert torch.allclose(back.norm(dim=-1), torch.full((10,), math.pi, dtype=F64), atol=1e-12)
    assert torch.allclose(so3_exp(back), R, atol=1e-12)


def test_so3_left_jacobian_is_the_derivative_of_exp():
    # exp(phi + d) p ~= exp(J_l(phi) d) exp(phi) p, so d/dd exp(phi + d) p = -(R p)^ J_l(phi).
    phi = _phis(3)
    p = torch.randn(len(ANGLES), 3, generator=_gen(4), dtype=F64)
    J = _batched_jacobian(lambda ph: (so3_exp(ph) @ p[..., None])[..., 0], phi)
    Rp = (so3_exp(phi) @ p[..., None])[..., 0]
    assert torch.allclose(J, -hat(Rp) @ so3_left_jacobian(phi), atol=1e-11)


def test_so3_left_jacobian_inverse():
    phi = _phis(5)
    prod = so3_left_jacobian_inv(phi) @ so3_left_jacobian(phi)
    assert torch.allclose(prod, EYE3.expand_as(prod), atol=1e-9)
    # d/dd log(exp(d) R) at d = 0 is J_l^-1(log R): autograd through so3_log (angles < pi only).
    phi = phi[:-2]
    R = so3_exp(phi)
    J = jacobian(lambda d: so3_log(so3_exp(d) @ R), torch.zeros(len(phi), 3, dtype=F64))
    J = torch.diagonal(J, dim1=0, dim2=2).permute(2, 0, 1)
    assert torch.allclose(J, so3_left_jacobian_inv(phi), atol=1e-8)


def test_float32_autograd_through_exp_is_accurate_at_small_angles():
    # Regression: the closed form (t - sin t)/t^3 cancels in float32 and made this error 5e-2 at t = 1e-6.
    xi = torch.cat([torch.randn(len(ANGLES), 3, generator=_gen(6), dtype=F64), _phis(6)], dim=-1)
    J64 = _batched_jacobian(lambda x: se3_exp(x).reshape(-1, 16), xi)
    J32 = _batched_jacobian(lambda x: se3_exp(x).reshape(-1, 16), xi.float())
    assert (J32.double() - J64).abs().max() < 1e-5


@settings(max_examples=50, deadline=None)
@given(
    axis=st.tuples(*[st.floats(-1, 1) for _ in range(3)]).filter(lambda a: sum(x * x for x in a) > 1e-2),
    angle=st.one_of(st.floats(0, math.pi - 1e-6), st.floats(0, 1e-5), st.floats(math.pi - 1e-3, math.pi - 1e-6)),
)
def test_so3_exp_log_round_trip_property(axis, angle):
    phi = torch.nn.functional.normalize(torch.tensor(axis, dtype=F64), dim=0) * angle
    assert torch.allclose(so3_log(so3_exp(phi)), phi, atol=1e-9, rtol=0)


# ------------------------------------------------------------------------------------------------- SE(3)


def test_se3_exp_matches_matrix_exponential_and_log_inverts_it():
    xi = _xis(50, 7)
    T = se3_exp(xi)
    wedge = torch.zeros(50, 4, 4, dtype=F64)
    wedge[:, :3, :3] = hat(xi[:, 3:])
    wedge[:, :3, 3] = xi[:, :3]
    assert torch.allclose(T, torch.linalg.matrix_exp(wedge), atol=1e-12)
    assert torch.allclose(se3_log(T), xi, atol=1e-10)


def test_se3_exp_host_is_se3_exp_at_every_angle_branch_and_keeps_dtype():
    phis = _phis(11)
    rho = torch.randn(len(ANGLES), 3, generator=_gen(12), dtype=F64)
    for xi in torch.cat([rho, phis], dim=-1):
        assert torch.allclose(se3_exp_host(xi), se3_exp(xi), atol=1e-14, rtol=0)
    xi32 = _xis(1, 13)[0].float()
    T = se3_exp_host(xi32)
    assert T.dtype == torch.float32 and torch.allclose(T.double(), se3_exp(xi32.double()), atol=1e-7)


def test_se3_log_host_is_se3_log_at_every_angle_branch_and_keeps_dtype():
    """Every angle branch (series, closed form, near pi) and every branch of Shepperd's method (the rotations about
    each axis near pi make each diagonal element the largest)."""
    phis = _phis(14)
    rho = torch.randn(len(ANGLES), 3, generator=_gen(15), dtype=F64)
    near_pi = [torch.tensor([a, 0.0, 0.0], dtype=F64) for a in (3.1, -3.1)] + [
        torch.tensor(v, dtype=F64) * 3.1 for v in ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]
    Ts = [se3_exp(xi) for xi in torch.cat([rho, phis], dim=-1)]
    Ts += [se3_exp(torch.cat([torch.ones(3, dtype=F64), p])) for p in near_pi]
    for T in Ts:
        assert torch.allclose(se3_log_host(T), se3_log(T), atol=1e-12, rtol=0)
    T32 = se3_exp(_xis(1, 16)[0]).float()
    xi = se3_log_host(T32)
    assert xi.dtype == torch.float32 and torch.allclose(xi.double(), se3_log(T32.double()), atol=1e-6)


def test_so3_angle_host_is_the_norm_of_so3_log_at_every_angle():
    """Tiny, small, large and near-pi angles about random axes, and the identity."""
    axes = torch.nn.functional.normalize(torch.randn(8, 3, generator=_gen(17), dtype=F64), dim=-1)
    for angle in (0.0, 1e-12, 1e-7, 1e-3, 0.3, 1.5, 3.0, math.pi - 1e-6, math.pi):
        for axis in axes:
            R = so3_exp(angle * axis)
            assert abs(so3_angle_host(R) - float(so3_log(R).norm())) < 1e-12
            assert abs(so3_angle_host(R) - angle) < 1e-9
    assert abs(so3_angle_host(so3_exp(torch.tensor([0.2, -0.1, 0.4])).float()) - math.sqrt(0.21)) < 1e-6


def test_se3_group_laws():
    T1, T2, T3 = se3_exp(_xis(30, 8)), se3_exp(_xis(30, 9)), se3_exp(_xis(30, 10))
    eye4 = torch.eye(4, dtype=F64).expand(30, 4, 4)
    assert torch.allclose(se3_compose(se3_compose(T1, T2), T3), se3_compose(T1, se3_compose(T2, T3)), atol=1e-12)
    assert torch.allclose(se3_compose(T1, se3_inverse(T1)), eye4, atol=1e-12)
    assert torch.allclose(se3_compose(se3_inverse(T1), T1), eye4, atol=1e-12)
    assert torch.allclose(se3_inverse(se3_exp(_xis(30, 8))), se3_exp(-_xis(30, 8)), atol=1e-12)
    # Acting with a composition is acting twice.
    p = torch.randn(30, 5, 3, generator=_gen(11), dtype=F64)
    assert torch.allclose(se3_act(se3_compose(T1, T2), p), se3_act(T1, se3_act(T2, p)), atol=1e-12)


def test_adjoint_identity():
    T = se3_exp(_xis(30, 12))
    xi = _xis(30, 13) * 0.5
    lhs = se3_compose(se3_compose(T, se3_exp(xi)), se3_inverse(T))
    rhs = se3_exp((se3_adjoint(T) @ xi[..., None])[..., 0])
    assert torch.allclose(lhs, rhs, atol=1e-11)


@settings(max_examples=50, deadline=None)
@given(
    rho=st.tuples(*[st.floats(-10, 10) for _ in range(3)]),
    axis=st.tuples(*[st.floats(-1, 1) for _ in range(3)]).filter(lambda a: sum(x * x for x in a) > 1e-2),
    angle=st.one_of(st.floats(0, math.pi - 1e-4), st.floats(0, 1e-5)),
)
def test_se3_exp_log_round_trip_property(rho, axis, angle):
    phi = torch.nn.functional.normalize(torch.tensor(axis, dtype=F64), dim=0) * angle
    xi = torch.cat([torch.tensor(rho, dtype=F64), phi])
    assert torch.allclose(se3_log(se3_exp(xi)), xi, atol=1e-8, rtol=0)


def test_se3_act_broadcasting():
    T = se3_exp(_xis(4, 14))
    p = torch.randn(4, 7, 3, generator=_gen(15), dtype=F64)
    out = se3_act(T, p)
    assert out.shape == (4, 7, 3)
    for b in range(4):
        expected = p[b] @ T[b, :3, :3].T + T[b, :3, 3]
        assert torch.allclose(out[b], expected)
    assert torch.allclose(se3_act(T, p[:, 0]), out[:, 0])  # one point per transform
    assert se3_act(T, p.reshape(4, 7, 1, 3)).shape == (4, 7, 1, 3)  # image-shaped points
    assert torch.allclose(se3_act(T[0], p), p @ T[0, :3, :3].T + T[0, :3, 3])  # one transform for all


def test_se3_act_jacobians_against_autograd():
    B, N = 6, 5
    T = se3_exp(_xis(B, 16))
    p = torch.randn(B, N, 3, generator=_gen(17), dtype=F64)
    T_n = T[:, None].expand(B, N, 4, 4).reshape(B * N, 4, 4)
    p_n = p.reshape(B * N, 3)
    zero = torch.zeros(B * N, 6, dtype=F64)

    J_left = _batched_jacobian(lambda xi: se3_act(se3_compose(se3_exp(xi), T_n), p_n), zero)
    assert torch.allclose(se3_act_jac_pose(T, p).reshape(B * N, 3, 6), J_left, atol=1e-12)

    J_right = _batched_jacobian(lambda xi: se3_act(se3_compose(T_n, se3_exp(xi)), p_n), zero)
    assert torch.allclose(se3_act_jac_pose_right(T, p).reshape(B * N, 3, 6), J_right, atol=1e-12)

    J_point = _batched_jacobian(lambda q: se3_act(T_n, q), p_n)
    assert torch.allclose(se3_act_jac_point(T_n), J_point, atol=1e-12)


def test_left_and_right_pose_jacobians_are_related_by_the_adjoint():
    # exp(xi_l) T = T exp(xi_r) with xi_l = Ad_T xi_r, so J_right = J_left Ad_T.
    T = se3_exp(_xis(5, 18))
    p = torch.randn(5, 3, generator=_gen(19), dtype=F64)
    assert torch.allclose(se3_act_jac_pose_right(T, p), se3_act_jac_pose(T, p) @ se3_adjoint(T), atol=1e-12)


def test_functions_follow_device_and_dtype():
    xi = _xis(3, 20).float()
    T = se3_exp(xi)
    assert T.dtype == torch.float32 and se3_log(T).dtype == torch.float32
    assert se3_act_jac_pose(T, torch.ones(3, 2, 3)).dtype == torch.float32


def test_batch_shape_agrees_with_torch_broadcast_shapes():
    """The hand-written batch broadcast of se3_from_rt / se3_act gives torch.broadcast_shapes' result, or raises
    where it does."""
    import itertools

    from codeslam.geometry.lie import _batch_shape

    shapes = [(), (1,), (3,), (2, 3), (2, 1), (1, 3), (4, 1, 3), (5,)]
    for a, b in itertools.product(shapes, shapes):
        try:
            want = torch.broadcast_shapes(a, b)
        except RuntimeError:
            with pytest.raises(RuntimeError):
                _batch_shape(torch.Size(a), torch.Size(b))
            continue
        assert _batch_shape(torch.Size(a), torch.Size(b)) == want
