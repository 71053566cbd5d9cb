"""Depth and relative-pose errors of reconstructions against ground truth (pure maths, no I/O).

* Proximity errors (paper Sec. 5.1, Table 1) are taken on the pixels with valid ground-truth depth, between the
  decoded proximity (as the network outputs it, unclamped) and the ground truth's proximity ``a / (d + a)``.
* :class:`DepthErrors` pools squared errors over many frames, so that a set's RMSE is that of all its pixels
  together; it also keeps the sums that give the RMSE of the best single constant proximity on the same pixels,
  ``min_c RMSE(p_gt - c)``, which is the population standard deviation of ``p_gt`` (the baseline a depth
  predictor must beat to carry any information).
* Relative poses of an SfM result: monocular SfM fixes the scale only through the network's depth prior, so
  translations are reported both as estimated and after the one scale factor that best aligns them to ground
  truth (:func:`pose_errors_relative_to_frame`; not the trajectory RPE of
  :func:`codeslam.eval.metrics.relative_motion_errors`, which compares motions between pairs of poses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.eval.metrics import relative_poses, rotation_angle


def valid_depth(depth: torch.Tensor) -> torch.Tensor:
    """(...) bool: finite and positive (the datasets' 0 means no measurement)."""
    return torch.isfinite(depth) & (depth > 0)


@dataclass
class DepthErrors:
    """Pooled error sums over the valid ground-truth pixels of any number of frames.

    ``add(prox_pred, prox_gt, depth_pred, depth_gt)`` with (H, W) tensors; every property is over all pixels
    added so far (None while no valid pixel was added). ``per_frame`` keeps each frame's proximity RMSE.
    """

    n: int = 0
    sq_prox: float = 0.0
    abs_rel: float = 0.0
    sum_gt: float = 0.0
    sum_gt_sq: float = 0.0
    per_frame: list[float | None] = field(default_factory=list)

    def add(
        self, prox_pred: torch.Tensor, prox_gt: torch.Tensor, depth_pred: torch.Tensor, depth_gt: torch.Tensor
    ) -> None:
        mask = valid_depth(depth_gt)
        k = int(mask.sum())
        if k == 0:
            self.per_frame.append(None)
            return
        p, g = prox_pred[mask].double(), prox_gt[mask].double()
        sq = float((p - g).square().sum())
        self.per_frame.append(math.sqrt(sq / k))
        self.n += k
        self.sq_prox += sq
        d, dg = depth_pred[mask].double(), depth_gt[mask].double()
        self.abs_rel += float(((d - dg).abs() / dg).sum())
        self.sum_gt += float(g.sum())
        self.sum_gt_sq += float(g.square().sum())

    @property
    def prox_rmse(self) -> float | None:
        return math.sqrt(self.sq_prox / self.n) if self.n else None

    @property
    def depth_abs_rel(self) -> float | None:
        """Mean of ``|d - d_gt| / d_gt``."""
        return self.abs_rel / self.n if self.n else None

    @property
    def constant_rmse(self) -> float | None:
        """RMSE of the best single constant proximity (the mean of ``p_gt``): the standard deviation of ``p_gt``."""
        if not self.n:
            return None
        mean = self.sum_gt / self.n
        return math.sqrt(max(self.sum_gt_sq / self.n - mean * mean, 0.0))


def prox_rmse(prox_pred: torch.Tensor, prox_gt: torch.Tensor, depth_gt: torch.Tensor) -> float | None:
    """(H, W) each -> proximity RMSE over the pixels with valid ``depth_gt`` (None when there are none)."""
    mask = valid_depth(depth_gt)
    if not bool(mask.any()):
        return None
    return float((prox_pred[mask].double() - prox_gt[mask].double()).square().mean().sqrt())


def median_scale(depth_pred: torch.Tensor, depth_gt: torch.Tensor) -> float | None:
    """The factor s = median(d_gt / d) over pixels valid in both: ``s d`` is the prediction at the ground truth's
    scale (the usual monocular alignment). None when no pixel is valid in both."""
    mask = valid_depth(depth_gt) & valid_depth(depth_pred)
    if not bool(mask.any()):
        return None
    return float((depth_gt[mask].double() / depth_pred[mask].double()).median())


@dataclass(frozen=True)
class PoseErrorsRelativeToFrame:
    """Errors of the poses of frames k relative to a reference frame r, ``T_rk = T_wr^-1 T_wk``, over the K
    frames other than r. Means over those frames; ``per_frame`` lists (trans, trans_scaled, rot_deg) each.

    Attributes:
        trans: mean ``||t_est - t_gt||`` (units of the ground truth).
        trans_scaled: the same after scaling every estimated translation by ``scale``.
        scale: the s minimising ``sum ||s t_est - t_gt||^2`` (None when all estimated translations are zero).
        rot_deg: mean angle of ``R_est^T R_gt`` in degrees.
        trans_gt: mean ground-truth baseline ``||t_gt||`` (the error of estimating no motion).
        rot_gt_deg: mean ground-truth rotation angle (the error of estimating no rotation).
    """

    trans: float
    trans_scaled: float
    scale: float | None
    rot_deg: float
    trans_gt: float
    rot_gt_deg: float
    per_frame: list[tuple[float, float, float]]


def pose_errors_relative_to_frame(poses_est: np.ndarray, poses_gt: np.ndarray, ref: int) -> PoseErrorsRelativeToFrame:
    """(F, 4, 4) estimated and ground-truth T_wc (F >= 2), index r of the reference frame (SfM's master) ->
    :class:`PoseErrorsRelativeToFrame`: how wrong each other frame's pose is as seen from frame r."""
    est = np.asarray(poses_est, dtype=np.float64)
    gt = np.asarray(poses_gt, dtype=np.float64)
    others = np.array([k for k in range(len(est)) if k != ref])
    refs = np.full_like(others, ref)
    rel_est = relative_poses(est, refs, others)  # (K, 4, 4) T_rk
    rel_gt = relative_poses(gt, refs, others)
    t_est, t_gt = rel_est[:, :3, 3], rel_gt[:, :3, 3]  # (K, 3)
    denom = float(np.sum(t_est * t_est))
    scale = float(np.sum(t_est * t_gt)) / denom if denom > 0 else None  # least-squares scale
    trans = np.linalg.norm(t_est - t_gt, axis=1)
    trans_scaled = np.linalg.norm((1.0 if scale is None else scale) * t_est - t_gt, axis=1)
    rot = np.degrees(rotation_angle(np.swapaxes(rel_est[:, :3, :3], 1, 2) @ rel_gt[:, :3, :3]))
    return PoseErrorsRelativeToFrame(
        trans=float(trans.mean()),
        trans_scaled=float(trans_scaled.mean()),
        scale=scale,
        rot_deg=float(rot.mean()),
        trans_gt=float(np.linalg.norm(t_gt, axis=1).mean()),
        rot_gt_deg=float(np.degrees(rotation_angle(rel_gt[:, :3, :3])).mean()),
        per_frame=[(float(a), float(b), float(c)) for a, b, c in zip(trans, trans_scaled, rot)],
    )
