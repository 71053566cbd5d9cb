"""Every dataset reader on tiny folders written here (a few 32x24 frames), the registry, `codeslam info`,
and the bad-input corpus: each malformed folder must give one ``codeslam: error:`` line, never a traceback.

The writers below produce each format from known values (images, depths, poses), so every test checks
what the reader returns against what was written, including the coordinate conventions that are easy to
get wrong: EuRoC's body-to-camera extrinsics, SceneNet's ray-length depth and look-at poses, and
TartanAir's NED axes.
"""

from __future__ import annotations

import json
import math
import shutil
import struct
import sys

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from PIL import Image

from codeslam.cli import main
from codeslam.data.euroc import EurocSequence
from codeslam.data.euroc_csv import write_euroc_csv
from codeslam.data.folder import FolderSequence
from codeslam.data.imageio import DepthWarning, write_depth_png, write_rgb_png
from codeslam.data.registry import FORMATS, describe_dataset, detect_format, open_dataset
from codeslam.data.scenenet import SCENENET_CAMERA, SceneNetSequence, look_at_pose, ray_length_to_z
from codeslam.data.tartanair import TartanAirSequence, ned_to_optical
from codeslam.data.trajectory import Trajectory, tum_rows_from_poses, write_tum
from codeslam.data.tum import TUM_PRESETS, TUM_ROS_DEFAULT, TumSequence
from codeslam.errors import ConfigError, DatasetError
from codeslam.geometry.camera import PinholeCamera

W, H = 32, 24
CAM = PinholeCamera(30.0, 31.0, 15.5, 11.5, W, H)
T0 = 100.0


def _rot(axis: str, a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    R = {"x": [[1, 0, 0], [0, c, -s], [0, s, c]], "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
         "z": [[c, -s, 0], [s, c, 0], [0, 0, 1]]}[axis]
    return torch.tensor(R, dtype=torch.float64)


def motion(t: float) -> torch.Tensor:
    """A constant-velocity pose (4, 4): linear position and slerp reproduce it exactly."""
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = _rot("y", 0.4 * t) @ _rot("x", 0.3)
    T[:3, 3] = torch.tensor([0.2 * t, 0.05 * t, 1.0], dtype=torch.float64)
    return T


def _images(n: int, seed: int, w: int = W, h: int = H) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.rand(3, h, w, generator=g) for _ in range(n)]


def _depths(n: int, seed: int, w: int = W, h: int = H) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed + 1)
    out = []
    for _ in range(n):
        d = 0.5 + 3 * torch.rand(h, w, generator=g)
        d[0, :3] = 0.0  # a few invalid pixels
        out.append(d)
    return out


# ---------------------------------------------------------------------------------------------- writers


def write_tum_folder(root, n=4, depth=True, gt=True, calib="30 31 15.5 11.5", w=W, h=H, seed=0):
    (root / "rgb").mkdir(parents=True)
    stamps = T0 + np.arange(n) / 30.0
    imgs, deps = _images(n, seed, w, h), _depths(n, seed, w, h)
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for t, img, d in zip(stamps, imgs, deps):
        write_rgb_png(root / "rgb" / f"{t:.6f}.png", img)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        if depth:
            td = t + 0.004  # depth a little after colour, as in TUM
            write_depth_png(root / "depth" / f"{td:.6f}.png", d, 5000)
            depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    if depth:
        (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if calib is not None:
        (root / "calib.txt").write_text(calib + "\n")
    if gt:
        ts = np.arange(T0 - 0.1, stamps[-1] + 0.1, 0.01)
        write_tum(root / "groundtruth.txt", Trajectory(ts, torch.stack([motion(t - T0) for t in ts])))
    return {"stamps": stamps, "images": imgs, "depths": deps}


# EuRoC-like extrinsics: camera rotated ~90 deg about the body z axis and offset from the IMU.
T_BS = torch.eye(4, dtype=torch.float64)
T_BS[:3, :3] = _rot("z", math.pi / 2 + 0.02) @ _rot("x", 0.03)
T_BS[:3, 3] = torch.tensor([-0.0216, -0.0647, 0.0098], dtype=torch.float64)
NS0 = 1403636579763555584


def write_euroc_folder(root, n=3, dist=(0.0, 0.0, 0.0, 0.0), gt=True, T_bs=T_BS, intr=(30.0, 31.0, 15.5, 11.5)):
    cam = root / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    ns = NS0 + np.arange(n, dtype=np.int64) * 50_000_000
    lines = ["#timestamp [ns],filename"]
    greys = []
    for k, t in enumerate(ns):
        g = (np.random.default_rng(k).random((H, W)) * 255).astype(np.uint8)
        Image.fromarray(g).save(cam / "data" / f"{t}.png")
        greys.append(g)
        lines.append(f"{t},{t}.png")
    (cam / "data.csv").write_text("\n".join(lines) + "\n")
    data = ", ".join(f"{v:.12f}" for v in T_bs.flatten().tolist())
    (cam / "sensor.yaml").write_text(
        "# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\n\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n\nrate_hz: 20\nresolution: [{W}, {H}]\n"
        f"camera_model: pinhole\nintrinsics: [{', '.join(map(str, intr))}] #fu, fv, cu, cv\n"
        f"distortion_model: radial-tangential\ndistortion_coefficients: [{', '.join(map(str, dist))}]\n"
    )
    if gt:
        t_rel = np.arange(-0.05, n * 0.05 + 0.05, 0.005)
        body = torch.stack([motion(t) for t in t_rel])
        write_euroc_csv(root / "mav0" / "state_groundtruth_estimate0" / "data.csv",
                        Trajectory(NS0 / 1e9 + t_rel, body))
    return {"ns": ns, "greys": greys}


# SceneNet protobuf, encoded by hand from the dataset's scenenet.proto (field numbers and wire types),
# independently of the reader's run-time descriptor.
def _varint(n: int) -> bytes:
    out = b""
    while True:
        b = n & 0x7F
        n >>= 7
        out += bytes([b | (0x80 if n else 0)])
        if not n:
            return out


def _ld(field: int, payload: bytes) -> bytes:
    return _varint(field << 3 | 2) + _varint(len(payload)) + payload


def _f32(field: int, v: float) -> bytes:
    return _varint(field << 3 | 5) + struct.pack("<f", v)


def _int(field: int, v: int) -> bytes:
    return _varint(field << 3 | 0) + _varint(v)


def _position(field, xyz):
    return _ld(field, b"".join(_f32(k + 1, v) for k, v in enumerate(xyz)))


def _pose(field, camera, lookat, t):
    return _ld(field, _position(1, camera) + _position(2, lookat) + _f32(3, t))


def scenenet_trajectory(render_path: str, views: list[tuple]) -> bytes:
    """views: (frame_num, (cam_open, look_open, t_open), (cam_close, look_close, t_close))."""
    layout = _ld(1, _int(1, 4) + _ld(2, b"living_room/model.obj"))  # SceneLayout (not read)
    instance = _ld(2, _int(1, 0) + _ld(3, b"background"))  # Instance (not read)
    body = layout + instance
    for frame_num, o, c in views:
        body += _ld(3, _int(1, frame_num) + _pose(2, *o) + _pose(3, *c))
    body += _ld(4, render_path.encode())
    return _ld(1, body)  # Trajectories.trajectories


SN_CAM = SCENENET_CAMERA.resized(W, H)  # the same 60 x 45 deg camera at 32x24


def scenenet_ray_norm(w: int, h: int) -> np.ndarray:
    """|ray| per pixel from SceneNet's own convention: tan(fov/2) * (2 (x + 0.5) / width - 1), z = 1."""
    x = math.tan(math.radians(30)) * (2 * (np.arange(w) + 0.5) / w - 1)
    y = math.tan(math.radians(22.5)) * (2 * (np.arange(h) + 0.5) / h - 1)
    return np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1)


