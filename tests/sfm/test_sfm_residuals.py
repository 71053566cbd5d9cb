"""Residuals, loss functions and the compact analytic Jacobians against autograd (float64)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from sfm_scene import look_pose, make_frames

from codeslam.errors import ConfigError
from codeslam.geometry.image import bilinear_sample, image_gradients
from codeslam.geometry.lie import se3_exp
from codeslam.sfm.autodiff import autodiff_jacobian, bilinear_sample_gather
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import build_levels
from codeslam.sfm.normal_equations import dense_jacobian
from codeslam.sfm.residuals import (
    common_cost_change,
    evaluate_pairs,
    huber_cost_and_weight,
    interpolant_gradient,
    pair_jacobians,
    robust_weights,
    sample_by_frame,
    slant_weight,
)
from codeslam.sfm.variables import AFFINE, CODE, POSE, BlockId, SfMState, VariableLayout

D = torch.float64
PAIRS = torch.tensor([[0, 1], [1, 0], [2, 0], [1, 2]])


@pytest.fixture(scope="module")
def problem():
    gt = [look_pose(), look_pose((0.2, -0.05, 0.03), (0.02, -0.04, 0.01)),
          look_pose((-0.1, 0.1, 0.1), (0.0, 0.03, 0.02))]
    kfs, codes, poses = make_frames(gt, width=32, height=24, code_size=5, levels=1, seed=2)
    g = torch.Generator().manual_seed(5)
    # A state away from the truth (so warped pixels are non-integer and residuals non-zero).
    poses = se3_perturb(poses, 0.02, g)
    state = SfMState(poses, codes + 0.3 * torch.randn(codes.shape, generator=g, dtype=D),
                     0.05 * torch.randn(4, 2, generator=g, dtype=D))
    return build_levels(kfs, [0])[0], state


def se3_perturb(poses, scale, g):
    from codeslam.geometry.lie import se3_exp
    return se3_exp(scale * torch.randn(poses.shape[0], 6, generator=g, dtype=D)) @ poses


def test_gather_lookup_equals_grid_sample_lookup():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(2, 3, 9, 11, generator=g, dtype=D)
    uv = torch.rand(2, 50, 2, generator=g, dtype=D) * torch.tensor([12.0, 10.0], dtype=D) - 1.0  # some outside
    a, va = bilinear_sample(img, uv)
    b, vb = bilinear_sample_gather(img, uv)
    torch.testing.assert_close(a, b)
    assert torch.equal(va, vb)


def test_interpolant_gradient_is_the_autograd_slope_of_the_bilinear_lookup():
    g = torch.Generator().manual_seed(1)
    img = torch.rand(1, 2, 9, 11, generator=g, dtype=D)
    uv = (torch.rand(1, 40, 2, generator=g, dtype=D) * torch.tensor([10.0, 8.0], dtype=D)).requires_grad_()
    vals, _ = bilinear_sample(img, uv)
    grad = interpolant_gradient(img, uv.detach())  # (1, 2, 2, N)
    for c in range(2):
        (gu,) = torch.autograd.grad(vals[0, c].sum(), uv, retain_graph=True)
        torch.testing.assert_close(grad[0, c].T, gu[0])


def test_huber_weight_is_the_derivative_of_its_cost_over_s():
    s = torch.linspace(-5, 5, 41, dtype=D).requires_grad_()
    cost, w = huber_cost_and_weight(s, 1.3)
    (d,) = torch.autograd.grad(cost.sum(), s)
    torch.testing.assert_close(d, w * s.detach())


def test_huber_cost_and_weight_are_the_two_branches():
    k = 1.3
    s = torch.tensor([-4.0, -1.3, -0.7, 0.0, 0.2, 1.3, 2.5, float("inf")], dtype=D)
    cost, w = huber_cost_and_weight(s, k)
    a = s.abs()
    inside = a <= k
    assert torch.equal(cost, torch.where(inside, 0.5 * s * s, k * a - 0.5 * k * k))
    assert torch.equal(w, torch.where(inside, torch.ones_like(a), k / a))
    cost_t, w_t = huber_cost_and_weight(s, torch.tensor(k, dtype=D))  # a tensor threshold too
    assert torch.equal(cost_t, cost) and torch.equal(w_t, w)


def _layout(fixed=()):
    return VariableLayout.for_sfm(3, 5, 4, True, fixed=fixed)


@pytest.mark.parametrize("types", [dict(), dict(geometric=False), dict(photometric=False),
                                   dict(photometric=False, geometric_space="proximity")])
def test_compact_jacobians_match_autograd_for_every_block(problem, types):
    level, state = problem
    cfg = SfMConfig(gradient_mode="interpolant", **types)
    layout = _layout()  # every block free, so each block's columns are checked
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    assert 0.5 < ev.valid.float().mean() < 1.0  # some rows masked, most valid
    terms = pair_jacobians(level, PAIRS, ev)
    J = dense_jacobian(terms, PAIRS, state.poses, level, layout)
    J_ref = autodiff_jacobian(level, PAIRS, state, layout, cfg)
    for b, sl in layout.slices():
        if b.kind == AFFINE and not cfg.photometric:
            assert J[:, sl].abs().max() == 0
        scale = J_ref[:, sl].abs().max().clamp_min(1e-12)
        err = (J[:, sl] - J_ref[:, sl]).abs().max() / scale
        assert err < 1e-10, (b, float(err))


def _with_rs(state, seed=7, scale=0.04):
    g = torch.Generator().manual_seed(seed)
    rs = scale * torch.randn(state.poses.shape[0], 3, generator=g, dtype=D)
    return SfMState(state.poses, state.codes, state.affine, rs)


@pytest.mark.parametrize("types", [dict(), dict(geometric=False), dict(photometric=False)])
def test_rolling_shutter_jacobians_match_autograd_for_every_block(problem, types):
    level, state = problem
    state = _with_rs(state)  # readout rotations of about 2 degrees, so every term of the chain rule is exercised
    cfg = SfMConfig(gradient_mode="interpolant", rolling_shutter=True, **types)
    layout = VariableLayout.for_sfm(3, 5, 4, True, rolling_shutter=True)
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg, rs=state.rs)
    terms = pair_jacobians(level, PAIRS, ev)
    J = dense_jacobian(terms, PAIRS, state.poses, level, layout)
    J_ref = autodiff_jacobian(level, PAIRS, state, layout, cfg)
    for b, sl in layout.slices():
        scale = J_ref[:, sl].abs().max().clamp_min(1e-12)
        assert scale > 1e-6 or (b.kind == AFFINE and not cfg.photometric), b  # the readout rotations move some
        err = (J[:, sl] - J_ref[:, sl]).abs().max() / scale
        assert err < 1e-10, (b, float(err))


def test_zero_readout_rotation_is_the_global_shutter_warp(problem):
    level, state = problem
    cfg = SfMConfig()
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    ev_rs = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg,
                           rs=torch.zeros(3, 3, dtype=D))
    torch.testing.assert_close(ev_rs.r, ev.r, rtol=0, atol=1e-12)
    torch.testing.assert_close(ev_rs.v, ev.v, rtol=0, atol=1e-12)


def test_readout_rotation_shifts_rows_in_proportion_to_their_readout_time(problem):
    # Frame B turned about its y axis during the readout: a point seen in B's middle row does not move, points
    # in the top and bottom rows move sideways by opposite amounts (first order: fx * s * omega_y).
    from codeslam.sfm.warp import warp_rolling_shutter

    H = 24
    params = torch.tensor([30.0, 30.0, 15.5, 11.5], dtype=D).reshape(1, 1, 4)
    rows = torch.tensor([0.0, 11.5, 23.0], dtype=D)
    uv = torch.stack([torch.full_like(rows, 15.5), rows], -1)[None]
    T = torch.eye(4, dtype=D)[None]
    zero = torch.zeros(1, 1, 3, dtype=D)
    omega = torch.tensor([0.0, 0.02, 0.0], dtype=D).reshape(1, 1, 3)
    v0 = warp_rolling_shutter(uv, torch.ones(1, 3, dtype=D), T, params, params, zero, zero, H)[0]
    v = warp_rolling_shutter(uv, torch.ones(1, 3, dtype=D), T, params, params, zero, omega, H)[0]
    du = (v - v0)[0, :, 0]
    s = (rows - 11.5) / H
    torch.testing.assert_close(du, -30.0 * s * 0.02, rtol=1e-3, atol=1e-9)
    assert abs(float(du[1])) < 1e-12


def test_relative_pose_jacobian_is_the_left_perturbation_of_T_BA(problem):
    """With B at the identity, xi_A perturbs T_BA = T_wA on the left: J_rel must equal d r / d xi_A."""
    level, state = problem
    cfg = SfMConfig(gradient_mode="interpolant")
    st = state.clone()
    st.poses[1] = torch.eye(4, dtype=D)
    pairs = torch.tensor([[0, 1]])
    st.affine = st.affine[:1]
    ev = evaluate_pairs(level, pairs, st.poses, st.codes, st.affine, cfg)
    terms = pair_jacobians(level, pairs, ev)
    layout = VariableLayout([(BlockId(POSE, 0), 6)])
    J_ref = autodiff_jacobian(level, pairs, st, layout, cfg)  # (T N, 6)
    torch.testing.assert_close(terms.J_rel.reshape(-1, 6), J_ref, rtol=1e-9, atol=1e-9)


def test_sobel_and_interpolant_jacobians_agree_where_both_gradients_are_exact(problem):
    """On an intensity ramp both the Sobel and the bilinear-interpolant slopes are the exact gradient, so the two
    modes must give the same Jacobians: the Sobel path uses the same chain rule."""
    level, state = problem
    uv = level.uv.reshape(level.height, level.width, 2)
    ramp = torch.stack([0.2 + 0.01 * uv[..., 0] + 0.02 * uv[..., 1], 0.8 - 0.015 * uv[..., 0] + 0.01 * uv[..., 1],
                        0.3 + 0.005 * uv[..., 0] + 0.003 * uv[..., 1]])[:, None]  # (3, 1, H, W)
    level = dataclasses.replace(level, gray=ramp, gray_grad=image_gradients(ramp))
    layout = _layout([BlockId(POSE, 0)])
    J = {}
    for mode in ("sobel", "interpolant"):
        cfg = SfMConfig(gradient_mode=mode, geometric=False, border=2.0)
        ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
        J[mode] = dense_jacobian(pair_jacobians(level, PAIRS, ev), PAIRS, state.poses, level, layout)
    assert J["sobel"].abs().max() > 0
    torch.testing.assert_close(J["sobel"], J["interpolant"], rtol=1e-9, atol=1e-9)


def test_residuals_vanish_at_the_truth_away_from_occlusions():
    gt = [look_pose(), look_pose((0.15, 0.0, 0.05), (0.0, -0.03, 0.0))]
    kfs, codes, poses = make_frames(gt, width=48, height=36, code_size=4, levels=1, panel=False)
    level = build_levels(kfs, [0])[0]
    ev = evaluate_pairs(level, torch.tensor([[0, 1]]), poses, codes, None, SfMConfig())
    r = ev.r[ev.valid]
    assert ev.valid.float().mean() > 0.7
    assert r.abs().median() < 1e-3  # photo-consistent rendering, exact depth


def test_masks_zero_invalid_rows_and_price_them_at_the_huber_threshold(problem):
    level, state = problem
    cfg = SfMConfig()
    st = state.clone()
    from codeslam.geometry.lie import se3_exp
    st.poses[1] = se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.0, 1.2, 0.0], dtype=D)) @ st.poses[0]  # looks away
    st.poses[2] = se3_exp(torch.tensor([0.0, 0.0, -3.0, 0.0, 0.0, 0.0], dtype=D)) @ st.poses[0]
    ev = evaluate_pairs(level, PAIRS, st.poses, st.codes, st.affine, cfg)
    assert not ev.valid[0].any()  # pair (0, 1): B looks 69 degrees away
    terms = pair_jacobians(level, PAIRS, ev)
    for t in (terms.r, terms.w, terms.J_rel, terms.J_aff, terms.s_A, terms.s_B):
        assert torch.isfinite(t).all()
        assert t[0].abs().max() == 0
    n_rows = ev.r[0].numel()
    for masked_rows in ("threshold", "common"):  # a pair that sees nothing: the threshold's price either way
        w, cost = robust_weights(ev, masked_rows)
        torch.testing.assert_close(cost[0], torch.tensor(0.5 * 1.345**2 * n_rows, dtype=D))


def test_masked_rows_are_priced_at_the_valid_rows_mean_and_steps_compared_over_common_rows(problem):
    # masked_rows 'common' (the SLAM window's and tracker's): a turn that moves pixels out of view neither pays
    # nor gains for them: the cost is N times the valid rows' mean, and the change between two evaluations is
    # summed over the rows valid in both.
    level, state = problem
    cfg = SfMConfig(masked_rows="common")
    evs = []
    for deg in (0.0, 6.0):
        st = state.clone()
        st.poses[1] = se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.0, math.radians(deg), 0.0], dtype=D)) @ state.poses[1]
        ev = evaluate_pairs(level, PAIRS, st.poses, st.codes, st.affine, cfg)
        _, cost = robust_weights(ev, cfg.masked_rows)
        rows, valid = ev.row_cost, ev.valid
        n, N = valid.sum(dim=2), valid.shape[2]
        assert (n > 0).all() and (n < N).any()  # every pair sees something, some not everything
        assert torch.equal(rows[~valid], torch.zeros_like(rows[~valid]))
        torch.testing.assert_close(cost, (rows.sum(dim=2) * N / n).sum(dim=1))
        evs.append(ev)
    a, b = evs
    assert (a.valid != b.valid).any()  # the turn moved pixels in or out of view
    both = a.valid & b.valid
    expected = (b.row_cost[both] - a.row_cost[both]).sum()
    torch.testing.assert_close(common_cost_change(a.row_cost, a.valid, b.row_cost, b.valid), expected)
    # rows valid in only one evaluation change nothing, whatever their cost
    b_rows = b.row_cost.clone()
    b_rows[b.valid & ~a.valid] += 100.0
    torch.testing.assert_close(common_cost_change(a.row_cost, a.valid, b_rows, b.valid), expected)


def test_slant_weight_is_one_fronto_parallel_and_follows_the_normal_angle():
    params = torch.tensor([[30.0, 30.0, 15.5, 11.5]], dtype=D)
    flat = torch.full((1, 1, 24, 32), 2.0, dtype=D)
    assert torch.allclose(slant_weight(flat, params, 0.25)[..., 1:-1, 1:-1], torch.ones((), dtype=D))
    # The plane Z = 2 + 3 X (normal (-3, 0, 1)/sqrt(10)): depth = 2 / (1 - 3 x) with x = (u - cx) / fx.
    x = (torch.arange(32, dtype=D) - 15.5) / 30.0
    steep = (2.0 / (1.0 - 3.0 * x)).expand(1, 1, 24, 32).clone()
    y = ((torch.arange(24, dtype=D) - 11.5) / 30.0)[:, None]
    cos = (1.0 - 3.0 * x).abs() / (10.0**0.5 * (1.0 + x * x + y * y).sqrt())  # |n . ray| / |ray|, (24, 32)
    expected = (cos / 0.5).clamp(max=1.0)
    w = slant_weight(steep, params, 0.5)[0, 0]
    torch.testing.assert_close(w[1:-1, 1:-1], expected[1:-1, 1:-1])
    assert w[:, 20:-1].max() < 0.5  # grazing part strongly down-weighted


def test_slant_weight_is_kornias_unit_normal_against_the_unit_ray():
    """The weight forms the cosine without unit vectors; kornia's unit normals give the same to rounding."""
    import kornia

    g = torch.Generator().manual_seed(4)
    depth = 2.0 + torch.nn.functional.interpolate(torch.rand(2, 1, 5, 6, generator=g, dtype=D), size=(24, 32),
                                                  mode="bicubic", align_corners=True)
    depth[1, 0, 5:9, 10:14] = 0.0  # no surface: no normal inside (0 / 0), weight 0 as kornia's zero vector gives
    params = torch.tensor([[30.0, 31.0, 15.5, 11.5], [29.0, 30.0, 16.0, 11.0]], dtype=D)
    K = torch.zeros(2, 3, 3, dtype=D)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = params[:, 0], params[:, 1], params[:, 2], \
        params[:, 3], 1.0
    n = kornia.geometry.depth.depth_to_normals(depth, K)  # (2, 3, H, W), unit (0 where undefined)
    ray = kornia.geometry.depth.depth_to_3d_v2(torch.ones(2, 24, 32, dtype=D), K).permute(0, 3, 1, 2)
    cos = (n * ray).sum(1, keepdim=True).abs() / ray.pow(2).sum(1, keepdim=True).sqrt()
    assert (n[1, :, 6:8, 11:13] == 0).all()
    for cos_min in (0.25, 0.9):
        torch.testing.assert_close(slant_weight(depth, params, cos_min), (cos / cos_min).clamp(max=1.0))


