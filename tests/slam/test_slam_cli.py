"""``codeslam slam`` and the runner: outputs on a synthetic TUM sequence and one-line errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from codeslam.cli import main
from codeslam.data.registry import open_dataset
from codeslam.data.trajectory import read_tum
from codeslam.recon.ply import read_ply
from codeslam.slam.config import load_config

CONFIG = (
    "tracker:\n  pyramid_levels: [2, 1, 0]\n  max_iterations: [8, 6, 5]\n"
    "keyframes:\n  min_baseline_ratio: 0.04\n"
    "window:\n  size: 3\n  sfm:\n    pyramid_levels: [2, 1, 0]\n    max_iterations: [6, 5, 4]\n"
)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A 20-frame synthetic TUM sequence at 64x48 written by ``codeslam synth``, and a one-frame one."""
    root = tmp_path_factory.mktemp("slam_cli")
    assert main(["synth", str(root / "seq"), "--scenes", "1", "--frames", "20", "--seed", "3", "--size", "64x48"]) == 0
    assert main(["synth", str(root / "one"), "--scenes", "1", "--frames", "1", "--seed", "4", "--size", "64x48"]) == 0
    (root / "slam.yaml").write_text(CONFIG)
    return root


def test_slam_cli_writes_a_tum_trajectory_and_a_summary(dataset, tmp_path, capsys):
    out, js = tmp_path / "out", tmp_path / "summary.json"
    seq_dir = dataset / "seq" / "scene_000"
    rc = main(["slam", str(seq_dir), "--depth-model", "standin", "--size", "64x48", "--config",
               str(dataset / "slam.yaml"), "--out", str(out), "--json", str(js), "--frames", "0:20:2", "-q",
               "--threads", "1"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    traj = read_tum(out / "trajectory.txt")
    seq = open_dataset(seq_dir)
    assert len(traj) == 10
    np.testing.assert_allclose(traj.timestamps, seq.timestamps[0:20:2], atol=1e-6)
    np.testing.assert_allclose(traj.poses[0].numpy(), np.eye(4), atol=1e-9)  # the map's origin
    kfs = read_tum(out / "keyframes.txt")
    summary = json.loads(js.read_text())
    assert len(kfs) == summary["keyframes"] >= 2
    for key in ("frames", "keyframes", "tracking_failures", "fps", "ate_se3_rmse", "ate_sim3_rmse", "sim3_scale",
                "no_motion_ate_rmse", "no_motion_ate_rmse_aligned", "rot_err_rmse_deg", "rpe_trans_rmse",
                "rpe_trans_sim3_rmse", "ms_per_frame", "depth_model"):
        assert key in summary, key
    assert summary["frames"] == 10 and summary["tracking_failures"] == 0
    assert summary["ate_se3_rmse"] < summary["no_motion_ate_rmse_aligned"]
    assert json.loads((out / "result.json").read_text())["ate_se3_rmse"] == summary["ate_se3_rmse"]
    resolved = load_config(out / "config.yaml")
    assert resolved.window.size == 3 and resolved.tracker.pyramid_levels == (2, 1, 0)
    with np.load(out / "keyframes.npz", allow_pickle=False) as npz:
        assert npz["depth"].shape == (summary["keyframes"], 48, 64)
        assert npz["T_wc"].shape == (summary["keyframes"], 4, 4) and npz["code"].shape[0] == summary["keyframes"]
    assert (out / "trajectory.png").stat().st_size > 0
    cloud = read_ply(out / "map.ply")
    assert len(cloud) > 1000 and np.isfinite(cloud.xyz.numpy()).all()
    assert "ATE SE(3)" in captured.out
    # the readout is estimated by default: 9 tracked frames are too few to decide it (the summary says so)
    rs = summary["rolling_shutter"]
    assert rs["readout"] is None and rs["decided_at_frame"] is None and rs["frames"] <= 9
    assert "rolling shutter" in captured.out and "not decided" in captured.out
    # the written trajectory's smoothing spline is stated, in result.json, the terminal and the report
    assert summary["trajectory_smoothing_s"] == 0.05
    # the summary table's cells as running text: a cell that wraps continues on the next row under a blank label
    text = " ".join(captured.out.replace("\u2502", " ").split())
    assert "positions smoothed over the whole run" in text
    assert "positions smoothed over the whole run" in (out / "report.html").read_text()
    # the window solves: one per keyframe after the first, none cut short in the (default) sequential mode
    stats = summary["mapping_statistics"]
    assert summary["mapping"] == "sequential" and stats["window_solves"] == summary["keyframes"] - 1
    assert stats["cut_short"] == stats["refused_busy"] == 0 and stats["median_iterations"] >= 1
    assert f"sequential: {stats['window_solves']} window solves, median {stats['median_iterations']:g}" in text
    # where the window left the map's scale, against the network's prediction and the dataset's depth
    scale = summary["map_scale"]
    assert scale["keyframes"] == summary["keyframes"] and 0 < scale["depth_over_prior"] < 10
    assert 0 < scale["depth_over_truth"] < 10
    assert f"keyframe depths {scale['depth_over_prior']:.2f} x the network's zero-code prediction" in text


def test_the_summary_says_how_the_readout_was_chosen():
    from codeslam.cli.slam import _readout_text

    base = {"frames": 40, "decided_at_frame": 48, "readout": 0.59}
    assert _readout_text(base) == "readout 0.59 of the frame interval (chosen at frame 48 from 40 turning frames)"
    assert _readout_text({**base, "readout": 0.0}) == "global shutter (chosen at frame 48 from 40 turning frames)"
    assert _readout_text({**base, "readout": -0.59}) == (
        "readout 0.59 of the frame interval, rows read bottom up (chosen at frame 48 from 40 turning frames)")
    assert _readout_text({**base, "frames": 25, "decided_at_frame": None, "readout": 0.0}) == (
        "global shutter (provisional, from 25 turning frames)")
    assert _readout_text({**base, "frames": 3, "decided_at_frame": None, "readout": None}) == (
        "readout not decided (3 turning frames, too few)")


def _one_line_error(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, (argv, err)
    assert err.startswith("codeslam: error:") and "\n" not in err and "Traceback" not in err, err
    return err


def test_bad_inputs_fail_with_one_line(dataset, tmp_path, capsys):
    seq_dir = str(dataset / "seq" / "scene_000")
    out = str(tmp_path / "out")
    standin = ["--depth-model", "standin", "--size", "64x48", "--out", out, "-q"]
    assert "not found" in _one_line_error(capsys, ["slam", str(tmp_path / "missing"), *standin])
    assert "outside" in _one_line_error(capsys, ["slam", seq_dir, "--frames", "0:500", *standin])
    assert "at least 2" in _one_line_error(capsys, ["slam", seq_dir, "--frames", "5:6", *standin])
    assert "at least 2" in _one_line_error(capsys, ["slam", str(dataset / "one" / "scene_000"), *standin])
    _one_line_error(capsys, ["slam", seq_dir, "--frames", "a:b", *standin])
    _one_line_error(capsys, ["slam", seq_dir, "--weights", str(tmp_path / "none.safetensors"), "--out", out, "-q"])
    _one_line_error(capsys, ["slam", seq_dir, "--viewer", "opengl", *standin])
    _one_line_error(capsys, ["slam", seq_dir, "--depth-model", "magic", "--out", out, "-q"])
    _one_line_error(capsys, ["slam", seq_dir, "--depth-model", "standin", "--size", "64", "--out", out, "-q"])
    _one_line_error(capsys, ["slam", seq_dir, "--device", "tpu", *standin])
    bad_cfg = tmp_path / "bad.yaml"
    bad_cfg.write_text("window:\n  size: 1\n")
    assert "window.size" in _one_line_error(capsys, ["slam", seq_dir, "--config", str(bad_cfg), *standin])
    assert not (tmp_path / "out" / "result.json").exists()  # nothing half-written


def test_rerun_viewer_without_rerun_is_one_line(dataset, tmp_path, capsys):
    pytest.importorskip("codeslam.viz.rerun_viewer")
    try:
        import rerun  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("rerun-sdk is installed")
    err = _one_line_error(capsys, ["slam", str(dataset / "seq" / "scene_000"), "--viewer", "rerun", "--depth-model",
                                   "standin", "--size", "64x48", "--out", str(tmp_path / "o"), "-q"])
    assert "rerun-sdk" in err


def test_true_prior_runs_the_network_jacobian_on_the_dataset_depth(dataset, tmp_path, capsys):
    """``--depth-model true-prior``: the shipped network's decoder with the zero code at the dataset's depth, stated
    as an oracle in the summary; it needs depth maps and takes --weights (the stand-in does not)."""
    from PIL import Image

    seq_dir = str(dataset / "seq" / "scene_000")
    out, js = tmp_path / "out", tmp_path / "s.json"
    rc = main(["slam", seq_dir, "--depth-model", "true-prior", "--config", str(dataset / "slam.yaml"), "--out",
               str(out), "--json", str(js), "--frames", "0:20:4", "-q", "--threads", "1"])
    assert rc == 0, capsys.readouterr().err
    summary = json.loads(js.read_text())
    assert summary["depth_model"].startswith("true-prior") and "oracle" in summary["depth_model"]
    assert summary["weights"] == "default" and summary["frames"] == 5 and summary["tracking_failures"] == 0
    with np.load(out / "keyframes.npz", allow_pickle=False) as npz:  # the zero code is the measured depth
        ok = npz["depth_gt"] > 0
        np.testing.assert_allclose(npz["depth_zero"][ok], npz["depth_gt"][ok], rtol=1e-3)
    images = tmp_path / "nodepth"
    (images / "images").mkdir(parents=True)
    for k in range(3):
        Image.fromarray(np.full((48, 64, 3), 60 * k + 20, np.uint8)).save(images / "images" / f"frame_{k:04d}.png")
    (images / "camera.yaml").write_text("fx: 50\nfy: 50\ncx: 31.5\ncy: 23.5\n")
    err = _one_line_error(capsys, ["slam", str(images), "--depth-model", "true-prior", "--out", str(out / "x"), "-q"])
    assert "needs a dataset with depth maps" in err
    err = _one_line_error(capsys, ["slam", seq_dir, "--depth-model", "standin", "--weights", str(tmp_path / "w"),
                                   "--out", str(out / "y"), "-q"])
    assert "--weights applies to --depth-model network and true-prior only" in err
