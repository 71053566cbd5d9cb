"""The SfM cost's fixed priors as cost objects: each one's normal equations are its cost's exact Hessian and
gradient (autograd, float64) on the free blocks it covers, and nothing elsewhere."""

from __future__ import annotations

import pytest
import torch

from codeslam.sfm.priors import AffinePrior, CodePrior, ReadoutPrior
from codeslam.sfm.variables import AFFINE, CODE, POSE, RS, BlockId, SfMState, VariableLayout

D = torch.float64
F_, C, P = 3, 5, 2


def _state() -> SfMState:
    g = torch.Generator().manual_seed(0)
    poses = torch.eye(4, dtype=D).repeat(F_, 1, 1)
    return SfMState(poses, torch.randn(F_, C, generator=g, dtype=D), torch.randn(P, 2, generator=g, dtype=D),
                    torch.randn(F_, 3, generator=g, dtype=D))


def _autograd(prior, state: SfMState, layout: VariableLayout) -> tuple[torch.Tensor, torch.Tensor]:
    """Gradient and Hessian of ``prior.cost`` in the layout's increments (all additive blocks here)."""

    def cost(x: torch.Tensor) -> torch.Tensor:
        moved = SfMState(state.poses, state.codes.clone(), state.affine.clone(), state.rs.clone())
        for b, sl in layout.slices():
            {CODE: moved.codes, AFFINE: moved.affine, RS: moved.rs}[b.kind][b.index] += x[sl]
        return torch.as_tensor(prior.cost(moved), dtype=D)

    x = torch.zeros(layout.dim, dtype=D)
    return torch.autograd.functional.jacobian(cost, x), torch.autograd.functional.hessian(cost, x)


# a layout with codes, affine and rs blocks, frame 0's code fixed (as a gauge or a frame without depth)
LAYOUT = VariableLayout.for_sfm(F_, C, P, True, [BlockId(POSE, i) for i in range(F_)] + [BlockId(CODE, 0)],
                                rolling_shutter=True)


@pytest.mark.parametrize("prior", [CodePrior(0.7), CodePrior(1.3, [1]), AffinePrior((0.2, 0.1)),
                                   ReadoutPrior(0.05)], ids=["code", "code-frame-1", "affine", "readout"])
def test_each_prior_adds_its_costs_hessian_and_gradient(prior):
    state = _state()
    H = torch.zeros(LAYOUT.dim, LAYOUT.dim, dtype=D)
    g = torch.zeros(LAYOUT.dim, dtype=D)
    prior.add_to(H, g, LAYOUT, state)
    g_ref, H_ref = _autograd(prior, state, LAYOUT)
    torch.testing.assert_close(g, g_ref, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(H, H_ref, rtol=1e-12, atol=1e-12)
    assert bool(H.abs().sum() > 0)  # it covers some free block of this layout


def test_the_code_prior_costs_fixed_codes_but_adds_only_free_ones():
    state = _state()
    assert float(CodePrior(2.0).cost(state)) == pytest.approx(float(state.codes.square().sum()))
    assert float(CodePrior(2.0, [0]).cost(state)) == pytest.approx(float(state.codes[0].square().sum()))
    H = torch.zeros(LAYOUT.dim, LAYOUT.dim, dtype=D)
    g = torch.zeros(LAYOUT.dim, dtype=D)
    CodePrior(2.0, [0]).add_to(H, g, LAYOUT, state)  # frame 0's code is not free: nothing to add
    assert not bool(H.any()) and not bool(g.any())


def test_the_readout_prior_costs_nothing_without_readout_rotations():
    state = _state()
    state.rs = None
    assert float(ReadoutPrior(0.05).cost(state)) == 0.0
