"""scripts/sequence_copy.py: the copies of a sequence played backwards, there and back, or seen by a camera upside
down, that the SLAM probes of a camera coming back the way it went and of a sensor read bottom up run on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from codeslam.data.tum import TumSequence

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "sequence_copy.py"


def _sequence(root: Path, n: int, calib: str = "10 10 4 3", size: tuple[int, int] = (8, 6)) -> None:
    """``n`` frames at 10 frames/s with jittered stamps, depth 5 ms off the colour, a pose per frame; textured
    images of ``size`` (W, H)."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, depth, gt = [], [], []
    for i in range(n):
        t = 1.0 + 0.1 * i + (0.01 if i == 2 else 0.0)
        w, h = size
        texture = np.random.default_rng(i).integers(0, 256, (h, w, 3), dtype=np.uint8)
        cv2.imwrite(str(root / "rgb" / f"{t:.3f}.png"), cv2.GaussianBlur(texture, (0, 0), 1.5))
        cv2.imwrite(str(root / "depth" / f"{t + 0.005:.3f}.png"),
                    (5000 + 100 * i + 7 * np.arange(h * w).reshape(h, w)).astype(np.uint16))
        rgb.append(f"{t:.3f} rgb/{t:.3f}.png\n")
        depth.append(f"{t + 0.005:.3f} depth/{t + 0.005:.3f}.png\n")
        gt.append(f"{t:.3f} {i} {2 * i} 0 0.1 0.2 0.3 0.927362\n")
    (root / "rgb.txt").write_text("# colour\n" + "".join(rgb))
    (root / "depth.txt").write_text("".join(depth))
    (root / "groundtruth.txt").write_text("".join(gt))
    (root / "calib.txt").write_text(calib + "\n")


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


@pytest.mark.parametrize("order, want", [("reverse", [3, 2, 1, 0]), ("there-and-back", [0, 1, 2, 3, 2, 1, 0])])
def test_the_copy_plays_each_frame_with_its_own_depth_and_pose_in_the_new_order_as_time_runs_on(
        tmp_path, order, want):
    _sequence(tmp_path / "src", 4)
    done = _run(tmp_path / "src", tmp_path / "out", "--order", order)
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    assert len(out) == len(want)
    assert np.allclose(np.diff(out.timestamps), 0.1)  # the median interval, evenly: time runs forwards
    assert out.timestamps[0] == pytest.approx(1.0)
    for j, i in enumerate(want):
        a, b = src.frame(i), out.frame(j)
        assert torch.equal(a.image, b.image) and torch.equal(a.depth, b.depth)
        assert torch.allclose(a.pose, b.pose, atol=1e-9)
    assert not list(tmp_path.glob("out.*"))  # no temporary folder left beside it


@pytest.mark.parametrize("order, want", [
    ("there-and-back", [0, 1, 2, 3, 2, 1, 0, 1, 2, 3, 2, 1, 0]),  # two loops, the first frame once between them
    ("forward", [0, 1, 2, 3, 0, 1, 2, 3]),
])
def test_a_repeated_order_plays_every_frame_again_as_hard_links_while_time_runs_on(tmp_path, order, want):
    _sequence(tmp_path / "src", 4)
    done = _run(tmp_path / "src", tmp_path / "out", "--order", order, "--repeat", 2)
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    assert len(out) == len(want)
    assert np.allclose(np.diff(out.timestamps), 0.1)
    for j, i in enumerate(want):
        a, b = src.frame(i), out.frame(j)
        assert torch.equal(a.image, b.image) and torch.equal(a.depth, b.depth)
        assert torch.allclose(a.pose, b.pose, atol=1e-9)
    first = {}  # a frame shown again is its first copy's file: the copy takes the source's space once
    for kind, files in (("rgb", out.image_files), ("depth", out.depth_files)):
        for j, i in enumerate(want):
            ino = files[j].stat().st_ino
            assert first.setdefault((kind, i), ino) == ino
        assert len({f.stat().st_ino for f in files}) == 4


def test_a_repeat_below_one_is_a_one_line_error(tmp_path):
    _sequence(tmp_path / "src", 3)
    done = _run(tmp_path / "src", tmp_path / "out", "--repeat", 0)
    assert done.returncode == 2 and "--repeat" in done.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "out").exists()


def test_a_missing_sequence_is_a_one_line_error_and_writes_nothing(tmp_path):
    done = _run(tmp_path / "nowhere", tmp_path / "out", "--order", "reverse")
    assert done.returncode == 2
    assert "nowhere" in done.stderr.strip().splitlines()[-1] and "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists()