SN_VIEWS = [
    (0, ((1.0, 2.0, 3.0), (1.0, 2.0, 2.0), 0.0), ((1.25, 2.0, 3.0), (1.25, 2.0, 2.0), 0.5)),
    (25, ((1.5, 2.0, 3.0), (2.5, 2.0, 3.0), 1.0), ((1.5, 2.0, 3.0), (2.5, 2.0, 3.0), 1.5)),
]


def write_scenenet_folder(base, views=SN_VIEWS, render_path="0/7", z=2.0):
    root = base / "train" / render_path
    (root / "photo").mkdir(parents=True)
    (root / "depth").mkdir()
    (root / "instance").mkdir()
    ray_mm = np.rint(z * scenenet_ray_norm(W, H) * 1000).astype(np.uint16)  # a plane at z metres
    for k, (frame_num, _, _) in enumerate(views):
        arr = (np.random.default_rng(k).random((H, W, 3)) * 255).astype(np.uint8)
        Image.fromarray(arr).save(root / "photo" / f"{frame_num}.jpg")
        Image.fromarray(ray_mm).save(root / "depth" / f"{frame_num}.png")
    (base / "train" / "scenenet_rgbd_train_0.pb").write_bytes(
        scenenet_trajectory("0/3", views[:1]) + scenenet_trajectory(render_path, views)
    )
    return root


def write_tartanair_folder(root, poses_ned, depth=True):
    (root / "image_left").mkdir(parents=True)
    if depth:
        (root / "depth_left").mkdir()
    for k, img in enumerate(_images(len(poses_ned), 3)):
        write_rgb_png(root / "image_left" / f"{k:06d}_left.png", img)
        if depth:
            np.save(root / "depth_left" / f"{k:06d}_left_depth.npy", np.full((H, W), 1.5 + k, np.float32))
    rows = tum_rows_from_poses(torch.stack(poses_ned))
    (root / "pose_left.txt").write_text("\n".join(" ".join(f"{v:.9e}" for v in r) for r in rows) + "\n")


TA_CAM = PinholeCamera(16.0, 16.0, 16.0, 12.0, W, H)


def write_folder(root, names, yaml_text=None, depth_ext=None, poses=None):
    (root / "images").mkdir(parents=True)
    imgs = _images(len(names), 5)
    for name, img in zip(names, imgs):
        write_rgb_png(root / "images" / f"{name}.png", img)
    if depth_ext:
        (root / "depth").mkdir()
        for name, d in zip(names, _depths(len(names), 5)):
            if depth_ext == ".png":
                write_depth_png(root / "depth" / f"{name}.png", d, 1000)
            else:
                np.save(root / "depth" / f"{name}.npy", d.numpy())
    (root / "camera.yaml").write_text(yaml_text or "fx: 30\nfy: 31\ncx: 15.5\ncy: 11.5\ndepth_factor: 1000\n")
    if poses is not None:
        write_tum(root / "poses.txt", poses)
    return imgs