def test_occluded_pixels_are_down_weighted_photometric_only_as_the_paper_or_in_both_terms(problem):
    level, state = problem
    cfg = SfMConfig(occlusion_weight=0.1, occlusion_geometric=False)  # the paper's (v)
    # Push frame 1's surface much closer (proximity + 0.3): points of 0 warped into 1 lie far behind it.
    near = dataclasses.replace(level, prox0=level.prox0 + torch.tensor([0, 0.3, 0], dtype=D)[:, None, None, None])
    ev = evaluate_pairs(near, PAIRS, state.poses, state.codes, state.affine, cfg)
    p = 0  # pair (0, 1)
    valid = ev.valid[p, 0]
    w_slant = ev.fixed_weight[p, 1]  # geometric: slant weight only
    torch.testing.assert_close(ev.fixed_weight[p, 0][valid], 0.1 * w_slant[valid])
    ev_geo = evaluate_pairs(near, PAIRS, state.poses, state.codes, state.affine,
                            SfMConfig(occlusion_weight=0.1, occlusion_geometric=True))
    torch.testing.assert_close(ev_geo.fixed_weight[p, 1][valid], 0.1 * w_slant[valid])


def test_uncertainty_widens_the_geometric_sigma(problem):
    level, state = problem
    b = torch.full_like(level.prox0, 0.03)
    lv = dataclasses.replace(level, uncertainty=b)
    cfg = SfMConfig(use_uncertainty=True, geometric_space="proximity", sigma_geometric=0.02)
    ev = evaluate_pairs(lv, PAIRS, state.poses, state.codes, state.affine, cfg)
    t = 1  # geometric
    expected = torch.tensor((0.02**2 + 4 * 0.03**2) ** 0.5, dtype=D)
    torch.testing.assert_close(ev.sigma[:, t][ev.valid[:, t]], expected.expand(int(ev.valid[:, t].sum())))