def test_upside_down_every_world_point_lands_on_the_mirrored_pixel_with_the_same_depth(tmp_path):
    """The copy's image, depth, calibration and pose are one camera turned by 180 degrees: a point seen at pixel
    (u, v) of a source frame is seen at (W - 1 - u, H - 1 - v) of the copy's frame, and the frames the reader
    gives (undistorted) are the source's turned, also with lens distortion (tangential terms negated)."""
    calib = "40 42 30.5 21 0.05 -0.02 0.004 -0.003"
    _sequence(tmp_path / "src", 3, calib, size=(64, 48))
    done = _run(tmp_path / "src", tmp_path / "out", "--upside-down")
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    assert np.array_equal(src.timestamps, out.timestamps)
    cam_a, cam_b = src.frame(0).camera, out.frame(0).camera
    X = torch.tensor([0.4, -0.3, 2.5, 1.0], dtype=torch.float64)  # a world point
    for i in range(3):
        a, b = src.frame(i), out.frame(i)
        xa = torch.linalg.inv(a.pose) @ X
        xb = torch.linalg.inv(b.pose) @ X
        ua, va = cam_a.fx * xa[0] / xa[2] + cam_a.cx, cam_a.fy * xa[1] / xa[2] + cam_a.cy
        ub, vb = cam_b.fx * xb[0] / xb[2] + cam_b.cx, cam_b.fy * xb[1] / xb[2] + cam_b.cy
        assert float(xa[2]) == pytest.approx(float(xb[2]))  # the same depth
        assert float(ub) == pytest.approx(63 - float(ua)) and float(vb) == pytest.approx(47 - float(va))
        inner = (slice(None), slice(6, -6), slice(6, -6))  # where undistortion interpolates inside both images
        assert (b.image - a.image.flip(1, 2))[inner].abs().max() < 2e-3
        assert torch.equal(b.depth[6:-6, 6:-6] > 0, a.depth.flip(0, 1)[6:-6, 6:-6] > 0)


