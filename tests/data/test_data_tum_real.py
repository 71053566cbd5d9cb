"""The TUM reader and `codeslam info` on the real 190-frame fr1/rpy subset (../shared/data/tum_fr1_rpy);
expected values come from that folder's README."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.cli import main
from codeslam.data.trajectory import read_tum
from codeslam.data.tum import TUM_ROS_DEFAULT, TumSequence


def test_codeslam_info_on_tum_rpy(tum_rpy, tmp_path, capsys):
    out_json = tmp_path / "info.json"
    assert main(["info", str(tum_rpy), "--json", str(out_json)]) == 0
    out, err = capsys.readouterr()
    assert "190" in out and "640 x 480" in out
    assert err == ""
    info = json.loads(out_json.read_text())
    assert info["format"] == "tum"
    assert info["frames"] == 190
    assert (info["width"], info["height"]) == (640, 480)
    assert info["has_depth"] and info["has_pose"] and info["frames_with_pose"] == 190
    # calib.txt: the calibrated fr1 camera; its distortion is removed by the reader.
    assert (info["fx"], info["fy"], info["cx"], info["cy"]) == (517.3, 516.5, 318.6, 255.3)
    assert info["distortion"] == [0.2624, -0.9531, -0.0054, 0.0026, 1.1633] and info["undistorted"]
    assert info["duration_s"] == pytest.approx(1305031238.829730 - 1305031232.525781, abs=1e-6)
    # README: "the camera moves about 0.62 m in total" (100 Hz ground truth); sampled at the ~30 Hz
    # frames the polyline is a little shorter.
    assert 0.55 < info["gt_path_length_m"] <= 0.63
    # README: first frame valid depth between 0.68 and 2.58 m.
    first = info["first_frame"]
    assert first["depth_min_m"] == pytest.approx(0.68, abs=0.01)
    assert first["depth_max_m"] == pytest.approx(2.58, abs=0.01)
    assert first["timestamp"] == 1305031232.525781


def test_tum_rpy_association_and_poses(tum_rpy):
    seq = TumSequence(tum_rpy, undistort=False)
    assert len(seq) == 190
    # README: colour and depth differ by at most 14 ms (mean 9 ms).
    dt = np.abs(seq.timestamps - seq.depth_timestamps)
    assert dt.max() <= 0.0145 and 0.005 < dt.mean() < 0.012
    # the files behind each frame, as associated: named by their own stamps
    assert len(seq.image_files) == len(seq.depth_files) == 190
    assert all(abs(float(f.stem) - t) < 1e-6 for f, t in zip(seq.image_files, seq.timestamps))
    assert all(abs(float(f.stem) - t) < 1e-6 for f, t in zip(seq.depth_files, seq.depth_timestamps))
    # README: the nearest ground-truth pose is at most 3.5 ms from each frame; the interpolated pose
    # must be close to it (the camera moves slowly over 3.5 ms).
    gt = read_tum(tum_rpy / "groundtruth.txt")
    for i in (0, 95, 189):
        j = int(np.argmin(np.abs(gt.timestamps - seq.timestamps[i])))
        assert abs(gt.timestamps[j] - seq.timestamps[i]) <= 0.0036
        P = seq.gt_poses[i]
        assert float((P[:3, 3] - gt.poses[j, :3, 3]).norm()) < 0.01
        assert float((P[:3, :3] - gt.poses[j, :3, :3]).abs().max()) < 0.02


def test_tum_rpy_first_frame_raw_values(tum_rpy):
    seq = TumSequence(tum_rpy, undistort=False)
    f = seq[0]
    assert f.image.shape == (3, 480, 640) and f.depth.shape == (480, 640)
    rgb_name = (tum_rpy / "rgb.txt").read_text().splitlines()[3].split()[1]
    raw = np.asarray(Image.open(tum_rpy / rgb_name), dtype=np.float32) / 255.0
    np.testing.assert_array_equal(f.image.permute(1, 2, 0).numpy(), raw)
    raw_d = np.asarray(Image.open(seq.depth_files[0]), dtype=np.float32) / 5000.0
    np.testing.assert_allclose(f.depth.numpy(), raw_d, rtol=1e-6)
    # README: about 72% of the first frame's pixels have depth.
    assert 0.68 < float((f.depth > 0).float().mean()) < 0.76


def test_tum_rpy_undistorted_frame_and_ros_default(tum_rpy):
    und = TumSequence(tum_rpy)
    f = und[0]
    assert f.camera == und.camera and not f.camera.has_distortion
    valid = f.depth[f.depth > 0]
    assert 0.68 <= float(valid.min()) and float(valid.max()) <= 2.59  # nearest: no new depth values
    ros = TumSequence(tum_rpy, camera=TUM_ROS_DEFAULT)
    assert ros.camera == TUM_ROS_DEFAULT and not ros.undistort
    assert torch.equal(ros[0].depth, TumSequence(tum_rpy, undistort=False)[0].depth)
