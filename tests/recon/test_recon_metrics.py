"""Depth and relative-pose metrics: pooled RMSE, the best-constant baseline, scale alignment of translations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from codeslam.geometry.lie import se3_exp
from codeslam.geometry.proximity import depth_to_prox
from codeslam.recon.metrics import DepthErrors, median_scale, pose_errors_relative_to_frame, prox_rmse


def _frame(seed: int, holes: float = 0.2):
    g = torch.Generator().manual_seed(seed)
    depth_gt = 0.5 + 3 * torch.rand(12, 16, generator=g, dtype=torch.float64)
    depth_gt[torch.rand(12, 16, generator=g) < holes] = 0.0
    depth_pred = 0.5 + 3 * torch.rand(12, 16, generator=g, dtype=torch.float64)
    return depth_pred, depth_gt


def test_pooled_errors_match_a_direct_computation_over_all_valid_pixels():
    a = 1.5
    errs = DepthErrors()
    preds, gts = [], []
    for s in range(3):
        d, dg = _frame(s)
        errs.add(depth_to_prox(d, a), depth_to_prox(dg, a), d, dg)
        preds.append(d[dg > 0])
        gts.append(dg[dg > 0])
    p, g = torch.cat(preds), torch.cat(gts)
    pp, pg = depth_to_prox(p, a), depth_to_prox(g, a)
    assert errs.n == len(g)
    assert errs.prox_rmse == pytest.approx(float((pp - pg).square().mean().sqrt()), rel=1e-12)
    assert errs.depth_abs_rel == pytest.approx(float(((p - g).abs() / g).mean()), rel=1e-12)
    assert len(errs.per_frame) == 3
    # the best constant: brute-force minimum over a fine grid of constants vs the closed form (std)
    grid = torch.linspace(0, 1, 20001, dtype=torch.float64)
    brute = float((pg[None] - grid[:, None]).square().mean(1).sqrt().min())
    assert errs.constant_rmse == pytest.approx(brute, abs=1e-6)
    assert errs.constant_rmse <= brute


def test_no_valid_pixels_gives_none():
    errs = DepthErrors()
    z = torch.zeros(4, 4)
    errs.add(z, z, z, z)
    assert errs.prox_rmse is None and errs.constant_rmse is None and errs.per_frame == [None]
    assert prox_rmse(z, z, z) is None and median_scale(z, z) is None


def test_median_scale_recovers_a_global_factor():
    d, dg = _frame(5, holes=0.0)
    assert median_scale(dg / 2.5, dg) == pytest.approx(2.5)


def _poses(xis):
    return torch.stack([se3_exp(torch.tensor(x, dtype=torch.float64)) for x in xis]).numpy()


GT = _poses([[0.3, 0.1, -0.2, 0.1, 0.0, 0.05], [0.5, 0.0, 0.1, 0.0, 0.2, 0.0], [0.1, -0.3, 0.2, -0.1, 0.1, 0.1]])


def test_exact_poses_have_zero_error_in_any_world_frame():
    T = se3_exp(torch.tensor([1.0, 2.0, 3.0, 0.3, -0.2, 0.1], dtype=torch.float64)).numpy()
    r = pose_errors_relative_to_frame(T @ GT, GT, ref=1)
    assert r.trans == pytest.approx(0, abs=1e-12) and r.rot_deg == pytest.approx(0, abs=1e-6)
    assert r.scale == pytest.approx(1.0) and len(r.per_frame) == 2


def test_scaled_translations_are_aligned_by_the_least_squares_scale():
    est = GT.copy()
    ref = 0
    # scale the world: every relative translation scales by 0.4, rotations unchanged
    est[:, :3, 3] = 0.4 * est[:, :3, 3]
    r = pose_errors_relative_to_frame(est, GT, ref)
    assert r.scale == pytest.approx(2.5, rel=1e-9)
    assert r.trans_scaled == pytest.approx(0, abs=1e-12)
    assert r.trans > 0.01 and r.rot_deg == pytest.approx(0, abs=1e-6)


def test_identity_estimate_errs_by_the_ground_truth_motion():
    est = np.repeat(np.eye(4)[None], 3, axis=0)
    r = pose_errors_relative_to_frame(est, GT, ref=0)
    assert r.trans == pytest.approx(r.trans_gt) and r.rot_deg == pytest.approx(r.rot_gt_deg)
    assert r.scale is None
    rel = np.linalg.inv(GT[0]) @ GT[2]
    assert r.per_frame[1][0] == pytest.approx(float(np.linalg.norm(rel[:3, 3])))
    angle = math.degrees(math.acos((np.trace(rel[:3, :3]) - 1) / 2))
    assert r.per_frame[1][2] == pytest.approx(angle, rel=1e-6)