def test_uncertainty_is_carried_into_log_depth_at_first_order(problem):
    """In log depth a proximity scale b becomes b |d log D / d P| = b / (P (1 - P)) (from D = a (1 - P) / P)."""
    level, state = problem
    b = torch.full_like(level.prox0, 0.03)
    lv = dataclasses.replace(level, uncertainty=b)
    cfg = SfMConfig(use_uncertainty=True, sigma_geometric=0.08)
    ev = evaluate_pairs(lv, PAIRS, state.poses, state.codes, state.affine, cfg)
    prox = lv.prox(state.codes)  # (F, 1, H, W)
    P_A = prox[PAIRS[:, 0]].reshape(len(PAIRS), -1)
    P_B, _ = bilinear_sample(prox[PAIRS[:, 1]], ev.v)
    P_B = P_B[:, 0]
    expected = (0.08**2 + 2 * (0.03 / (P_A * (1 - P_A))) ** 2 + 2 * (0.03 / (P_B * (1 - P_B))) ** 2).sqrt()
    ok = ev.valid[:, 1]
    torch.testing.assert_close(ev.sigma[:, 1][ok], expected[ok])


def test_log_depth_geometric_residual_ignores_a_common_scale():
    """Scaling every depth and translation by s leaves the log-depth geometric residual unchanged (the scale is
    not the geometric term's to choose); the proximity residual changes."""
    gt = [look_pose(), look_pose((0.15, 0.0, 0.05), (0.0, -0.03, 0.0))]
    kfs, codes, poses = make_frames(gt, width=48, height=36, code_size=4, levels=1, panel=False)
    level = build_levels(kfs, [0])[0]
    a = level.avg_depth[:, None, None, None]
    s = 1.7
    depth = a * (1 - level.prox0) / level.prox0
    scaled = dataclasses.replace(level, prox0=a / (s * depth + a))
    scaled_poses = poses.clone()
    scaled_poses[:, :3, 3] *= s
    pair = torch.tensor([[0, 1]])
    change = {}
    for space in ("log_depth", "proximity"):
        cfg = SfMConfig(photometric=False, geometric_space=space)
        r0 = evaluate_pairs(level, pair, poses, codes * 0, None, cfg)
        r1 = evaluate_pairs(scaled, pair, scaled_poses, codes * 0, None, cfg)
        assert torch.equal(r0.valid, r1.valid)
        # Relative to the residual's own spread; B's depth is looked up in proximity, so log depth is scale-free
        # only up to the curvature of that bilinear lookup.
        change[space] = float((r0.r - r1.r).abs().mean() / r0.r.abs().mean())
    assert change["log_depth"] < 0.01
    assert change["proximity"] > 0.1