def run_cli(args, capsys):
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_error_line(rc, err, *needles):
    assert rc != 0
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("codeslam: warning:")]
    assert len(lines) == 1, err
    assert lines[0].startswith("codeslam: error:"), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


# ---------------------------------------------------------------------------------------------- TUM


def test_tum_reads_frames_depth_and_interpolated_gt(tmp_path):
    truth = write_tum_folder(tmp_path / "seq")
    seq = TumSequence(tmp_path / "seq")
    assert len(seq) == 4 and seq.has_depth and seq.has_pose
    assert seq.camera == CAM  # calib.txt, size from the images
    np.testing.assert_array_equal(seq.timestamps, np.round(truth["stamps"], 6))
    for i, f in enumerate(seq):
        assert f.index == i and f.camera == CAM
        assert f.image.shape == (3, H, W) and f.image.dtype == torch.float32
        assert (f.image - truth["images"][i]).abs().max() <= 0.5 / 255 + 1e-6
        assert f.depth.dtype == torch.float32 and (f.depth - truth["depths"][i]).abs().max() <= 0.5 / 5000 + 1e-6
        assert f.pose.dtype == torch.float64
        torch.testing.assert_close(f.pose, motion(f.timestamp - T0), rtol=0, atol=1e-6)
    torch.testing.assert_close(seq.gt_poses[2], seq[2].pose)


def test_tum_frame_of_another_size_fails_when_read(tmp_path):
    write_tum_folder(tmp_path / "seq", n=3)
    second = tmp_path / "seq" / (tmp_path / "seq" / "rgb.txt").read_text().splitlines()[3].split()[1]
    write_rgb_png(second, torch.rand(3, H + 2, W))
    seq = TumSequence(tmp_path / "seq")
    seq[0]
    with pytest.raises(DatasetError, match=rf"{second.name} is 32x26 but the camera is 32x24"):
        seq[1]


def test_tum_drops_colour_frames_without_depth(tmp_path):
    write_tum_folder(tmp_path / "seq", n=4)
    lines = (tmp_path / "seq" / "depth.txt").read_text().splitlines()
    (tmp_path / "seq" / "depth.txt").write_text("\n".join(lines[:2] + lines[3:]) + "\n")  # drop depth of frame 1
    with pytest.warns(UserWarning, match="1 of 4 colour images have no depth"):
        seq = TumSequence(tmp_path / "seq")
    assert len(seq) == 3
    np.testing.assert_allclose(seq.timestamps, T0 + np.array([0, 2, 3]) / 30.0, atol=1e-6)


def test_tum_without_depth_or_gt(tmp_path):
    write_tum_folder(tmp_path / "seq", depth=False, gt=False)
    seq = TumSequence(tmp_path / "seq")
    assert len(seq) == 4 and not seq.has_depth and not seq.has_pose and seq.gt_poses is None
    f = seq[-1]
    assert f.depth is None and f.pose is None and f.index == 3


def test_tum_gt_outside_span_gives_no_pose(tmp_path):
    write_tum_folder(tmp_path / "seq", gt=False)
    ts = np.arange(T0 + 0.04, T0 + 0.2, 0.01)  # starts after frame 0 and 1
    write_tum(tmp_path / "seq" / "groundtruth.txt", Trajectory(ts, torch.stack([motion(t - T0) for t in ts])))
    seq = TumSequence(tmp_path / "seq")
    assert seq[0].pose is None and seq[1].pose is None and seq[2].pose is not None
    assert torch.isnan(seq.gt_poses[0]).all()


def test_tum_camera_presets_from_folder_name(tmp_path):
    write_tum_folder(tmp_path / "rgbd_dataset_freiburg2_desk", calib=None, w=640, h=480, n=1, gt=False, depth=False)
    seq = TumSequence(tmp_path / "rgbd_dataset_freiburg2_desk", undistort=False)
    assert seq.source_camera == TUM_PRESETS["fr2"] and not seq.camera.has_distortion
    write_tum_folder(tmp_path / "mine", calib=None, w=640, h=480, n=1, gt=False, depth=False)
    with pytest.warns(UserWarning, match="ROS default"):
        seq = TumSequence(tmp_path / "mine")
    assert seq.camera == TUM_ROS_DEFAULT
    # A preset of the wrong size fails at once.
    write_tum_folder(tmp_path / "rgbd_dataset_freiburg3_small", calib=None, n=1, gt=False, depth=False)
    with pytest.raises(DatasetError, match="32x24 but the camera is 640x480"):
        TumSequence(tmp_path / "rgbd_dataset_freiburg3_small")


def test_tum_undistorts_rgb_and_depth_with_one_map(tmp_path):
    write_tum_folder(tmp_path / "seq", calib="30 31 15.5 11.5 0.1 -0.05 0.001 0.002 0.0", gt=False)
    raw = TumSequence(tmp_path / "seq", undistort=False)
    und = TumSequence(tmp_path / "seq")
    assert und.camera == raw.camera == CAM and und.source_camera.has_distortion
    f_raw, f_und = raw[0], und[0]
    assert f_und.image.shape == (3, H, W) and f_und.depth.shape == (H, W)
    assert not torch.equal(f_raw.image, f_und.image)
    # Nearest-neighbour depth: every undistorted depth is one of the stored depths (or 0 outside).
    stored = set(f_raw.depth.flatten().tolist()) | {0.0}
    assert set(f_und.depth.flatten().tolist()) <= stored
    # At the principal point distortion is zero, so both agree there.
    assert f_und.depth[11, 15] == f_raw.depth[11, 15]


