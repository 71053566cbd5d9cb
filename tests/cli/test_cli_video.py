"""`codeslam slam video.mp4`: a short video rendered by the generator and encoded with PyAV (`codeslam synth
--video`) runs through SLAM to a trajectory, a map and a report without ground truth, the field-of-view guess stated;
bad video input is one line and leaves no output folder. A tiny random network keeps it fast (the accuracy is the
demo test's business)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from codeslam.cli import main
from codeslam.data.registry import open_dataset
from codeslam.data.trajectory import read_tum
from codeslam.data.video import VideoSequence
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import save_weights
from codeslam.recon.ply import read_ply

FRAMES, FPS = 16, 30


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """(a 16-frame MP4 of a generator room at 30 frames/s, tiny network weights, the generator's folder), the video
    rendered and encoded by `codeslam synth --video`."""
    root = tmp_path_factory.mktemp("clip")
    assert main(["synth", str(root / "seq"), "--frames", str(FRAMES), "--seed", "3", "--size", "128x96", "--video",
                 "-q"]) == 0
    video, folder = root / "seq" / "scene_000.mp4", root / "seq" / "scene_000"
    frames = VideoSequence(video, fov=60)
    assert len(frames) == FRAMES and frames.video_fps == FPS
    for i in (0, FRAMES - 1):  # the video holds the rendered frames
        rendered = open_dataset(folder)[i].image
        assert float((frames[i].image - rendered).abs().mean()) < 0.03
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
                                    full_res_channels=4, bottleneck_channels=4, fc_units=16))
    save_weights(root / "tiny.safetensors", net)
    return video, root / "tiny.safetensors", folder


def test_slam_on_a_video_ends_with_trajectory_map_and_report(clip, tmp_path, capsys):
    video, weights, _ = clip
    out = tmp_path / "run"
    rc = main(["slam", str(video), "--fov", "60", "--fps", "15", "--out", str(out), "--weights", str(weights),
               "-q", "--threads", "1"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    traj = read_tum(out / "trajectory.txt")
    np.testing.assert_allclose(traj.timestamps, np.arange(0, FRAMES, 2) / FPS, atol=1e-6)  # --fps 15 of 30
    assert len(read_ply(out / "map.ply")) > 0
    summary = json.loads((out / "result.json").read_text())
    assert summary["format"] == "video" and summary["fov_guess_deg"] == 60 and summary["video_fps"] == FPS
    assert "ate_se3_rmse" not in summary and "evaluation_error" not in summary  # no ground truth, no error
    assert "60 deg horizontal field of view" in summary["camera"] and "60 deg" in captured.out
    page = (out / "report.html").read_text()
    assert "60 deg horizontal field of view" in page  # the guess is stated in the report too
    assert "Accuracy against ground truth" not in page and 'id="fig-map"' in page
    assert not (out / "groundtruth.txt").exists()


def _one_line_error(capsys, argv, needle):
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip()
    lines = [ln for ln in err.splitlines() if not ln.startswith("codeslam: warning:")]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("codeslam: error:"), err
    assert needle in lines[0] and "Traceback" not in err, err
    return lines[0]


def test_bad_video_input_is_one_line_and_writes_nothing(clip, tmp_path, capsys):
    video, weights, folder = clip
    out = tmp_path / "out"
    run = ["--out", out, "--weights", weights, "-q"]
    _one_line_error(capsys, ["slam", tmp_path / "missing.mp4", *run], "not found")
    _one_line_error(capsys, ["synth", tmp_path / "odd", "--size", "65x48", "--video"], "even width and height")
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00\x00\x00\x18ftypmp42 but nothing else")
    _one_line_error(capsys, ["slam", broken, *run], "cannot read video")
    _one_line_error(capsys, ["slam", video, "--fov", "200", *run], "--fov")
    _one_line_error(capsys, ["slam", video, "--fps", "0", *run], "--fps")
    _one_line_error(capsys, ["slam", video, "--every", "0", *run], "--every")
    _one_line_error(capsys, ["slam", folder, "--fov", "60", *run], "video file only")
    cam = tmp_path / "camera.yaml"
    cam.write_text("fx: wide\nfy: 100\ncx: 63.5\ncy: 47.5\n")
    _one_line_error(capsys, ["slam", video, "--camera", cam, *run], "'fx' must be a positive number")
    _one_line_error(capsys, ["slam", video, "--camera", cam, "--fov", "60", *run], "not both")
    _one_line_error(capsys, ["slam", video, "--camera", tmp_path / "nope.yaml", *run], "not found")
    assert not out.exists()