def test_code_blocks_of_a_pair_touch_only_its_frames(problem):
    level, state = problem
    cfg = SfMConfig(gradient_mode="interpolant")
    layout = _layout()
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    J = dense_jacobian(pair_jacobians(level, PAIRS, ev), PAIRS, state.poses, level, layout)
    J = J.reshape(4, 2, -1, layout.dim)
    sl = layout.slice(BlockId(CODE, 2))
    assert J[0, :, :, sl].abs().max() == 0  # pair (0, 1) does not see frame 2's code
    assert J[2, 0, :, layout.slice(BlockId(CODE, 0))].abs().max() == 0  # photometric: no code of B


def test_geometric_lookups_touching_a_hole_of_b_are_masked(problem):
    level, state = problem
    prox0 = level.prox0.clone()
    jac = level.jac.clone()
    prox0[1, :, 8:14, 10:20] = 0.0  # a hole (the invalid sentinel) in frame 1's proximity
    jac[1, :, 8:14, 10:20] = 0.0
    holey = dataclasses.replace(level, prox0=prox0, jac=jac)
    ev = evaluate_pairs(holey, PAIRS, state.poses, state.codes, state.affine, SfMConfig())
    p = 0  # pair (0, 1): B = 1
    u, v = ev.v[p].unbind(-1)
    near = (u > 10 - 1) & (u < 19 + 1) & (v > 8 - 1) & (v < 13 + 1) & ev.valid[p, 0]
    assert near.sum() > 10
    assert not ev.valid[p, 1][near].any()  # geometric: masked
    assert ev.valid[p, 0][near].all()  # photometric: images have no holes


