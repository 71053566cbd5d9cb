"""The evaluation of a SLAM run against ground truth: the metrics ``codeslam slam`` reports and its trajectory plot.

It reads what the SLAM runner produces (the estimated :class:`~codeslam.data.trajectory.Trajectory` and the
ground truth of the same frames) and nothing else, so the SLAM package never imports evaluation code.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from codeslam.data.trajectory import Trajectory
from codeslam.errors import CodeSLAMError
from codeslam.eval import metrics
from codeslam.eval.plots import plot_trajectories


def rotation_drift_deg(est: Trajectory, ref: Trajectory, ate: metrics.ATEResult) -> np.ndarray:
    """(K,) orientation error (degrees) of every matched pose relative to the first, ``angle((R_ref0^T R_ref)^T
    (R_est0^T R_est))``: independent of any alignment (a position-only alignment leaves the roll about a nearly
    straight path undetermined)."""
    R_est = est.poses.numpy()[ate.est_idx, :3, :3]  # (K, 3, 3)
    R_ref = ref.poses.numpy()[ate.ref_idx, :3, :3]
    rel_est = np.swapaxes(R_est[:1], -1, -2) @ R_est  # R_est0^T R_est
    rel_ref = np.swapaxes(R_ref[:1], -1, -2) @ R_ref
    return np.degrees(metrics.rotation_angle(np.swapaxes(rel_ref, -1, -2) @ rel_est))


def evaluate_run(est: Trajectory, gt: Trajectory) -> dict:
    """Metrics of the estimate against ground truth: ATE (SE(3) and Sim(3) alignment), RPE (its translation also
    after the Sim(3) scale, ``rpe_trans_sim3_rmse``), the orientation
    error relative to the first frame (``rot_err_rmse_deg``, ``rot_err_max_deg``) and after the best rotation
    alignment (``rot_aligned_rmse_deg``, ``rot_aligned_max_deg``), and two no-motion
    baselines: a constant pose at the first ground-truth pose
    (``no_motion_ate_rmse``, unaligned) and the best any constant pose can do under alignment
    (``no_motion_ate_rmse_aligned``, the RMS distance of the positions to their mean), and the scale drift
    (``scale_drift``, :func:`codeslam.eval.metrics.scale_drift_or_none`).
    Raises :class:`CodeSLAMError` when the trajectories cannot be matched or aligned."""
    out: dict = {}
    se3 = metrics.evaluate(est, gt, align="se3")
    s = se3.summary()
    out.update(ate_se3_rmse=s["ate_rmse"], ate_se3_mean=s["ate_mean"], ate_se3_max=s["ate_max"],
               rpe_trans_rmse=s["rpe_trans_rmse"], rpe_rot_rmse_deg=s["rpe_rot_rmse_deg"],
               n_matched=s["n_matched"], path_length_gt=s["path_length_gt"], drift_end_error=s["drift_end_error"])
    rot = rotation_drift_deg(est, gt, se3.ate)
    out.update(rot_err_rmse_deg=float(np.sqrt(np.mean(rot**2))), rot_err_max_deg=float(rot.max()))
    R_est = est.poses.numpy()[se3.ate.est_idx, :3, :3]
    R_ref = gt.poses.numpy()[se3.ate.ref_idx, :3, :3]
    rot_al = np.degrees(metrics.orientation_errors_aligned(R_est, R_ref))
    out.update(rot_aligned_rmse_deg=float(np.sqrt(np.mean(rot_al**2))), rot_aligned_max_deg=float(rot_al.max()))
    sim3 = metrics.ate(est, gt, align="sim3")
    out.update(ate_sim3_rmse=float(sim3.rmse), sim3_scale=float(sim3.alignment.s))
    # a monocular map has no scale of its own: its per-frame translations read after the Sim(3) scale (evo_rpe -as)
    out["rpe_trans_sim3_rmse"] = float(metrics.rpe(est, gt, align="sim3").trans.rmse)
    out["scale_drift"] = metrics.scale_drift_or_none(est, gt)
    xyz = gt.positions_xyz.numpy()
    out["no_motion_ate_rmse"] = float(np.sqrt(np.mean(np.sum((xyz - xyz[0]) ** 2, axis=1))))
    out["no_motion_ate_rmse_aligned"] = float(np.sqrt(np.mean(np.sum((xyz - xyz.mean(0)) ** 2, axis=1))))
    return out


def evaluate_run_if_possible(est: Trajectory, gt: Trajectory | None) -> dict:
    """:func:`evaluate_run`, or ``{}`` without ground truth, or ``{"evaluation_error": why}`` when the ground
    truth is too short or degenerate to align (a run is still worth its outputs then)."""
    if gt is None:
        return {}
    try:
        return evaluate_run(est, gt)
    except CodeSLAMError as e:
        return {"evaluation_error": str(e)}


def plot_run(path: str | Path, est: Trajectory, gt: Trajectory, keyframes: int) -> None:
    """PNG of the estimate after SE(3) alignment against the ground truth, seen from above (x-y and x-z)."""
    ate = metrics.ate(est, gt, align="se3")
    plot_trajectories(path, ate.est_xyz, gt.positions_xyz.numpy(),
                      title=f"CodeSLAM: ATE RMSE {ate.rmse:.4f} m (SE(3) alignment), {keyframes} keyframes",
                      est_label="estimate", ref_label="ground truth")
