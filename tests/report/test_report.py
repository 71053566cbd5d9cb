"""The run report: reading a run folder (optional files absent or present), the page's sections and figures with
and without ground truth, the status timeline from frames.csv or from the summary, and one-line errors for a folder
that is not a run. Built on a small hand-made run (no SLAM), so each case takes a fraction of a second; the
end-to-end report of a real run, opened in a browser, is tests/report/test_report_browser.py."""

from __future__ import annotations

import csv
import html
import json
import math
import re
from html.parser import HTMLParser

import numpy as np
import pytest
import torch

from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.errors import DatasetError
from codeslam.eval.slam_run import evaluate_run
from codeslam.recon.fusion import PointCloud
from codeslam.recon.ply import write_ply
from codeslam.report import build_html, load_run, report_figures, write_report
from codeslam.report.figures import MAX_MAP_POINTS, panel_keyframes, subsample, view_axes
from codeslam.report.html import failure_counts
from codeslam.report.run import frame_statuses, mapping_text

N, H, W = 30, 12, 16


def _circle_poses(n: int) -> np.ndarray:
    """(n, 4, 4) upright cameras (image-down = world -z) on a circle of radius 1 at height 1.5, looking along it."""
    T = np.tile(np.eye(4), (n, 1, 1))
    for k, th in enumerate(np.linspace(0, 1.5, n)):
        fwd = np.array([-math.sin(th), math.cos(th), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        T[k, :3, :3] = np.stack([np.cross(down, fwd), down, fwd], axis=1)  # columns x (right), y (down), z
        T[k, :3, 3] = [math.cos(th), math.sin(th), 1.5]
    return T


def _make_run(root, with_gt: bool = True, with_frames_csv: bool = False, npz_extra: bool = False):
    """A run folder as the SLAM runner writes it: the estimate is the ground truth seen from the first camera,
    scaled by 0.8, with a little noise."""
    root.mkdir(parents=True, exist_ok=True)
    stamps = np.arange(N) / 30.0
    gt = _circle_poses(N)
    est = np.linalg.inv(gt[0]) @ gt
    est[:, :3, 3] *= 0.8
    est[:, :3, 3] += np.random.default_rng(0).normal(scale=0.002, size=(N, 3))
    est_traj, gt_traj = Trajectory(stamps, est), Trajectory(stamps, gt)
    write_tum(root / "trajectory.txt", est_traj)
    kf = [0, 9, 18, 27]
    summary = {"dataset": "hand-made", "format": "tum", "frames": N, "first_frame": 0, "last_frame": N - 1,
               "keyframes": len(kf), "keyframe_frames": kf, "tracking_failures": 2, "failed_frames": [12, 13],
               "marginalised": 0, "width": W, "height": H, "fps": 3.5, "fps_with_io": 3.4, "wall_s": 8.8,
               "ms_per_frame": {"read": 1.0, "track": 100.0, "window": 150.0},
               "ms_per_keyframe": {"window": 1000.0}, "depth_model": "network"}
    if with_gt:
        write_tum(root / "groundtruth.txt", gt_traj)
        summary.update(evaluate_run(est_traj, gt_traj))
    (root / "result.json").write_text(json.dumps(summary))
    depth = np.full((len(kf), H, W), 2.0, dtype=np.float32) + np.linspace(0, 1, W, dtype=np.float32)
    arrays = {"id": np.arange(len(kf)), "frame_index": np.array(kf), "timestamp": stamps[kf], "T_wc": est[kf],
              "code": np.zeros((len(kf), 8)), "depth": depth,
              "image": np.random.default_rng(1).random((len(kf), 3, H, W)).astype(np.float32),
              "camera": np.array([20.0, 20.0, (W - 1) / 2, (H - 1) / 2, W, H])}
    if npz_extra:
        arrays["depth_zero"] = depth * 1.1
        arrays["uncertainty"] = np.full_like(depth, 0.1)
        gt_depth = depth * 0.9
        gt_depth[1] = np.nan  # no ground truth for keyframe 1
        arrays["depth_gt"] = gt_depth
    np.savez_compressed(root / "keyframes.npz", **arrays)
    xyz = np.random.default_rng(2).normal(size=(500, 3)).astype(np.float32) + [0, 0, 2]
    write_ply(root / "map.ply", PointCloud(torch.from_numpy(xyz), torch.full((500, 3), 128, dtype=torch.uint8)))
    if with_frames_csv:
        with open(root / "frames.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["frame", "timestamp", "status", "reason", "is_keyframe", "keyframe_reason", "inlier_ratio"])
            for i in range(N):
                status = "initialising" if i == 0 else "predicted" if i in (12, 13) else "tracked"
                reason = "too few inliers" if i == 12 else "residual too high" if i == 13 else ""
                w.writerow([i, stamps[i], status, reason, int(i in kf), "baseline" if i in kf[1:] else "",
                            "" if i == 0 else 0.8])
    return root


def _scripts(page: str) -> list[tuple[dict, str]]:
    """(attributes, text) of every <script> element, parsed as a browser does (script text is not markup)."""
    out = []

    class Parser(HTMLParser):
        def handle_starttag(self, tag, attrs):
            if tag == "script":
                out.append((dict(attrs), ""))

        def handle_data(self, data):
            if self.lasttag == "script" and out:
                out[-1] = (out[-1][0], out[-1][1] + data)

    Parser().feed(page)
    return out


def test_report_with_ground_truth_has_metrics_and_every_figure(tmp_path):
    root = _make_run(tmp_path / "run")
    path = write_report(root)
    assert path == root / "report.html"
    page = path.read_text()
    summary = json.loads((root / "result.json").read_text())
    assert "Accuracy against ground truth" in page
    # the numbers of result.json, beside the never-moving camera's
    for key in ("ate_se3_rmse", "ate_sim3_rmse", "no_motion_ate_rmse_aligned", "no_motion_ate_rmse", "rpe_trans_rmse"):
        assert f"{summary[key]:.4f}" in page, key
    assert f"{summary['rot_err_rmse_deg']:.3f} RMSE" in page
    ids = re.findall(r'<div id="(fig-[a-z]+)" class="plotly-graph-div"', page)
    assert ids == ["fig-trajectory", "fig-drift", "fig-status", "fig-keyframes", "fig-map"]
    # self-contained: plotly.js inline once (the largest script), then one small script per figure, none loaded
    scripts = _scripts(page)
    assert len(scripts) == 1 + len(ids) and not any("src" in attrs for attrs, _ in scripts)
    sizes = sorted(len(text) for _, text in scripts)
    assert sizes[-1] > 1_000_000 and sizes[-2] < 1_000_000
    assert not list(root.glob(".report.html.*"))  # no temporary left behind


def test_report_without_ground_truth_has_no_metrics_section(tmp_path):
    root = _make_run(tmp_path / "run", with_gt=False)
    run = load_run(root)
    assert run.groundtruth is None and not run.has_metrics and run.frames is None
    page = build_html(run)
    assert "Accuracy against ground truth" not in page and "never-moving" not in page
    assert [i for i, _, _ in report_figures(run)] == ["fig-trajectory", "fig-status", "fig-keyframes", "fig-map"]
    assert "no ground truth" in page


def test_statuses_come_from_frames_csv_when_the_run_has_one(tmp_path):
    run = load_run(_make_run(tmp_path / "a", with_frames_csv=True))
    idx, status, reason = frame_statuses(run)
    assert list(idx) == list(range(N)) and status[12] == "predicted" and reason[13] == "residual too high"
    assert failure_counts(run) == ({"too few inliers": 1, "residual too high": 1}, "frames.csv")
    assert np.isnan(run.frames["inlier_ratio"][0]) and run.frames["inlier_ratio"][1] == 0.8
    # without it, from result.json's failed frames
    run = load_run(_make_run(tmp_path / "b"))
    idx, status, _ = frame_statuses(run)
    assert list(idx) == list(range(N)) and status[0] == "initialising"
    assert [i for i, s in zip(idx, status) if s == "failed"] == [12, 13]
    assert failure_counts(run) == ({"reason not recorded": 2}, "result.json")
    run.summary["failures_by_reason"] = {"lost": 2}
    assert failure_counts(run) == ({"lost": 2}, "result.json")


def test_keyframe_panels_show_what_the_run_stored(tmp_path):
    run = load_run(_make_run(tmp_path / "a"))  # depth and image only
    fig = dict((i, f) for i, f, _ in report_figures(run))["fig-keyframes"]
    title = fig.layout.title.text
    assert "not available in this run: zero-code depth, uncertainty, ground-truth depth" in title
    run = load_run(_make_run(tmp_path / "b", npz_extra=True))
    fig = dict((i, f) for i, f, _ in report_figures(run))["fig-keyframes"]
    titles = [a.text for a in fig.layout.annotations]
    assert "not available in this run" not in fig.layout.title.text
    assert titles.count("ground-truth depth: not available") == 1  # keyframe 1 has none
    assert "uncertainty" in titles and "zero-code depth" in titles


def test_a_camera_that_never_moved_and_an_empty_map_still_give_a_report(tmp_path, recwarn):
    root = _make_run(tmp_path / "static", with_gt=False)
    write_tum(root / "trajectory.txt", Trajectory(np.arange(N) / 30.0, np.tile(np.eye(4), (N, 1, 1))))
    kf = dict(np.load(root / "keyframes.npz"))
    kf["T_wc"], kf["depth"] = np.tile(np.eye(4), (4, 1, 1)), np.full_like(kf["depth"], np.nan)
    np.savez(root / "keyframes.npz", **kf)
    (root / "map.ply").unlink()
    page = write_report(root).read_text()
    assert 'id="fig-map"' in page and 'id="fig-keyframes"' in page
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_map_points_keep_their_colours_and_the_figure_is_valid_plotly(tmp_path):
    import plotly.graph_objects as go

    root = _make_run(tmp_path / "run")
    rgb = np.random.default_rng(3).integers(0, 256, size=(500, 3)).astype(np.uint8)
    xyz = np.random.default_rng(2).normal(size=(500, 3)).astype(np.float32)
    write_ply(root / "map.ply", PointCloud(torch.from_numpy(xyz), torch.from_numpy(rgb)))
    fig = {i: f for i, f, _ in report_figures(load_run(root))}["fig-map"]
    cloud = fig["data"][0]
    assert cloud["type"] == "scatter3d" and cloud["mode"] == "markers"
    expected = [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in rgb.tolist()]  # 500 points: none left out
    assert cloud["marker"]["color"] == expected
    go.Figure(fig)  # what was added unvalidated passes plotly's validation
    page = write_report(root).read_text()
    assert all(c in page for c in expected[:20])


def test_view_axes_find_up_from_upright_cameras():
    gt = _circle_poses(20)
    e1, e2, up = view_axes(gt)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(np.stack([e1, e2, up]) @ np.stack([e1, e2, up]).T, np.eye(3), atol=1e-9)
    assert np.linalg.det(np.stack([e1, e2, up])) > 0
    est = np.linalg.inv(gt[0]) @ gt  # seen from the first camera: image-down is +y, so up is -y
    np.testing.assert_allclose(view_axes(est)[2], [0, -1, 0], atol=1e-9)


def test_helpers_cap_points_and_spread_keyframes():
    cloud = PointCloud(torch.zeros(MAX_MAP_POINTS + 10, 3), torch.zeros(MAX_MAP_POINTS + 10, 3, dtype=torch.uint8))
    assert len(subsample(cloud)[0]) == MAX_MAP_POINTS
    assert panel_keyframes(3) == [0, 1, 2] and panel_keyframes(10) == [0, 3, 6, 9]


def test_a_folder_that_is_not_a_run_is_a_one_line_error(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        load_run(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="result.json is missing"):
        write_report(tmp_path / "empty")
    assert not (tmp_path / "empty" / "report.html").exists()
    root = _make_run(tmp_path / "bad")
    (root / "result.json").write_text("{not json")
    with pytest.raises(DatasetError, match="cannot read"):
        write_report(root)
    assert not (root / "report.html").exists()


def test_the_mapping_line_says_when_parallel_mapping_fell_behind(tmp_path):
    """The summary's and the report's line on the window solves: counts as the run stored them, and the hint to
    map sequentially only where parallel mapping cut more than half of its solves short, and the option that takes
    the keyframes it refused only where it refused some."""
    behind = {"window_solves": 50, "cut_short": 47, "cut_before_first_iteration": 18, "median_iterations": 2.0,
              "refused_busy": 0}
    text = mapping_text({"mapping": "parallel", "mapping_statistics": behind})
    assert "50 window solves" in text and "47 cut short" in text and "18 before their first" in text
    assert "--sequential" in text
    assert "--sequential" not in mapping_text({"mapping": "parallel",
                                               "mapping_statistics": {**behind, "cut_short": 20}})
    assert mapping_text({"mapping": "sequential",
                         "mapping_statistics": {**behind, "cut_short": 0, "cut_before_first_iteration": 0}}) == (
        "sequential: 50 window solves, median 2 iterations")
    assert mapping_text({"mapping": "sequential"}) is None  # a run from before the statistics
    refused = mapping_text({"mapping": "parallel", "mapping_statistics": {**behind, "refused_busy": 77}})
    assert ("77 frames asked for a keyframe while the mapping thread was busy (keyframes: {take_when_busy: true}"
            in refused)
    assert "take_when_busy" not in text  # none refused: no hint
    undone = mapping_text({"mapping": "sequential", "window_rollbacks": 11,
                           "mapping_statistics": {**behind, "cut_short": 0, "cut_before_first_iteration": 0}})
    assert undone.startswith("sequential: 50 window solves, median 2 iterations; 11 undone by the window's checks")
    root = _make_run(tmp_path / "run")
    s = json.loads((root / "result.json").read_text())
    (root / "result.json").write_text(json.dumps({**s, "mapping": "parallel", "mapping_statistics": behind}))
    assert text in build_html(load_run(root))
    assert "window solves" not in build_html(load_run(_make_run(tmp_path / "old")))  # a run from before it


def test_the_map_scale_line_says_when_the_window_left_the_networks_scale(tmp_path):
    """``map_scale``: keyframe depths over the network's zero code (and the dataset's depth); the hint only
    outside MAP_SCALE_HINT, nothing for a run from before it."""
    from codeslam.report.run import map_scale_text

    walk = {"keyframes": 49, "depth_over_prior": 0.5, "depth_over_truth": 0.46}
    text = map_scale_text({"map_scale": walk})
    assert text.startswith("keyframe depths 0.50 x the network's zero-code prediction (median over 49 keyframes)")
    assert "0.46 x the dataset's depth" in text and "moved the map's scale away" in text
    held = map_scale_text({"map_scale": {**walk, "depth_over_prior": 1.02, "depth_over_truth": None}})
    assert held == "keyframe depths 1.02 x the network's zero-code prediction (median over 49 keyframes)"
    assert map_scale_text({}) is None and map_scale_text({"map_scale": None}) is None
    root = _make_run(tmp_path / "run")
    s = json.loads((root / "result.json").read_text())
    (root / "result.json").write_text(json.dumps({**s, "map_scale": walk}))
    assert html.escape(text) in build_html(load_run(root))