def test_photometric_residuals_read_only_real_image_pixels(problem):
    """Loss (i) for images: a pixel of A that is not real, or a warp into a part of B that is not, masks the
    photometric row; the geometric rows do not depend on the image."""
    level, state = problem
    cfg = SfMConfig()
    base = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    ok = torch.ones_like(level.gray)
    ok[0, 0, :, :10] = 0  # frame 0: left 10 columns not real
    ok[1] = 0  # frame 1: nothing real
    masked = dataclasses.replace(level, gray_valid=ok)
    ev = evaluate_pairs(masked, PAIRS, state.poses, state.codes, state.affine, cfg)
    torch.testing.assert_close(ev.r, base.r * ev.valid)  # same residuals where still valid
    assert torch.equal(ev.valid[:, 1], base.valid[:, 1])  # geometric rows untouched
    assert not ev.valid[0, 0].any() and not ev.valid[1, 0].any()  # pairs (0, 1) and (1, 0) read frame 1
    cols = ev.v[2, :, 0]  # pair (2, 0): every pixel of A = 2 is real, but those landing in 0's unreal columns
    assert base.valid[2, 0][cols < 10].any() and not ev.valid[2, 0][cols < 10].any()  # are masked
    assert torch.equal(ev.valid[2, 0] | (cols < 11), base.valid[2, 0] | (cols < 11))