def _readers_with_depth(tmp_path):
    """One sequence of every reader that has depth, the distorted ones undistorting it."""
    write_tum_folder(tmp_path / "tum", calib="30 31 15.5 11.5 0.1 -0.05 0.001 0.002 0.0", gt=False)
    write_folder(tmp_path / "png", ["a", "b"], depth_ext=".png",
                 yaml_text="fx: 30\nfy: 31\ncx: 15.5\ncy: 11.5\ndist: [0.1, -0.05, 0.0, 0.0]\ndepth_factor: 1000\n")
    write_folder(tmp_path / "npy", ["a", "b"], depth_ext=".npy")
    write_tartanair_folder(tmp_path / "ta", [_ned(), _ned(t=(1, 0, 0))])
    return [TumSequence(tmp_path / "tum"), FolderSequence(tmp_path / "png"), FolderSequence(tmp_path / "npy"),
            TartanAirSequence(tmp_path / "ta", camera=TA_CAM),
            SceneNetSequence(write_scenenet_folder(tmp_path / "sn"), camera=SN_CAM)]


def test_frames_read_without_depth_and_depth_read_alone_are_the_whole_frames_parts(tmp_path):
    # Monocular SLAM with the network's depth reads frames without depth and its keyframes' depth alone.
    seqs = _readers_with_depth(tmp_path)
    assert seqs[0].undistort and seqs[0].source_camera.has_distortion
    assert seqs[1].undistort and seqs[1].source_camera.has_distortion
    for seq in seqs:
        assert seq.has_depth
        for i in (0, -1):
            whole, bare = seq[i], seq.frame(i, depth=False)
            assert whole.depth is not None and bare.depth is None, type(seq).__name__
            assert torch.equal(bare.image, whole.image) and bare.index == whole.index
            assert bare.timestamp == whole.timestamp and bare.camera == whole.camera
            assert (bare.valid is None) == (whole.valid is None)
            assert bare.valid is None or torch.equal(bare.valid, whole.valid)
            assert torch.equal(seq.depth(i), whole.depth), type(seq).__name__
    write_euroc_folder(tmp_path / "MH_01")
    assert EurocSequence(tmp_path / "MH_01").depth(0) is None
    write_tum_folder(tmp_path / "tum_rgb", depth=False, gt=False)
    assert TumSequence(tmp_path / "tum_rgb").depth(1) is None


def test_a_depth_read_alone_of_the_wrong_size_names_its_file(tmp_path):
    write_tum_folder(tmp_path / "seq", n=2, gt=False)
    path = tmp_path / "seq" / "depth"
    first = sorted(path.iterdir())[0]
    write_depth_png(first, torch.ones(H + 2, W), 5000)
    with pytest.raises(DatasetError, match=rf"depth .*{first.name} is {W}x{H + 2} but the camera is {W}x{H}"):
        TumSequence(tmp_path / "seq").depth(0)


# ---------------------------------------------------------------------------------------------- EuRoC


def test_euroc_camera_pose_is_body_pose_times_T_BS(tmp_path):
    truth = write_euroc_folder(tmp_path / "MH_01")
    seq = EurocSequence(tmp_path / "MH_01")
    assert len(seq) == 3 and not seq.has_depth and seq.has_pose
    assert seq.camera == CAM
    torch.testing.assert_close(seq.T_BS, T_BS, rtol=0, atol=1e-11)
    for i, f in enumerate(seq):
        assert f.timestamp == int(truth["ns"][i]) / 10**9  # exact int / int division
        assert f.depth is None
        assert torch.equal(f.image[0], f.image[2])
        np.testing.assert_allclose(f.image[0].numpy(), truth["greys"][i] / 255.0, atol=1e-6)
        T_wb = motion(i * 0.05)
        torch.testing.assert_close(f.pose, T_wb @ T_BS, rtol=0, atol=1e-6)
        # Independent check of the convention: the optical centre is the body-frame point t_BS.
        centre = T_wb[:3, :3] @ T_BS[:3, 3] + T_wb[:3, 3]
        torch.testing.assert_close(f.pose[:3, 3], centre, rtol=0, atol=1e-6)
        # The classic mistakes give something else.
        for wrong in (T_BS @ T_wb, T_wb @ torch.linalg.inv(T_BS), T_wb):
            assert (f.pose - wrong).abs().max() > 1e-3


def test_euroc_accepts_mav0_folder_and_undistorts(tmp_path):
    write_euroc_folder(tmp_path / "seq", dist=(-0.28, 0.07, 0.0002, 0.00002), gt=False)
    seq = EurocSequence(tmp_path / "seq" / "mav0")
    assert seq.source_camera.dist == (-0.28, 0.07, 0.0002, 0.00002, 0.0)
    assert not seq.camera.has_distortion and seq.undistort and not seq.has_pose
    assert seq[0].image.shape == (3, H, W) and seq[0].pose is None


# ---------------------------------------------------------------------------------------------- SceneNet


