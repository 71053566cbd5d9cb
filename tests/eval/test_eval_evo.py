"""Cross-check ATE and RPE against evo (the reference implementation SLAM papers report), on the real TUM
fr1/rpy ground truth and an estimate made from it with a known similarity and seeded noise.

evo is GPL and only imported here, never by the package.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.data.trajectory_file import load_trajectory
from codeslam.eval.metrics import ate, rpe

evo_metrics = pytest.importorskip("evo.core.metrics")
from evo.core import sync  # noqa: E402
from evo.tools import file_interface  # noqa: E402

RTOL = 1e-6
SCALE = 0.37  # a monocular estimate's arbitrary scale


def make_estimate(gt_path: Path, out_dir: Path, seed: int = 0) -> Path:
    """Every 3rd ground-truth pose (about 33 Hz), timestamps jittered by up to 2 ms (less than half the 10 ms
    ground-truth period, so each has one nearest reference stamp), positions and orientations perturbed
    by seeded noise, then mapped by a known similarity into another world frame."""
    gt = load_trajectory(gt_path)
    rng = np.random.default_rng(seed)
    idx = np.arange(5, len(gt) - 5, 3)
    T = gt.poses.numpy()[idx].copy()  # (N, 4, 4)
    T[:, :3, 3] += rng.normal(scale=0.01, size=(len(idx), 3))  # 1 cm position noise
    dR = Rotation.from_rotvec(rng.normal(scale=np.deg2rad(0.5), size=(len(idx), 3))).as_matrix()
    T[:, :3, :3] = T[:, :3, :3] @ dR  # 0.5 degree orientation noise
    R_a = Rotation.from_euler("zyx", [40.0, -25.0, 70.0], degrees=True).as_matrix()
    t_a = np.array([3.0, -1.0, 0.5])
    est = T.copy()
    est[:, :3, :3] = R_a @ T[:, :3, :3]
    est[:, :3, 3] = SCALE * T[:, :3, 3] @ R_a.T + t_a
    stamps = gt.timestamps[idx] + rng.uniform(-0.002, 0.002, size=len(idx))
    out = out_dir / "estimate.txt"
    write_tum(out, Trajectory(stamps, torch.from_numpy(est)))
    return out


def evo_pair(gt_path: Path, est_path: Path, max_diff: float = 0.01):
    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    return sync.associate_trajectories(ref, est, max_diff=max_diff)


@pytest.fixture(scope="module")
def paths(tum_rpy, tmp_path_factory) -> tuple[Path, Path]:
    """(estimate, ground truth) TUM files."""
    gt = tum_rpy / "groundtruth.txt"
    return make_estimate(gt, tmp_path_factory.mktemp("evo")), gt


@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_ate_matches_evo_ape(paths, align):
    est_path, gt = paths
    ref_e, est_e = evo_pair(gt, est_path)
    r_a, t_a, s_a = est_e.align(ref_e, correct_scale=align == "sim3")
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    stats = ape.get_all_statistics()

    ours = ate(load_trajectory(est_path), load_trajectory(gt), align=align)
    assert ours.n_matched == est_e.num_poses
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(ours, key) == pytest.approx(stats[key], rel=RTOL), key
    np.testing.assert_allclose(ours.errors, ape.error, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(ours.alignment.R, r_a, atol=1e-9)
    np.testing.assert_allclose(ours.alignment.t, t_a, rtol=RTOL, atol=1e-9)
    assert ours.alignment.s == pytest.approx(s_a, rel=RTOL)


@pytest.mark.parametrize(
    ("align", "delta", "unit", "all_pairs"),
    [("se3", 1, "frames", False), ("sim3", 1, "frames", False), ("sim3", 5, "frames", True),
     ("sim3", 0.1, "m", False), ("sim3", 0.1, "m", True)],
)
def test_rpe_matches_evo_rpe(paths, align, delta, unit, all_pairs):
    est_path, gt = paths
    ours = rpe(load_trajectory(est_path), load_trajectory(gt), delta=delta, delta_unit=unit, align=align,
               all_pairs=all_pairs)
    evo_unit = evo_metrics.Unit.frames if unit == "frames" else evo_metrics.Unit.meters
    for relation, stats_ours in (
        (evo_metrics.PoseRelation.translation_part, ours.trans),
        (evo_metrics.PoseRelation.rotation_angle_deg, ours.rot_deg),
    ):
        ref_e, est_e = evo_pair(gt, est_path)
        est_e.align(ref_e, correct_scale=align == "sim3")
        m = evo_metrics.RPE(relation, delta=delta, delta_unit=evo_unit, all_pairs=all_pairs)
        m.process_data((ref_e, est_e))
        stats = m.get_all_statistics()
        assert ours.n_pairs == len(m.error)
        for key in ("rmse", "mean", "median", "std", "min", "max"):
            assert getattr(stats_ours, key) == pytest.approx(stats[key], rel=RTOL), (relation, key)