def test_level_validity_covers_the_pyramid_footprint():
    """A keyframe's unreal pixels make every pyramid pixel fed by them unreal, and only those."""
    gt = [look_pose(), look_pose((0.1, 0.0, 0.0), (0.0, 0.02, 0.0))]
    kfs, _, _ = make_frames(gt, width=64, height=48, code_size=4, levels=3)
    mask = torch.ones(48, 64, dtype=torch.bool)
    mask[-1] = False  # the bottom row (what undistorting TUM fr1 leaves in the canonical camera)
    kfs[0] = type(kfs[0])(kfs[0].image, kfs[0].camera, kfs[0].decoder, mask)
    levels = build_levels(kfs, [0, 1, 2])
    v0 = levels[0].gray_valid
    assert torch.equal(v0[1], torch.ones_like(v0[1]))  # frame 1: all real
    assert not v0[0, 0, -1].any() and v0[0, 0, :-1].all()  # row 47 only
    for lvl in (1, 2):
        v = levels[lvl].gray_valid[0, 0]
        assert not v[-1].any() and v[0].all()
    with pytest.raises(Exception, match="validity mask"):
        type(kfs[0])(kfs[0].image, kfs[0].camera, kfs[0].decoder, torch.ones(47, 64, dtype=torch.bool))