@pytest.mark.parametrize("rotation", [90, 180])
def test_a_video_copy_turned_by_its_display_rotation_is_the_same_camera_turned(tmp_path, rotation):
    """``--video 90``: a phone's portrait video of the sequence. The reader turns its frames as a player does, the
    copy's camera.yaml and poses are that turned camera's (a point at (u, v) of the source is at (v, W - 1 - u)),
    and its frames say that the sensor's rows run along their columns."""
    from codeslam.data.trajectory import read_tum
    from codeslam.data.video import VideoSequence

    _sequence(tmp_path / "src", 3, "40 42 30.5 21", size=(64, 48))
    done = _run(tmp_path / "src", tmp_path / "out", "--video", rotation)
    assert done.returncode == 0, done.stderr
    src = TumSequence(tmp_path / "src")
    video = VideoSequence(tmp_path / "out" / "video.mp4", camera=tmp_path / "out" / "camera.yaml")
    gt = read_tum(tmp_path / "out" / "groundtruth.txt")
    assert len(video) == len(gt) == 3 and np.allclose(gt.timestamps, video.timestamps, atol=1e-3)
    cam_a, cam_b = src.camera, video.camera
    X = torch.tensor([0.4, -0.3, 2.5, 1.0], dtype=torch.float64)
    for i in range(3):
        a, b = src.frame(i), video.frame(i)
        assert b.readout_axis == ("columns" if rotation == 90 else "rows")
        assert (b.image - torch.rot90(a.image, rotation // 90, (1, 2))).abs().mean() < 0.03  # H.264 near-lossless
        xa, xb = torch.linalg.inv(a.pose) @ X, torch.linalg.inv(gt.poses[i]) @ X
        ua, va = cam_a.fx * xa[0] / xa[2] + cam_a.cx, cam_a.fy * xa[1] / xa[2] + cam_a.cy
        ub, vb = cam_b.fx * xb[0] / xb[2] + cam_b.cx, cam_b.fy * xb[1] / xb[2] + cam_b.cy
        want = (float(va), 63 - float(ua)) if rotation == 90 else (63 - float(ua), 47 - float(va))
        assert (float(ub), float(vb)) == pytest.approx(want)


def test_a_held_frame_is_shown_again_with_fresh_noise_at_its_own_depth_and_pose_as_time_runs_on(tmp_path):
    _sequence(tmp_path / "src", 4)
    done = _run(tmp_path / "src", tmp_path / "out", "--hold", "1:3", "--hold-noise", 2.0)
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    want = [0, 1, 1, 1, 1, 2, 3]
    assert len(out) == len(want)
    assert np.allclose(np.diff(out.timestamps), 0.1)  # the camera stands still for three frame intervals
    noise = []
    for j, i in enumerate(want):
        a, b = src.frame(i), out.frame(j)
        assert torch.equal(a.depth, b.depth) and torch.allclose(a.pose, b.pose, atol=1e-9)
        if j in (2, 3, 4):
            noise.append(255.0 * (b.image - a.image))
        else:
            assert torch.equal(a.image, b.image)
    noise = torch.stack(noise)
    assert 1.0 < float(noise.std()) < 3.0  # 2 grey levels, rounded to whole ones
    assert not torch.equal(noise[0], noise[1])  # each held frame its own noise
    quiet = _run(tmp_path / "src", tmp_path / "quiet", "--hold", "1:3", "--hold-noise", 0)
    assert quiet.returncode == 0, quiet.stderr
    copy = TumSequence(tmp_path / "quiet")
    assert all(torch.equal(copy.frame(j).image, src.frame(1).image) for j in (2, 3, 4))


@pytest.mark.parametrize("hold", ["4:2", "1", "a:b", "1:-1"])
def test_a_hold_outside_the_copy_is_a_one_line_error_and_writes_nothing(tmp_path, hold):
    _sequence(tmp_path / "src", 4)
    done = _run(tmp_path / "src", tmp_path / "out", "--hold", hold)
    assert done.returncode == 2 and "--hold" in done.stderr.strip().splitlines()[-1]
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


@pytest.mark.parametrize("contrast", [45.0, 0.0])
def test_an_occluder_sweeps_left_to_right_over_its_frames_and_leaves_depth_poses_and_other_frames(tmp_path, contrast):
    _sequence(tmp_path / "src", 5, size=(40, 30))
    done = _run(tmp_path / "src", tmp_path / "out", "--occluder", "1:3", "--occluder-width", 0.25,
                "--occluder-contrast", contrast)
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    assert len(out) == 5 and np.allclose(out.timestamps, src.timestamps)
    centres = []
    for i in range(5):
        a, b = src.frame(i), out.frame(i)
        assert torch.equal(a.depth, b.depth) and torch.allclose(a.pose, b.pose, atol=1e-9)
        changed = (a.image != b.image).any(0).any(0)  # (W,) columns the band covers
        if i in (1, 2, 3):
            cols = torch.nonzero(changed).squeeze(1).float()
            assert 1 <= len(cols) <= 10  # at most a quarter of the 40 columns
            centres.append(float(cols.mean()))
            band = 255.0 * b.image[:, :, changed]
            assert abs(float(band.mean()) - 60.0) < 15.0
            assert (float(band.std()) > 15.0) == (contrast > 0)  # textured, or flat
        else:
            assert not changed.any()
    assert centres[0] < centres[1] < centres[2]  # left to right


@pytest.mark.parametrize("args", [["--occluder", "4:2"], ["--occluder", "x"], ["--occluder", "1:2", "--hold", "1:1"],
                                  ["--occluder", "1:2", "--occluder-width", "0"]])
def test_an_occluder_outside_the_copy_is_a_one_line_error_and_writes_nothing(tmp_path, args):
    _sequence(tmp_path / "src", 4)
    done = _run(tmp_path / "src", tmp_path / "out", *args)
    assert done.returncode == 2 and "--occluder" in done.stderr.strip().splitlines()[-1]
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()


def test_a_covered_lens_is_dark_noise_over_its_frames_while_depth_and_poses_go_on(tmp_path):
    _sequence(tmp_path / "src", 5)
    done = _run(tmp_path / "src", tmp_path / "out", "--cover", "1:2")
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    assert len(out) == 5 and np.allclose(out.timestamps, src.timestamps)  # the source's own time
    for i in range(5):
        a, b = src.frame(i), out.frame(i)
        assert torch.equal(a.depth, b.depth) and torch.allclose(a.pose, b.pose, atol=1e-9)
        if i in (1, 2):
            grey = 255.0 * b.image
            assert 2.0 < float(grey.mean()) < 4.0 and 0.5 < float(grey.std()) < 1.5
        else:
            assert torch.equal(a.image, b.image)
    assert not torch.equal(out.frame(1).image, out.frame(2).image)  # each its own noise


def test_played_frames_come_in_the_order_given_as_time_runs_on(tmp_path):
    _sequence(tmp_path / "src", 6)
    done = _run(tmp_path / "src", tmp_path / "out", "--play", "0:4,1:3,5")
    assert done.returncode == 0, done.stderr
    src, out = TumSequence(tmp_path / "src"), TumSequence(tmp_path / "out")
    want = [0, 1, 2, 3, 1, 2, 5]  # carried back from frame 3 to frame 1, then on to frame 5
    assert len(out) == len(want) and np.allclose(np.diff(out.timestamps), 0.1)
    for j, i in enumerate(want):
        a, b = src.frame(i), out.frame(j)
        assert torch.equal(a.image, b.image) and torch.equal(a.depth, b.depth)
        assert torch.allclose(a.pose, b.pose, atol=1e-9)


@pytest.mark.parametrize("args", [("--cover", "4:2"), ("--cover", "1"), ("--play", "0:9"), ("--play", "3:1"),
                                  ("--play", "a"), ("--play", "0:2", "--order", "reverse")])
def test_a_cover_or_play_outside_the_sequence_is_a_one_line_error_and_writes_nothing(tmp_path, args):
    _sequence(tmp_path / "src", 5)
    done = _run(tmp_path / "src", tmp_path / "out", *args)
    assert done.returncode == 2 and args[0] in done.stderr.strip().splitlines()[-1], done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "out").exists()
