"""A keyframe's depth scale as one more code entry (:class:`~codeslam.sfm.decoder.ScaledDecoder`): the depth it
decodes, and the window's normal equations and scale prior with it against autograd, in float64."""

from __future__ import annotations

import pytest
import torch
from sfm_scene import look_pose, make_frames

from codeslam.errors import CodeSLAMError
from codeslam.geometry.lie import se3_exp
from codeslam.sfm.autodiff import autodiff_normal_equations, retract_differentiable
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.decoder import ScaledDecoder
from codeslam.sfm.keyframes import Keyframe, build_levels
from codeslam.sfm.normal_equations import assemble
from codeslam.sfm.residuals import evaluate_pairs, pair_jacobians
from codeslam.sfm.scale_prior import DepthScalePrior, WindowScalePrior
from codeslam.sfm.variables import POSE, BlockId, SfMState, VariableLayout

D = torch.float64
PAIRS = torch.tensor([[0, 1], [1, 0], [0, 2], [2, 1], [2, 0]])


@pytest.fixture(scope="module")
def problem():
    gt = [look_pose(), look_pose((0.2, -0.05, 0.03), (0.02, -0.04, 0.01)),
          look_pose((-0.1, 0.1, 0.1), (0.0, 0.03, 0.02))]
    kfs, codes, poses = make_frames(gt, width=32, height=24, code_size=6, levels=1, seed=4)
    kfs = [Keyframe(k.image, k.camera, ScaledDecoder.wrap(k.decoder), k.valid) for k in kfs]
    g = torch.Generator().manual_seed(7)
    poses = se3_exp(0.02 * torch.randn(3, 6, generator=g, dtype=D)) @ poses
    scales = torch.tensor([[0.1], [-0.2], [0.3]], dtype=D)
    codes = torch.cat([codes + 0.3 * torch.randn(codes.shape, generator=g, dtype=D), scales], dim=1)
    state = SfMState(poses, codes, 0.05 * torch.randn(5, 2, generator=g, dtype=D))
    return kfs, build_levels(kfs, [0])[0], state


def test_the_scale_entry_scales_the_decoded_depth_exactly(problem):
    kfs, _, state = problem
    dec = kfs[1].decoder
    assert dec.code_size == 7 and isinstance(dec.to(D), ScaledDecoder)
    code = state.codes[1]
    unscaled = dec.depth(torch.cat([code[:-1], torch.zeros(1, dtype=D)]))
    torch.testing.assert_close(dec.depth(code), unscaled * torch.exp(code[-1]), rtol=1e-12, atol=0)
    with pytest.raises(CodeSLAMError):
        dec.principal(3)


@pytest.mark.parametrize("types", [dict(), dict(photometric=False), dict(geometric=False)])
def test_window_normal_equations_with_a_scale_entry_equal_autograd(problem, types):
    _, level, state = problem
    assert level.scale_entry and level.code_size == 7
    cfg = SfMConfig(gradient_mode="interpolant", **types)
    layout = VariableLayout.for_sfm(3, 7, 5, True, fixed=[BlockId(POSE, 0)])
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    level.refresh_scale_column(state.codes)
    H, g = assemble(pair_jacobians(level, PAIRS, ev), PAIRS, state.poses, level, layout)
    H_ad, g_ad = autodiff_normal_equations(level, PAIRS, state, layout, cfg)
    assert (H - H_ad).abs().max() < 1e-10 * H_ad.abs().max()
    assert (g - g_ad).abs().max() < 1e-10 * g_ad.abs().max()
    scale_rows = [layout.slice(BlockId("code", f)).stop - 1 for f in range(3)]
    assert g[scale_rows].abs().min() > 1e-3 * g.abs().max()  # the scales are seen, not zero columns


@pytest.mark.parametrize("prior_type", [DepthScalePrior, WindowScalePrior])
def test_scale_priors_with_a_scale_entry_match_autograd(problem, prior_type):
    _, level, state = problem
    prior = prior_type(level, [0, 1, 2], 0.3)
    layout = VariableLayout.for_sfm(3, 7, 5, True, fixed=[BlockId(POSE, 0)])
    H = torch.zeros(layout.dim, layout.dim, dtype=D)
    g = torch.zeros(layout.dim, dtype=D)
    prior.add_to(H, g, layout, state)
    delta = torch.zeros(layout.dim, dtype=D, requires_grad=True)
    prior.cost(retract_differentiable(state, layout, delta)).backward()
    torch.testing.assert_close(g, delta.grad, rtol=1e-10, atol=1e-12)
    # the prior holds the whole depth: moving the scale and the code's mean log depth against each other is free
    unscaled = SfMState(state.poses, torch.cat([state.codes[:, :-1], torch.zeros(3, 1, dtype=D)], 1), state.affine)
    assert float(prior.cost(state)) != pytest.approx(float(prior.cost(unscaled)))