def test_geometric_stride_keeps_a_grid_of_the_finest_level_weighted_by_its_area(problem):
    level, state = problem  # 32x24, level 0
    base = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, SfMConfig())
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, SfMConfig(geometric_stride=2))
    n = torch.arange(level.height * level.width)
    grid = ((n // level.width) % 2 == 0) & ((n % level.width) % 2 == 0)
    assert torch.equal(ev.valid[:, 1], base.valid[:, 1] & grid)  # geometric: the grid only
    assert int(ev.valid[:, 1].sum()) > 0
    torch.testing.assert_close(ev.fixed_weight[:, 1], 4.0 * base.fixed_weight[:, 1])
    assert torch.equal(ev.valid[:, 0], base.valid[:, 0])  # photometric: every pixel, as before
    torch.testing.assert_close(ev.fixed_weight[:, 0], base.fixed_weight[:, 0])
    coarse = dataclasses.replace(level, level=1)  # level 1: stride 2 >> 1 = 1, every pixel
    ev1 = evaluate_pairs(coarse, PAIRS, state.poses, state.codes, state.affine, SfMConfig(geometric_stride=2))
    assert torch.equal(ev1.valid, base.valid)
    torch.testing.assert_close(ev1.fixed_weight, base.fixed_weight)


def test_sample_by_frame_gives_each_pairs_bilinear_lookup_whatever_the_thread_count():
    """Every pair gets the values of bilinear_sample at its own points (zeros outside the image, also for points
    with only some neighbours inside), for point sets of any size and frames shared by several pairs; and the
    same bits with 1 and 3 threads (the window's solves must not depend on the thread count)."""
    gen = torch.Generator().manual_seed(0)
    img = torch.randn(3, 128, 24, 32, generator=gen).contiguous(memory_format=torch.channels_last)
    sizes, frame_of = (5000, 3, 2047, 777, 4100), [0, 2, 0, 1, 1]
    uv = [torch.rand(n, 2, generator=gen) * torch.tensor([35.0, 27.0]) - 2.0 for n in sizes]  # some outside
    old = torch.get_num_threads()
    outs = []
    try:
        for threads in (1, 3):
            torch.set_num_threads(threads)
            outs.append(sample_by_frame(img, frame_of, uv))
    finally:
        torch.set_num_threads(old)
    for p, f in enumerate(frame_of):
        ref, _ = bilinear_sample(img[f:f + 1], uv[p][None])
        assert outs[0][p].shape == (128, sizes[p])
        torch.testing.assert_close(outs[0][p], ref[0], rtol=1e-5, atol=1e-5)
        assert torch.equal(outs[0][p], outs[1][p])
    outside = (uv[0] < -1).any(-1) | (uv[0][:, 0] > 32) | (uv[0][:, 1] > 24)  # no neighbour inside
    assert int(outside.sum()) > 0 and bool((outs[0][0][:, outside] == 0).all())


def test_a_blank_first_view_keeps_the_geometric_rows_off_the_poses(problem):
    """``geometric_pose_min_std``: a pair whose first view is blank (its intensities' standard deviation over the
    pixels the photometric term sees below the threshold) keeps the geometric rows' code derivatives and loses their
    pose derivatives by ``(std / threshold)^2``; the photometric rows, the residuals and the cost do not change, and
    a pair above the threshold keeps every derivative."""
    level, state = problem
    F_, _, H, W = level.gray.shape
    flat = level.gray.clone()
    flat[1] = 0.5 + 0.01 * (level.gray[1] - level.gray[1].mean())  # frame 1 nearly blank (std ~ 0.01 of before)
    level = dataclasses.replace(level, gray=flat, gray_grad=image_gradients(flat))
    base = SfMConfig(gradient_mode="interpolant")
    gated = SfMConfig(gradient_mode="interpolant", geometric_pose_min_std=0.05)
    ev0 = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, base)
    ev1 = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, gated)
    t0, t1 = pair_jacobians(level, PAIRS, ev0), pair_jacobians(level, PAIRS, ev1)
    assert ev0.geo_pose_scale is None
    seen = ev1.valid[:, 0]
    expected = torch.stack([
        (flat[a, 0].reshape(-1)[seen[p]].std(unbiased=False) / 0.05).clamp(max=1.0) ** 2
        for p, a in enumerate(PAIRS[:, 0].tolist())])
    torch.testing.assert_close(ev1.geo_pose_scale, expected[:, None].expand(-1, H * W))  # one cell: the pair's
    blank = PAIRS[:, 0] == 1
    assert bool((ev1.geo_pose_scale[blank] < 0.01).all()) and bool((ev1.geo_pose_scale[~blank] == 1).all())
    torch.testing.assert_close(t1.r, t0.r, rtol=0, atol=0)
    torch.testing.assert_close(t1.cost, t0.cost, rtol=0, atol=0)
    for name in ("s_A", "s_B"):
        torch.testing.assert_close(getattr(t1, name), getattr(t0, name), rtol=0, atol=0)
    torch.testing.assert_close(t1.J_rows[:, 0], t0.J_rows[:, 0], rtol=0, atol=0)  # photometric rows
    geo0, geo1 = t0.J_rows[:, 1], t1.J_rows[:, 1]
    assert geo0[blank].abs().max() > 0
    torch.testing.assert_close(geo1, geo0 * ev1.geo_pose_scale[..., None], rtol=1e-12, atol=0)
    torch.testing.assert_close(geo1[~blank], geo0[~blank], rtol=0, atol=0)
    with pytest.raises(ConfigError, match="geometric_pose_min_std"):
        SfMConfig(geometric_pose_min_std=-0.1)


