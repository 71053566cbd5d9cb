"""Image I/O shared by the readers: every kind of bad file becomes a DatasetError naming the file."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.data.imageio import (
    DepthWarning,
    check_frame_shapes,
    frame_index,
    read_depth_npy,
    read_depth_png,
    read_rgb,
    resolve_in_root,
    sanitize_depth,
    write_depth_png,
    write_rgb_png,
)
from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera


def test_rgb_png_round_trip(tmp_path):
    img = torch.rand(3, 24, 32)
    write_rgb_png(tmp_path / "a.png", img)
    back = read_rgb(tmp_path / "a.png")
    assert back.shape == (3, 24, 32) and back.dtype == torch.float32
    assert (back - img).abs().max() <= 0.5 / 255 + 1e-6  # 8-bit rounding
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_read_rgb_grey_alpha_palette_and_16bit(tmp_path):
    grey = (np.arange(24 * 32) % 256).astype(np.uint8).reshape(24, 32)
    Image.fromarray(grey).save(tmp_path / "g.png")
    g = read_rgb(tmp_path / "g.png")
    assert g.shape == (3, 24, 32)
    assert torch.equal(g[0], g[1]) and torch.equal(g[1], g[2])
    torch.testing.assert_close(g[0], torch.from_numpy(grey.astype(np.float32) / 255))

    rgba = np.zeros((24, 32, 4), np.uint8)
    rgba[..., 0] = 255
    rgba[..., 3] = 7
    Image.fromarray(rgba).save(tmp_path / "a.png")
    a = read_rgb(tmp_path / "a.png")
    assert a.shape == (3, 24, 32) and float(a[0].min()) == 1.0 and float(a[1:].max()) == 0.0

    Image.fromarray(grey).convert("P").save(tmp_path / "p.png")
    assert read_rgb(tmp_path / "p.png").shape == (3, 24, 32)

    g16 = np.full((24, 32), 65535, np.uint16)
    g16[0, 0] = 0
    Image.fromarray(g16).save(tmp_path / "g16.png")
    x = read_rgb(tmp_path / "g16.png")
    assert float(x.max()) == 1.0 and float(x[:, 0, 0].max()) == 0.0


def test_depth_png_round_trip_and_scale(tmp_path):
    d = torch.rand(24, 32) * 5
    d[3, 4] = 0
    write_depth_png(tmp_path / "d.png", d, factor=5000)
    raw = np.asarray(Image.open(tmp_path / "d.png"))
    assert raw.dtype == np.uint16
    assert raw[3, 4] == 0 and raw[0, 0] == round(float(d[0, 0]) * 5000)
    back = read_depth_png(tmp_path / "d.png", 5000)
    assert back.dtype == torch.float32 and back.shape == (24, 32)
    assert (back - d).abs().max() <= 0.5 / 5000 + 1e-6
    assert float(read_depth_png(tmp_path / "d.png", 1000).max()) == pytest.approx(float(back.max()) * 5, rel=1e-6)


def test_write_depth_rejects_out_of_range_and_zeroes_invalid(tmp_path):
    with pytest.raises(DatasetError, match="16-bit range"):
        write_depth_png(tmp_path / "d.png", torch.full((2, 2), 14.0), factor=5000)
    assert not (tmp_path / "d.png").exists()
    write_depth_png(tmp_path / "d.png", torch.tensor([[float("nan"), -1.0], [float("inf"), 1.0]]), 1000)
    assert np.asarray(Image.open(tmp_path / "d.png")).tolist() == [[0, 0], [0, 1000]]


def test_eight_bit_depth_is_rejected(tmp_path):
    Image.fromarray(np.ones((4, 4), np.uint8)).save(tmp_path / "d8.png")
    with pytest.raises(DatasetError, match=r"d8.png.*16-bit"):
        read_depth_png(tmp_path / "d8.png", 5000)
    Image.fromarray(np.ones((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(DatasetError, match=r"rgb.png.*16-bit"):
        read_depth_png(tmp_path / "rgb.png", 5000)


@pytest.mark.parametrize("reader", [read_rgb, lambda p: read_depth_png(p, 5000)])
def test_bad_files_name_the_file(tmp_path, reader):
    with pytest.raises(DatasetError, match="missing.png"):
        reader(tmp_path / "missing.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(DatasetError, match="empty.png"):
        reader(tmp_path / "empty.png")
    (tmp_path / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(200))
    with pytest.raises(DatasetError, match="garbage.png"):
        reader(tmp_path / "garbage.png")
    write_depth_png(tmp_path / "full.png", torch.rand(64, 64), 5000)
    data = (tmp_path / "full.png").read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) // 2])  # header fine, pixel data cut
    with pytest.raises(DatasetError, match="trunc.png"):
        reader(tmp_path / "trunc.png")


def test_depth_npy_and_invalid_values_warn(tmp_path):
    d = np.ones((3, 4), np.float32)
    d[0, 0], d[0, 1], d[0, 2] = np.nan, np.inf, -2.0
    np.save(tmp_path / "d.npy", d)
    with pytest.warns(DepthWarning, match="3 depth values"):
        out = read_depth_npy(tmp_path / "d.npy")
    assert out[0, :3].tolist() == [0.0, 0.0, 0.0] and float(out[1:].min()) == 1.0
    np.save(tmp_path / "three.npy", np.ones((2, 3, 4), np.float32))
    with pytest.raises(DatasetError, match="2-D"):
        read_depth_npy(tmp_path / "three.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DatasetError, match="obj.npy"):
        read_depth_npy(tmp_path / "obj.npy")  # pickled objects are never loaded
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    with pytest.raises(DatasetError, match="bad.npy"):
        read_depth_npy(tmp_path / "bad.npy")


def test_sanitize_depth_passes_clean_maps_silently(recwarn):
    d = torch.rand(5, 5)
    assert sanitize_depth(d, "x") is d
    assert not recwarn.list


def test_resolve_in_root_confines_paths(tmp_path):
    root = tmp_path / "ds"
    (root / "rgb").mkdir(parents=True)
    assert resolve_in_root(root, "rgb/a.png", "rgb.txt:1") == root / "rgb" / "a.png"
    for bad in ["../../etc/passwd", "/etc/passwd", "rgb/../../x.png", ""]:
        with pytest.raises(DatasetError, match="rgb.txt:3"):
            resolve_in_root(root, bad, "rgb.txt:3")
    (tmp_path / "outside.png").write_bytes(b"")
    (root / "rgb" / "link.png").symlink_to(tmp_path / "outside.png")
    with pytest.raises(DatasetError, match="outside the dataset folder"):
        resolve_in_root(root, "rgb/link.png", "rgb.txt:4")


def test_check_frame_shapes_and_index():
    cam = PinholeCamera(10, 10, 15.5, 11.5, 32, 24)
    check_frame_shapes(cam, torch.zeros(3, 24, 32), torch.zeros(24, 32), "a")
    with pytest.raises(DatasetError, match="33x24 but the camera is 32x24"):
        check_frame_shapes(cam, torch.zeros(3, 24, 33), None, "a.png")
    with pytest.raises(DatasetError, match="d.png is 16x12"):
        check_frame_shapes(cam, torch.zeros(3, 24, 32), torch.zeros(12, 16), "a.png", "d.png")
    assert frame_index(-1, 3) == 2
    with pytest.raises(IndexError):
        frame_index(3, 3)
