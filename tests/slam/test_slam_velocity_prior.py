"""The window's constant-velocity prior: its hand-written Jacobian against autograd (float64), its zero on a
constant velocity, and its normal equations against the dense J^T J, J^T r."""

import torch

from codeslam.geometry.lie import se3_exp
from codeslam.sfm.variables import POSE, BlockId, SfMState, VariableLayout
from codeslam.slam.velocity_prior import VelocityPrior


def _state(poses: torch.Tensor) -> SfMState:
    F_ = poses.shape[0]
    return SfMState(poses, torch.zeros(F_, 4, dtype=poses.dtype), torch.zeros(0, 2, dtype=poses.dtype))


def _random_poses(n: int, gen: torch.Generator) -> torch.Tensor:
    xi = torch.randn(n, 6, generator=gen, dtype=torch.float64) * torch.tensor([1.0, 1.0, 1.0, 0.5, 0.5, 0.5],
                                                                                dtype=torch.float64)
    return se3_exp(xi)


def test_jacobian_matches_autograd_float64():
    gen = torch.Generator().manual_seed(3)
    poses = _random_poses(5, gen)
    prior = VelocityPrior.consecutive([0.0, 0.1, 0.25, 0.3, 0.5], acceleration=2.0)
    assert prior.triples == [(0, 1, 2), (1, 2, 3), (2, 3, 4)]
    J = prior.jacobians(_state(poses))  # (T, 3, 3, 6)

    def res(xi: torch.Tensor) -> torch.Tensor:  # left increments of every pose
        return prior.residuals(_state(se3_exp(xi.view(5, 6)) @ poses))

    Ja = torch.autograd.functional.jacobian(res, torch.zeros(30, dtype=torch.float64)).view(3, 3, 5, 6)
    for t, triple in enumerate(prior.triples):
        for a, i in enumerate(triple):
            torch.testing.assert_close(J[t, a], Ja[t, :, i], atol=1e-10, rtol=1e-9)
        others = [i for i in range(5) if i not in triple]
        assert float(Ja[t, :, others].abs().max()) == 0.0


def test_constant_velocity_costs_nothing_and_a_jump_costs_by_sigma():
    t = [0.0, 0.1, 0.3, 0.4]
    poses = torch.eye(4, dtype=torch.float64).repeat(4, 1, 1)
    v = torch.tensor([0.3, -0.1, 1.2], dtype=torch.float64)
    for n, tn in enumerate(t):
        poses[n, :3, 3] = v * tn
    prior = VelocityPrior.consecutive(t, acceleration=4.0)
    assert float(prior.cost(_state(poses))) < 1e-24
    poses[3, 0, 3] += 0.02  # 0.2 m/s more in the last interval (0.1 s); sigma = 4 * (0.2 + 0.1) / 2 = 0.6 m/s
    r = prior.residuals(_state(poses))
    torch.testing.assert_close(r[1], torch.tensor([0.2 / 0.6, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(r[0], torch.zeros(3, dtype=torch.float64))


def test_times_that_do_not_increase_are_skipped():
    prior = VelocityPrior.consecutive([0.0, 0.1, 0.1, 0.2, 0.3], acceleration=1.0, first=2)
    assert prior.triples == [(4, 5, 6)]
    assert len(VelocityPrior.consecutive([0.0, 1.0], acceleration=1.0)) == 0


def test_normal_equations_are_the_dense_ones_and_skip_fixed_poses():
    gen = torch.Generator().manual_seed(5)
    poses = _random_poses(4, gen)
    prior = VelocityPrior.consecutive([0.0, 0.2, 0.3, 0.6], acceleration=1.5)
    layout = VariableLayout([(BlockId(POSE, i), 6) for i in (1, 2, 3)])  # pose 0 fixed
    H = torch.zeros(layout.dim, layout.dim, dtype=torch.float64)
    g = torch.zeros(layout.dim, dtype=torch.float64)
    state = _state(poses)
    prior.add_to(H, g, layout, state)
    J = prior.jacobians(state)
    Jd = torch.zeros(len(prior) * 3, 24, dtype=torch.float64)  # dense over all four poses
    for t, triple in enumerate(prior.triples):
        for a, i in enumerate(triple):
            Jd[3 * t:3 * t + 3, 6 * i:6 * i + 6] = J[t, a]
    r = prior.residuals(state).reshape(-1)
    Jf = Jd[:, 6:]  # the free poses
    torch.testing.assert_close(H, Jf.T @ Jf)
    torch.testing.assert_close(g, Jf.T @ r)
    torch.testing.assert_close(prior.cost(state), 0.5 * r.square().sum())