def test_a_partly_blank_first_view_keeps_its_blank_regions_geometric_rows_off_the_poses(problem):
    """``geometric_pose_regions``: a first view whose left half is blank and right half textured passes the gate
    taken whole (its spread is the texture's), and cut into cells a side its left half's geometric rows lose their
    pose derivatives by their cells' ``(std / threshold)^2`` (hand-computed) while the right half's keep them."""
    level, state = problem
    _, _, H, W = level.gray.shape
    half = level.gray.clone()
    left = half[1, 0, :, : W // 2]
    half[1, 0, :, : W // 2] = 0.5 + 0.01 * (left - left.mean())
    level = dataclasses.replace(level, gray=half, gray_grad=image_gradients(half))
    whole = SfMConfig(gradient_mode="interpolant", geometric_pose_min_std=0.05)
    cut = dataclasses.replace(whole, geometric_pose_regions=2)
    ev1 = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, whole)
    ev2 = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cut)
    blank = PAIRS[:, 0] == 1
    assert bool((ev1.geo_pose_scale[blank] == 1).all())  # taken whole, the view passes
    seen = ev2.valid[:, 0].reshape(-1, H, W)
    scale = ev2.geo_pose_scale.reshape(-1, H, W)
    for p in blank.nonzero().squeeze(1).tolist():
        for ys, xs in ((slice(0, H // 2), slice(0, W // 2)), (slice(H // 2, H), slice(0, W // 2))):
            std = half[1, 0][ys, xs][seen[p][ys, xs]].std(unbiased=False)
            torch.testing.assert_close(scale[p][ys, xs], ((std / 0.05).clamp(max=1.0) ** 2).expand(H // 2, W // 2))
            assert float(scale[p][ys, xs].max()) < 0.01
        assert bool((scale[p][:, W // 2:] == 1).all())
    assert bool((scale[~blank] == 1).all())
    t1, t2 = pair_jacobians(level, PAIRS, ev1), pair_jacobians(level, PAIRS, ev2)
    torch.testing.assert_close(t2.J_rows[:, 1], t1.J_rows[:, 1] * ev2.geo_pose_scale[..., None], rtol=1e-12, atol=0)
    torch.testing.assert_close(t2.s_A, t1.s_A, rtol=0, atol=0)
    with pytest.raises(ConfigError, match="geometric_pose_regions"):
        SfMConfig(geometric_pose_regions=0)