def test_scenenet_ray_length_depth_and_lookat_poses(tmp_path):
    root = write_scenenet_folder(tmp_path)
    seq = SceneNetSequence(root, camera=SN_CAM)
    assert len(seq) == 2 and seq.has_depth and seq.has_pose and seq.render_path == "0/7"
    np.testing.assert_allclose(seq.timestamps, [0.25, 1.25])
    f0, f1 = seq[0], seq[1]
    # Ray length of a plane at z = 2 m -> z = 2 m everywhere (to the millimetre quantisation).
    assert float((f0.depth - 2.0).abs().max()) < 1e-3
    # View 0: camera midway between (1, 2, 3) and (1.25, 2, 3), looking along world -z, up = +y.
    R_expected = torch.tensor([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]], dtype=torch.float64)
    torch.testing.assert_close(f0.pose[:3, :3], R_expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(f0.pose[:3, 3], torch.tensor([1.125, 2.0, 3.0], dtype=torch.float64))
    # View 1: looking along world +x: camera x (right) = world +z... x = z cross up = (1,0,0) x (0,1,0).
    torch.testing.assert_close(f1.pose[:3, 2], torch.tensor([1.0, 0, 0], dtype=torch.float64))
    torch.testing.assert_close(f1.pose[:3, 0], torch.tensor([0, 0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(f1.pose[:3, 1], torch.tensor([0, -1.0, 0], dtype=torch.float64))


def test_scenenet_camera_matches_the_renderer_fov():
    assert SCENENET_CAMERA.fx == pytest.approx(277.128, abs=1e-3)
    assert SCENENET_CAMERA.fy == pytest.approx(289.706, abs=1e-3)
    # The corner pixels' rays under our K equal SceneNet's (x + 0.5) / width convention.
    z = ray_length_to_z(torch.from_numpy(scenenet_ray_norm(320, 240)), SCENENET_CAMERA)
    torch.testing.assert_close(z, torch.ones(240, 320, dtype=torch.float64), rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=6, max_size=6))
def test_look_at_pose_properties(v):
    eye, target = torch.tensor(v[:3], dtype=torch.float64), torch.tensor(v[3:], dtype=torch.float64)
    d = target - eye
    assume(d.norm() > 1e-2)
    assume(torch.linalg.cross(d / d.norm(), torch.tensor([0.0, 1, 0], dtype=torch.float64)).norm() > 1e-2)
    T = look_at_pose(eye, target)
    R = T[:3, :3]
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=torch.float64), rtol=0, atol=1e-12)
    assert float(torch.linalg.det(R)) == pytest.approx(1.0, abs=1e-12)
    p_c = torch.linalg.inv(T) @ torch.cat([target, torch.ones(1, dtype=torch.float64)])
    torch.testing.assert_close(p_c[:3], torch.tensor([0, 0, float(d.norm())], dtype=torch.float64), rtol=0, atol=1e-9)
    # World up points up in the image (negative camera y) and has no camera-x component (no roll).
    up_c = R.T @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    assert up_c[1] < 0 and abs(float(up_c[0])) < 1e-12


def test_scenenet_degenerate_lookat_raises():
    with pytest.raises(DatasetError, match="parallel"):
        look_at_pose(torch.zeros(3), torch.tensor([0.0, 3.0, 0.0]))
    with pytest.raises(DatasetError, match="coincides"):
        look_at_pose(torch.ones(3), torch.ones(3))


def test_scenenet_without_protobuf_package_is_a_clear_error(tmp_path, monkeypatch):
    root = write_scenenet_folder(tmp_path)
    monkeypatch.setitem(sys.modules, "google.protobuf", None)
    with pytest.raises(DatasetError, match=r"pip install 'codeslam\[scenenet\]'"):
        SceneNetSequence(root, camera=SN_CAM)


# ---------------------------------------------------------------------------------------------- TartanAir


def _ned(R=None, t=(0.0, 0.0, 0.0)) -> torch.Tensor:
    T = torch.eye(4, dtype=torch.float64)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = torch.tensor(t, dtype=torch.float64)
    return T


def test_tartanair_ned_motion_in_camera_frame(tmp_path):
    yaw = 0.3  # about NED z (down): turns the nose from north (x) toward east (y), i.e. to the right
    poses = [_ned(), _ned(t=(0.5, 0, 0)), _ned(t=(0, 0.4, 0)), _ned(t=(0, 0, 0.3)), _ned(R=_rot("z", yaw))]
    write_tartanair_folder(tmp_path / "P000", poses)
    seq = TartanAirSequence(tmp_path / "P000", camera=TA_CAM)
    assert len(seq) == 5 and seq.has_depth and seq.has_pose
    np.testing.assert_allclose(seq.timestamps, np.arange(5) / 10.0)
    T0_inv = torch.linalg.inv(seq[0].pose)
    rel = [T0_inv @ seq[i].pose for i in range(5)]
    e = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(rel[1][:3, 3], 0.5 * e[2], rtol=0, atol=1e-8)  # forward -> +z
    torch.testing.assert_close(rel[2][:3, 3], 0.4 * e[0], rtol=0, atol=1e-8)  # right -> +x
    torch.testing.assert_close(rel[3][:3, 3], 0.3 * e[1], rtol=0, atol=1e-8)  # down -> +y
    # Turning right = rotating about the camera's y (down) axis: forward z goes toward +x.
    torch.testing.assert_close(rel[4][:3, :3], _rot("y", yaw), rtol=0, atol=1e-8)
    f = seq[2]
    assert f.depth.shape == (H, W) and float(f.depth.min()) == 3.5


def test_tartanair_conversion_is_a_similarity_of_the_poses():
    T = torch.stack([_ned(R=_rot("x", 0.2) @ _rot("z", 1.0), t=(1.0, 2.0, 3.0)), _ned(t=(0.0, 0.0, 1.0))])
    C = ned_to_optical(T)
    R = C[:, :3, :3]
    torch.testing.assert_close(R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand(2, 3, 3))
    torch.testing.assert_close(C[0, :3, 3], torch.tensor([2.0, 3.0, 1.0], dtype=torch.float64))
    # Composition is preserved: relative motions map consistently.
    torch.testing.assert_close(ned_to_optical(T[0] @ T[1]), C[0] @ C[1])


def test_tartanair_invalid_depth_values_warn(tmp_path):
    write_tartanair_folder(tmp_path / "P001", [_ned(), _ned(t=(1, 0, 0))])
    d = np.ones((H, W), np.float32)
    d[0, 0], d[1, 1] = np.nan, -1.0
    np.save(tmp_path / "P001" / "depth_left" / "000001_left_depth.npy", d)
    seq = TartanAirSequence(tmp_path / "P001", camera=TA_CAM)
    with pytest.warns(DepthWarning, match="2 depth values"):
        f = seq[1]
    assert float(f.depth[0, 0]) == 0.0 and float(f.depth[1, 1]) == 0.0 and float(f.depth[2, 2]) == 1.0


# ---------------------------------------------------------------------------------------------- folder


def test_folder_numeric_names_are_timestamps_and_poses_interpolate(tmp_path):
    names = ["10.5", "9.25", "11"]  # sorted by value, not by name
    ts = np.arange(9.0, 12.0, 0.05)
    traj = Trajectory(ts, torch.stack([motion(t) for t in ts]))
    imgs = write_folder(tmp_path / "f", names, depth_ext=".png", poses=traj)
    seq = FolderSequence(tmp_path / "f")
    np.testing.assert_array_equal(seq.timestamps, [9.25, 10.5, 11.0])
    assert seq.camera == CAM and seq.has_depth and seq.has_pose
    f = seq[0]
    assert (f.image - imgs[1]).abs().max() <= 0.5 / 255 + 1e-6
    torch.testing.assert_close(f.pose, motion(9.25), rtol=0, atol=1e-6)
    assert float(f.depth.max()) <= 3.5 + 1e-3


def test_folder_non_numeric_names_use_fps_and_npy_depth(tmp_path):
    write_folder(tmp_path / "f", ["frame_b", "frame_a"], depth_ext=".npy",
                 yaml_text="fx: 30\nfy: 31\ncx: 15.5\ncy: 11.5\nfps: 4\nwidth: 32\nheight: 24\n")
    seq = FolderSequence(tmp_path / "f")
    np.testing.assert_array_equal(seq.timestamps, [0.0, 0.25])
    assert seq._images[0].name == "frame_a.png"
    assert seq[1].depth.dtype == torch.float32 and not seq.has_pose


def test_folder_with_distortion_is_undistorted(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: 30\nfy: 31\ncx: 15.5\ncy: 11.5\ndist: [0.1, 0.0, 0.0, 0.0]\n")
    seq = FolderSequence(tmp_path / "f")
    assert seq.source_camera.dist == (0.1, 0.0, 0.0, 0.0, 0.0) and not seq.camera.has_distortion
    assert seq[0].image.shape == (3, H, W)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(1, 4),
    w=st.integers(4, 20),
    h=st.integers(3, 16),
    seed=st.integers(0, 1000),
)
def test_tum_reader_returns_what_was_written(tmp_path_factory, n, w, h, seed):
    root = tmp_path_factory.mktemp("tum_prop") / "seq"
    truth = write_tum_folder(root, n=n, w=w, h=h, seed=seed, calib=f"{w} {w} {(w - 1) / 2} {(h - 1) / 2}")
    seq = open_dataset(root)
    assert isinstance(seq, TumSequence) and len(seq) == n
    for i in range(n):
        f = seq[i]
        assert f.image.shape == (3, h, w) and f.depth.shape == (h, w)
        assert (f.depth - truth["depths"][i]).abs().max() <= 0.5 / 5000 + 1e-6
        assert (f.image - truth["images"][i]).abs().max() <= 0.5 / 255 + 1e-6
        torch.testing.assert_close(f.pose, motion(f.timestamp - T0), rtol=0, atol=1e-6)
    shutil.rmtree(root)


# ---------------------------------------------------------------------------------------------- registry


def test_registry_detects_every_format(tmp_path):
    write_tum_folder(tmp_path / "tum", n=2)
    write_euroc_folder(tmp_path / "euroc", n=2)
    sn = write_scenenet_folder(tmp_path / "sn")
    write_tartanair_folder(tmp_path / "ta", [_ned(), _ned()])
    write_folder(tmp_path / "folder", ["a"])
    assert detect_format(tmp_path / "tum") == "tum"
    assert detect_format(tmp_path / "euroc") == "euroc"
    assert detect_format(tmp_path / "euroc" / "mav0") == "euroc"
    assert detect_format(sn) == "scenenet"
    assert detect_format(tmp_path / "ta") == "tartanair"
    assert detect_format(tmp_path / "folder") == "folder"
    assert set(FORMATS) == {"tum", "euroc", "scenenet", "tartanair", "folder", "video"}
    assert isinstance(open_dataset(tmp_path / "ta", camera=TA_CAM), TartanAirSequence)
    assert isinstance(open_dataset(sn, format="scenenet", camera=SN_CAM), SceneNetSequence)
    with pytest.raises(ConfigError, match="unknown dataset format 'kitti'"):
        open_dataset(tmp_path / "tum", format="kitti")


def test_describe_dataset_keys(tmp_path):
    write_euroc_folder(tmp_path / "e", n=3)
    info = describe_dataset(open_dataset(tmp_path / "e"))
    assert info["format"] == "euroc" and info["frames"] == 3 and not info["has_depth"] and info["has_pose"]
    assert (info["width"], info["height"], info["fx"], info["cy"]) == (W, H, 30.0, 11.5)
    assert info["duration_s"] == pytest.approx(0.1, abs=1e-6)
    # Camera path: the body moves (0.2, 0.05, 0) m/s and turns; T_BS moves the centre with the rotation.
    centres = torch.stack([(motion(k * 0.05) @ T_BS)[:3, 3] for k in range(3)])
    expected = float((centres[1:] - centres[:-1]).norm(dim=-1).sum())
    assert info["gt_path_length_m"] == pytest.approx(expected, abs=1e-6)
    assert "depth_min_m" not in info["first_frame"]


def test_cli_info_on_generated_folder_writes_json(tmp_path, capsys):
    truth = write_tum_folder(tmp_path / "seq", n=3)
    rc, out, err = run_cli(["info", tmp_path / "seq", "--json", tmp_path / "out" / "info.json"], capsys)
    assert rc == 0, err
    assert "frames" in out and "32 x 24" in out
    info = json.loads((tmp_path / "out" / "info.json").read_text())
    for key in ("frames", "width", "height", "fx", "fy", "cx", "cy", "has_depth", "has_pose", "format",
                "duration_s", "gt_path_length_m", "distortion"):
        assert key in info
    assert info["frames"] == 3 and info["has_depth"] and info["has_pose"] and info["format"] == "tum"
    d0 = truth["depths"][0]
    assert info["first_frame"]["depth_min_m"] == pytest.approx(float(d0[d0 > 0].min()), abs=1e-4)
    assert info["first_frame"]["depth_max_m"] == pytest.approx(float(d0.max()), abs=1e-4)
    assert info["first_frame"]["depth_valid_fraction"] == pytest.approx(float((d0 > 0).float().mean()))


def test_cli_info_prints_reader_warnings_as_lines(tmp_path, capsys):
    write_tum_folder(tmp_path / "seq", n=3)
    lines = (tmp_path / "seq" / "depth.txt").read_text().splitlines()
    (tmp_path / "seq" / "depth.txt").write_text("\n".join(lines[:-1]) + "\n")
    rc, _, err = run_cli(["info", tmp_path / "seq"], capsys)
    assert rc == 0
    assert err.strip().splitlines() == [
        f"codeslam: warning: {tmp_path / 'seq'}: 1 of 3 colour images have no depth map within 0.02 s and are skipped"
    ]


# ---------------------------------------------------------------------------------------------- bad inputs


def _tum(tmp_path, **kw):
    root = tmp_path / "seq"
    write_tum_folder(root, n=3, **kw)
    return root


def _first_rgb(root):
    return root / (root / "rgb.txt").read_text().splitlines()[2].split()[1]


def _first_depth(root):
    return root / (root / "depth.txt").read_text().splitlines()[1].split()[1]


def _replace_line(path, index, new):
    lines = path.read_text().splitlines()
    lines[index] = new
    path.write_text("\n".join(lines) + "\n")


def bad_missing_path(tmp_path):
    return tmp_path / "does_not_exist", ["not found"]


def bad_unknown_format(tmp_path):
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("hello")
    return tmp_path / "junk", ["no known dataset format"]


def bad_ambiguous(tmp_path):
    root = _tum(tmp_path)
    (root / "camera.yaml").write_text("fx: 1\nfy: 1\ncx: 1\ncy: 1\n")
    return root, ["several formats (tum, folder)", "--format"]


def bad_missing_image(tmp_path):
    root = _tum(tmp_path)
    _first_rgb(root).unlink()
    return root, ["rgb.txt:3", "file not found"]


def bad_corrupt_png(tmp_path):
    root = _tum(tmp_path)
    _first_rgb(root).write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 50)
    return root, [_first_rgb(root).name]


