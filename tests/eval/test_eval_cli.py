"""``codeslam eval`` end to end: JSON numbers (checked against evo), plots, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from codeslam.cli import main
from codeslam.data.euroc_csv import write_euroc_csv
from codeslam.data.trajectory import Trajectory, read_tum, write_tum

evo_metrics = pytest.importorskip("evo.core.metrics")
from evo.core import sync  # noqa: E402
from evo.tools import file_interface  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def files(tum_rpy, tmp_path_factory) -> tuple[Path, Path]:
    """(estimate as EuRoC CSV, ground truth TUM): 0.8 s of every 2nd ground-truth pose, 1.5 ms late, scaled by
    0.5 and rotated, with 5 mm of seeded position noise."""
    gt_path = tum_rpy / "groundtruth.txt"
    gt = read_tum(gt_path)
    rng = np.random.default_rng(11)
    idx = np.arange(700, 1500, 2)
    T = gt.poses.numpy()[idx].copy()
    T[:, :3, 3] += rng.normal(scale=0.005, size=(len(idx), 3))
    R = Rotation.from_euler("xyz", [10.0, 80.0, -30.0], degrees=True).as_matrix()
    T[:, :3, :3] = R @ T[:, :3, :3]
    T[:, :3, 3] = 0.5 * T[:, :3, 3] @ R.T + np.array([1.0, 2.0, 3.0])
    est_path = tmp_path_factory.mktemp("cli") / "estimate.csv"
    write_euroc_csv(est_path, Trajectory(gt.timestamps[idx] + 0.0015, torch.from_numpy(T)))
    return est_path, gt_path


def run(capsys, *args: str) -> tuple[int, str, str]:
    rc = main(["eval", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_eval_json_matches_evo(files, tmp_path, capsys, align):
    est_path, gt_path = files
    js, plot, drift = tmp_path / "r.json", tmp_path / "traj.png", tmp_path / "drift.png"
    rc, out, err = run(capsys, est_path, gt_path, "--align", align, "--delta", "3", "--json", js, "--plot", plot,
                       "--drift-plot", drift)
    assert rc == 0, err
    assert "ATE" in out and "RPE" in out
    res = json.loads(js.read_text())

    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_euroc_csv_trajectory(str(est_path))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    _, _, s = est.align(ref, correct_scale=align == "sim3")
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe_t = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=3)
    rpe_t.process_data((ref, est))
    rpe_r = evo_metrics.RPE(evo_metrics.PoseRelation.rotation_angle_deg, delta=3)
    rpe_r.process_data((ref, est))

    assert res["n_matched"] == est.num_poses == 400
    assert res["align"] == align
    assert res["scale"] == pytest.approx(s, rel=1e-6)
    for k in ("rmse", "mean", "median", "max"):
        assert res[f"ate_{k}"] == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType(k)), rel=1e-6)
    assert res["rpe_trans_rmse"] == pytest.approx(rpe_t.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-6)
    assert res["rpe_rot_rmse_deg"] == pytest.approx(rpe_r.get_statistic(evo_metrics.StatisticsType.rmse),
                                                    rel=1e-6)
    assert res["rpe_n_pairs"] == len(rpe_t.error)
    assert res["path_length_gt"] == pytest.approx(ref.path_length, rel=1e-9)
    if align == "sim3":
        assert res["scale"] == pytest.approx(2.0, rel=0.1)
        assert res["ate_rmse"] < 0.02  # 5 mm per axis of noise
    for png in (plot, drift):
        assert png.read_bytes()[:8] == PNG_MAGIC
    assert not list(tmp_path.glob(".*.tmp")) and not list(tmp_path.glob(".*.png"))  # no temporaries left


def write_lines(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("make_est", "match"),
    [
        (lambda d, gt: d / "missing.txt", "not found"),
        (lambda d, gt: write_lines(d / "bad.txt", ["1305031230.0 1 2 3 0 0 0 1", "1305031230.1 1 2 x 0 0 0 1"]),
         "bad.txt:2"),
        (lambda d, gt: write_lines(d / "late.txt", [f"{2e9 + k} {k} {k * k} 0 0 0 0 1" for k in range(5)]),
         "do not overlap"),
        (lambda d, gt: write_lines(d / "two.txt", [f"{gt.timestamps[k]:.6f} {k} {k * k} 0 0 0 0 1"
                                                   for k in (100, 200)]), "at least 3"),
        (lambda d, gt: write_lines(d / "line.txt", [f"{gt.timestamps[k]:.6f} {k} 0 0 0 0 0 1"
                                                    for k in range(100, 110)]), "collinear"),
    ],
)
def test_bad_input_one_line_no_json(files, tmp_path, capsys, make_est, match):
    _, gt_path = files
    est_path = make_est(tmp_path, read_tum(gt_path))
    js = tmp_path / "r.json"
    rc, _, err = run(capsys, est_path, gt_path, "--json", js)
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("codeslam: error:"), err
    assert match in lines[0]
    assert not js.exists()


@pytest.mark.parametrize(
    ("opts", "match"),
    [(["--align", "affine"], "--align"), (["--delta-unit", "s"], "--delta-unit"), (["--delta", "1000"], "--delta"),
     (["--max-diff", "-1"], "max_diff")],
)
def test_bad_options_one_line_no_json(files, tmp_path, capsys, opts, match):
    est_path, gt_path = files
    js = tmp_path / "r.json"
    rc, _, err = run(capsys, est_path, gt_path, *opts, "--json", js)
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and match in lines[0], err
    assert not js.exists()


def test_tum_estimate_and_self_evaluation(files, tmp_path, capsys):
    """A TUM estimate equal to a slice of the ground truth: zero error, unit scale."""
    _, gt_path = files
    gt = read_tum(gt_path)
    est_path = tmp_path / "same.txt"
    write_tum(est_path, gt.subset(np.arange(0, 600)))
    js = tmp_path / "r.json"
    rc, _, err = run(capsys, est_path, gt_path, "--align", "none", "--json", js)
    assert rc == 0, err
    res = json.loads(js.read_text())
    assert res["n_matched"] == 600 and res["scale"] == 1.0
    assert res["ate_max"] < 1e-6 and res["rpe_trans_max"] < 1e-6 and res["drift_end_error"] < 1e-6
    assert res["scale_drift"] == pytest.approx(1.0, rel=1e-9)  # each fifth of the path fits itself exactly