def bad_truncated_png(tmp_path):
    root = _tum(tmp_path)
    p = _first_rgb(root)
    p.write_bytes(p.read_bytes()[:300])
    return root, [p.name, "truncated"]


def bad_empty_png(tmp_path):
    root = _tum(tmp_path)
    p = _first_depth(root)
    p.write_bytes(b"")
    return root, [p.name, "empty"]


def bad_8bit_depth(tmp_path):
    root = _tum(tmp_path)
    Image.fromarray(np.full((H, W), 9, np.uint8)).save(_first_depth(root))
    return root, [_first_depth(root).name, "16-bit"]


def bad_depth_size(tmp_path):
    root = _tum(tmp_path)
    write_depth_png(_first_depth(root), torch.ones(H // 2, W // 2), 5000)
    return root, ["depth", "16x12", "32x24"]


def bad_empty_sequence(tmp_path):
    root = _tum(tmp_path)
    (root / "rgb.txt").write_text("# color images\n# nothing here\n")
    return root, ["lists no images"]


def bad_groundtruth_line(tmp_path):
    root = _tum(tmp_path)
    _replace_line(root / "groundtruth.txt", 3, "100.0 1 2 3 0 0 0")
    return root, ["groundtruth.txt:4", "expected"]


def bad_out_of_order(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "rgb.txt").read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    return root, ["rgb.txt:5", "not after the previous"]


def bad_duplicate_timestamp(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "rgb.txt").read_text().splitlines()
    (root / "rgb.txt").write_text("\n".join(lines + [lines[-1]]) + "\n")
    return root, ["rgb.txt:6", "not after the previous"]


def bad_escaping_path(tmp_path):
    root = _tum(tmp_path)
    _replace_line(root / "rgb.txt", 2, "100.000000 ../../../../etc/passwd")
    return root, ["rgb.txt:3", "outside the dataset folder"]


def bad_absolute_path(tmp_path):
    root = _tum(tmp_path)
    _replace_line(root / "rgb.txt", 2, "100.000000 /etc/passwd")
    return root, ["rgb.txt:3", "relative"]


def bad_calib(tmp_path):
    root = _tum(tmp_path, calib="30 31 15.5")
    return root, ["calib.txt", "expected 4, 8 or 9 numbers"]


def bad_malformed_yaml(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: [30, 31\ncy: 2\n")
    return tmp_path / "f", ["camera.yaml", "not valid YAML"]


def bad_yaml_missing_key(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: 30\nfy: 30\ncx: 15.5\n")
    return tmp_path / "f", ["camera.yaml", "missing keys ['cy']"]


def bad_yaml_typo(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: 30\nfy: 30\ncx: 15.5\ncy: 11.5\ndepth_scale: 1000\n")
    return tmp_path / "f", ["unknown keys ['depth_scale']"]


def bad_yaml_negative_focal(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: -30\nfy: 30\ncx: 15.5\ncy: 11.5\n")
    return tmp_path / "f", ["'fx' must be a positive number"]


def bad_yaml_size(tmp_path):
    write_folder(tmp_path / "f", ["a"], yaml_text="fx: 30\nfy: 30\ncx: 15.5\ncy: 11.5\nwidth: 64\nheight: 48\n")
    return tmp_path / "f", ["32x24", "64x48"]


def bad_folder_duplicate_timestamps(tmp_path):
    write_folder(tmp_path / "f", ["1", "1.0"])
    return tmp_path / "f", ["same timestamp"]


def bad_euroc_T_BS(tmp_path):
    T = T_BS.clone()
    T[0, 0] = 3.0
    write_euroc_folder(tmp_path / "e", n=2, T_bs=T)
    return tmp_path / "e", ["sensor.yaml", "T_BS", "not a rigid"]


def bad_euroc_distortion_model(tmp_path):
    write_euroc_folder(tmp_path / "e", n=2)
    y = tmp_path / "e" / "mav0" / "cam0" / "sensor.yaml"
    y.write_text(y.read_text().replace("radial-tangential", "equidistant"))
    return tmp_path / "e", ["equidistant", "not supported"]


def bad_euroc_gt_line(tmp_path):
    write_euroc_folder(tmp_path / "e", n=2)
    _replace_line(tmp_path / "e" / "mav0" / "state_groundtruth_estimate0" / "data.csv", 2, "12,1,2")
    return tmp_path / "e", ["data.csv:3"]


def bad_scenenet_no_protobuf(tmp_path):
    root = write_scenenet_folder(tmp_path)
    (tmp_path / "train" / "scenenet_rgbd_train_0.pb").unlink()
    return root, ["no SceneNet protobuf"]


def bad_scenenet_garbage_protobuf(tmp_path):
    root = write_scenenet_folder(tmp_path)
    (tmp_path / "train" / "scenenet_rgbd_train_0.pb").write_bytes(b"\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01")
    return root, ["scenenet_rgbd_train_0.pb"]


def bad_scenenet_missing_photo(tmp_path):
    root = write_scenenet_folder(tmp_path)
    (root / "photo" / "25.jpg").unlink()
    return root, ["25.jpg", "file not found"]


def bad_tartanair_pose_count(tmp_path):
    write_tartanair_folder(tmp_path / "P", [_ned(), _ned()])
    _replace_line(tmp_path / "P" / "pose_left.txt", 1, "")
    return tmp_path / "P", ["pose_left.txt has 1 poses but", "2 images"]


def bad_tartanair_size(tmp_path):
    write_tartanair_folder(tmp_path / "P", [_ned()])  # 32x24 images, TartanAir's camera is 640x480
    return tmp_path / "P", ["32x24 but the camera is 640x480"]


BAD_INPUTS = [v for k, v in sorted(globals().items()) if k.startswith("bad_")]


@pytest.mark.parametrize("make", BAD_INPUTS, ids=[f.__name__[4:] for f in BAD_INPUTS])
def test_bad_input_gives_one_error_line(tmp_path, capsys, make):
    path, needles = make(tmp_path)
    rc, out, err = run_cli(["info", path], capsys)
    assert_one_error_line(rc, err, *needles)
    assert rc == 2


def test_unknown_format_option_is_one_error_line(tmp_path, capsys):
    root = _tum(tmp_path)
    rc, _, err = run_cli(["info", root, "--format", "kitti"], capsys)
    assert_one_error_line(rc, err, "unknown dataset format 'kitti'", "tum, euroc")
    rc, _, err = run_cli(["info", root, "--format", "euroc"], capsys)
    assert_one_error_line(rc, err, "not an EuRoC folder")
