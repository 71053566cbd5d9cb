"""Bad dataset folders through ``codeslam info`` and ``codeslam train --data``: each either fails with one
``codeslam: error:`` line (exit 2, no traceback, no run folder left) or is handled as documented with a
``codeslam: warning:`` line.

tests/data/test_data_formats.py already runs 30 malformed folders through ``info`` (missing path, unknown
layout, corrupt/truncated/empty PNGs of the first frame, 8-bit depth, a depth of another size, out-of-order and
duplicated rgb.txt timestamps, ``..`` and absolute list paths, malformed calib/camera.yaml/sensor.yaml, ...);
this file adds what those leave out: nonsense intrinsics, NaN/inf/zero/negative depth, bad ``.npy`` depth
(including a pickle posing as one), malformed ground truth of other kinds, symbolic links out of the folder,
single-frame and empty sequences, and frames past the first, which ``info`` does not read but ``train`` does.
"""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest
from corpus import (
    _Payload,
    assert_clean_failure,
    folder_dataset,
    listing,
    run_cli,
    tartanair_folder,
    tiny_yaml,
    tum_file,
    tum_folder,
    yaml_payload,
)
from PIL import Image

# ---------------------------------------------------------------------------------------------- info: errors


def _tum(tmp_path, **kw):
    return tum_folder(tmp_path / "seq", **kw)


def _set_line(path, index, text):
    lines = path.read_text().splitlines()
    lines[index] = text
    path.write_text("\n".join(lines) + "\n")


def calib_zero_focal(tmp_path):
    return _tum(tmp_path, calib="0 14 7.5 7.5"), ["calib.txt", "focal lengths must be positive"]


def calib_negative_focal(tmp_path):
    return _tum(tmp_path, calib="14 -14 7.5 7.5"), ["calib.txt", "focal lengths must be positive"]


def calib_principal_point_outside(tmp_path):
    return _tum(tmp_path, calib="14 14 7.5 300"), ["calib.txt", "principal point", "outside"]


def calib_nan(tmp_path):
    return _tum(tmp_path, calib="nan 14 7.5 7.5"), ["calib.txt", "non-finite"]


def calib_inf(tmp_path):
    return _tum(tmp_path, calib="14 14 inf 7.5"), ["calib.txt", "non-finite"]


def calib_not_numbers(tmp_path):
    return _tum(tmp_path, calib="fx fy cx cy"), ["calib.txt", "not a number"]


def calib_empty(tmp_path):
    return _tum(tmp_path, calib=""), ["calib.txt", "empty"]


def calib_binary(tmp_path):
    root = _tum(tmp_path)
    (root / "calib.txt").write_bytes(b"\xff\xfe\x00\x81garbage")
    return root, ["calib.txt"]


def yaml_zero_focal(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="fx: 0\nfy: 14\ncx: 7.5\ncy: 7.5\n"), ["'fx' must be a positive"]


def yaml_nan_focal(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="fx: .nan\nfy: 14\ncx: 7.5\ncy: 7.5\n"), ["'fx' must be a positive"]


def yaml_string_focal(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="fx: big\nfy: 14\ncx: 7.5\ncy: 7.5\n"), ["'fx' must be a positive"]


def yaml_inf_principal_point(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="fx: 14\nfy: 14\ncx: .inf\ncy: 7.5\n"), ["'cx' must be a number"]


def yaml_principal_point_outside(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="fx: 14\nfy: 14\ncx: -40\ncy: 7.5\n"), ["principal point"]


def yaml_negative_size(tmp_path):
    text = "fx: 14\nfy: 14\ncx: 7.5\ncy: 7.5\nwidth: -16\nheight: 16\n"
    return folder_dataset(tmp_path / "f", yaml_text=text), ["'width' must be a positive integer"]


def yaml_zero_depth_factor(tmp_path):
    text = "fx: 14\nfy: 14\ncx: 7.5\ncy: 7.5\ndepth_factor: 0\n"
    return folder_dataset(tmp_path / "f", yaml_text=text), ["'depth_factor' must be a positive"]


def yaml_empty(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text=""), ["camera.yaml must be a YAML mapping"]


def yaml_list(tmp_path):
    return folder_dataset(tmp_path / "f", yaml_text="- 1\n- 2\n"), ["camera.yaml must be a YAML mapping"]


def empty_rgb_file(tmp_path):
    root = _tum(tmp_path)
    tum_file(root, "rgb", 0).write_bytes(b"")
    return root, ["empty"]


def rgb_is_text(tmp_path):
    root = _tum(tmp_path)
    tum_file(root, "rgb", 0).write_text("this is not an image\n")
    return root, ["not a readable image"]


def colour_depth_png(tmp_path):
    root = _tum(tmp_path)
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(tum_file(root, "depth", 0))
    return root, ["depth image", "16-bit"]


def depth_txt_out_of_order(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "depth.txt").read_text().splitlines()
    lines[1], lines[2] = lines[2], lines[1]
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    return root, ["depth.txt:3", "not after the previous"]


def depth_txt_escapes(tmp_path):
    root = _tum(tmp_path)
    _set_line(root / "depth.txt", 1, "100.000000 depth/../../outside.png")
    (tmp_path / "outside.png").write_bytes(b"")
    return root, ["depth.txt:2", "outside the dataset folder"]


def symlink_escapes(tmp_path):
    root = _tum(tmp_path)
    secret = tmp_path / "secret.png"
    secret.write_bytes(tum_file(root, "rgb", 0).read_bytes())
    (root / "rgb" / "link.png").symlink_to(secret)
    _set_line(root / "rgb.txt", 1, "100.000000 rgb/link.png")
    return root, ["rgb.txt:2", "outside the dataset folder"]


def list_line_three_fields(tmp_path):
    root = _tum(tmp_path)
    _set_line(root / "rgb.txt", 1, "100.000000 rgb/a.png extra")
    return root, ["rgb.txt:2", "expected 'timestamp filename'"]


def list_timestamp_nan(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "rgb.txt").read_text().splitlines()
    lines[1] = "nan " + lines[1].split()[1]
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    return root, ["rgb.txt:2", "non-finite"]


def rgb_txt_binary(tmp_path):
    root = _tum(tmp_path)
    (root / "rgb.txt").write_bytes(os.urandom(64) + b"\xff\xfe")
    return root, ["rgb.txt"]


def gt_not_a_number(tmp_path):
    root = _tum(tmp_path)
    _set_line(root / "groundtruth.txt", 3, "100.0 1 2 x 0 0 0 1")
    return root, ["groundtruth.txt:4", "not a number"]


def gt_nan(tmp_path):
    root = _tum(tmp_path)
    _set_line(root / "groundtruth.txt", 3, "99.95 nan 2 3 0 0 0 1")
    return root, ["groundtruth.txt:4", "non-finite"]


def gt_zero_quaternion(tmp_path):
    root = _tum(tmp_path)
    _set_line(root / "groundtruth.txt", 3, "99.95 1 2 3 0 0 0 0")
    return root, ["groundtruth.txt:4", "zero quaternion"]


def gt_duplicate_timestamp(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    lines.insert(3, lines[3])
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return root, ["groundtruth.txt:5", "not after the previous"]


def gt_out_of_order(tmp_path):
    root = _tum(tmp_path)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return root, ["groundtruth.txt:5", "not after the previous"]


def gt_binary(tmp_path):
    root = _tum(tmp_path)
    (root / "groundtruth.txt").write_bytes(b"\x00\x01\x02\xff\xfe" * 20)
    return root, ["groundtruth.txt"]


def dataset_is_a_file(tmp_path):
    (tmp_path / "seq.txt").write_text("1 2 3\n")
    return tmp_path / "seq.txt", ["not a folder"]


def empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    return tmp_path / "empty", ["no known dataset format"]


def folder_without_images(tmp_path):
    root = folder_dataset(tmp_path / "f", n=0)
    return root, ["holds no images"]


def tartanair_without_images(tmp_path):
    (tmp_path / "P000" / "image_left").mkdir(parents=True)
    return tmp_path / "P000", ["holds no images"]


def npy_depth_of_another_size(tmp_path):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.ones((8, 8), np.float32)] * 2)
    return root, ["depth", "8x8", "16x16"]


def npy_depth_3d(tmp_path):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.ones((16, 16, 3), np.float32)] * 2)
    return root, ["must hold a 2-D array"]


def npy_depth_strings(tmp_path):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.full((16, 16), "a")] * 2)
    return root, ["expected numbers"]


def npy_depth_truncated(tmp_path):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.ones((16, 16), np.float32)] * 2)
    p = root / "depth" / "frame_0000.npy"
    p.write_bytes(p.read_bytes()[:100])
    return root, ["frame_0000.npy"]


def npy_depth_not_npy(tmp_path):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.ones((16, 16), np.float32)] * 2)
    (root / "depth" / "frame_0000.npy").write_bytes(os.urandom(300))
    return root, ["frame_0000.npy"]


BAD_FOLDERS = [v for k, v in sorted(globals().items()) if callable(v) and v.__module__ == __name__
               and not k.startswith(("_", "test")) and k != "BAD_FOLDERS"]


@pytest.mark.parametrize("make", BAD_FOLDERS, ids=[f.__name__ for f in BAD_FOLDERS])
def test_info_bad_folder_is_one_error_line(tmp_path, capsys, make):
    path, needles = make(tmp_path)
    out_json = tmp_path / "out" / "info.json"
    rc, _, err = run_cli(capsys, "info", path, "--json", out_json)
    assert_clean_failure(rc, err, *needles, out_dir=tmp_path / "out")


# ---------------------------------------------------------------------------------------------- untrusted files


def test_pickled_npy_depth_is_refused_without_unpickling(tmp_path, capsys):
    """A ``.npy`` holding a pickled object array: np.load(allow_pickle=False) refuses it, nothing runs."""
    marker = tmp_path / "PWNED"
    root = folder_dataset(tmp_path / "f", npy_depth=[np.ones((16, 16), np.float32)] * 2)
    evil = np.empty((16, 16), dtype=object)
    evil[0, 0] = _Payload(marker)
    np.save(root / "depth" / "frame_0000.npy", evil, allow_pickle=True)
    rc, _, err = run_cli(capsys, "info", root)
    assert_clean_failure(rc, err, "frame_0000.npy")
    assert not marker.exists()


def test_camera_yaml_with_python_tags_is_refused_not_executed(tmp_path, capsys):
    marker = tmp_path / "PWNED"
    root = folder_dataset(tmp_path / "f", yaml_text="fx: 14\nfy: 14\ncx: 7.5\ncy: 7.5\n" + yaml_payload(marker)
                          .replace("network:", "fps:").replace("train:", "depth_factor:"))
    rc, _, err = run_cli(capsys, "info", root)
    assert_clean_failure(rc, err, "camera.yaml", "not valid YAML")
    assert not marker.exists()


# ---------------------------------------------------------------------------------------------- documented handling


@pytest.mark.parametrize("fmt", ["folder", "tartanair"])
def test_nan_inf_negative_depth_are_invalid_with_a_warning(tmp_path, capsys, fmt):
    """NaN, +-inf and negative depths become 0 (invalid) with one ``codeslam: warning:`` line naming the file and
    the count; zeros are already invalid and not counted. The command succeeds."""
    h, w = (16, 16) if fmt == "folder" else (480, 640)
    d = np.full((h, w), 2.0, np.float32)
    d[0, 0], d[0, 1], d[0, 2], d[0, 3], d[0, 4] = np.nan, np.inf, -np.inf, -1.0, 0.0
    depths = [d, np.full((h, w), 1.0, np.float32)]
    root = folder_dataset(tmp_path / "f", npy_depth=depths) if fmt == "folder" else tartanair_folder(tmp_path / "P",
                                                                                                      depths)
    rc, _, err = run_cli(capsys, "info", root, "--json", tmp_path / "i.json")
    assert rc == 0, err
    warnings = err.strip().splitlines()
    assert len(warnings) == 1 and warnings[0].startswith("codeslam: warning:"), err
    assert "4 depth values are NaN, infinite or negative" in warnings[0] and "treated as invalid" in warnings[0]
    first = json.loads((tmp_path / "i.json").read_text())["first_frame"]
    assert first["depth_valid_fraction"] == pytest.approx(1 - 5 / (h * w))
    assert first["depth_min_m"] == 2.0 and first["depth_max_m"] == 2.0


def test_all_invalid_depth_is_reported_not_crashed(tmp_path, capsys):
    root = folder_dataset(tmp_path / "f", npy_depth=[np.full((16, 16), np.nan, np.float32)] * 2)
    rc, _, err = run_cli(capsys, "info", root, "--json", tmp_path / "i.json")
    assert rc == 0, err
    assert "256 depth values" in err
    first = json.loads((tmp_path / "i.json").read_text())["first_frame"]
    assert first["depth_valid_fraction"] == 0.0 and first["depth_min_m"] is None


def test_single_frame_sequence_info_works(tmp_path, capsys):
    root = tum_folder(tmp_path / "seq", n=1)
    rc, _, err = run_cli(capsys, "info", root, "--json", tmp_path / "i.json")
    assert rc == 0, err
    info = json.loads((tmp_path / "i.json").read_text())
    assert info["frames"] == 1 and info["duration_s"] == 0.0 and info["gt_path_length_m"] == 0.0


def test_colour_frames_without_depth_are_skipped_with_a_warning(tmp_path, capsys):
    root = tum_folder(tmp_path / "seq", n=3)
    lines = (root / "depth.txt").read_text().splitlines()
    (root / "depth.txt").write_text("\n".join(lines[:2]) + "\n")  # depth of frames 1 and 2 missing
    rc, _, err = run_cli(capsys, "info", root, "--json", tmp_path / "i.json")
    assert rc == 0
    assert err.count("codeslam: warning:") == 1 and "2 of 3 colour images have no depth map" in err
    assert json.loads((tmp_path / "i.json").read_text())["frames"] == 1


# ---------------------------------------------------------------------------------------------- train reads all frames


def _train(capsys, tmp_path, data, *extra):
    cfg = tiny_yaml(tmp_path / "tiny.yaml")
    out = tmp_path / "run"
    rc, _, err = run_cli(capsys, "train", "--data", data, "--out", out, "--config", cfg, "--steps", "1",
                         "--no-progress", *extra)
    return rc, err, out


@pytest.mark.parametrize(
    ("damage", "needles"),
    [
        (lambda root: tum_file(root, "rgb", 2).write_bytes(tum_file(root, "rgb", 2).read_bytes()[:60]), ["truncated"]),
        (lambda root: tum_file(root, "depth", 1).write_bytes(b""), ["empty"]),
        (lambda root: Image.fromarray(np.zeros((8, 8), np.uint16)).save(tum_file(root, "depth", 2)), ["8x8"]),
        (lambda root: Image.fromarray(np.zeros((16, 16), np.uint8)).save(tum_file(root, "depth", 1)), ["16-bit"]),
    ],
    ids=["truncated_rgb", "empty_depth", "depth_size", "8bit_depth"],
)
def test_train_reads_every_frame_and_fails_cleanly(tmp_path, capsys, damage, needles):
    """``info`` reads only the first frame; ``train`` reads them all, so a bad later frame must fail there with
    one line, before any run folder is written."""
    root = tum_folder(tmp_path / "seq", n=3)
    damage(root)
    rc, err, out = _train(capsys, tmp_path, root)
    assert_clean_failure(rc, err, *needles, out_dir=out)


def test_train_on_single_frame_fails_clearly(tmp_path, capsys):
    rc, err, out = _train(capsys, tmp_path, tum_folder(tmp_path / "seq", n=1))
    assert_clean_failure(rc, err, "training frames", "batch", out_dir=out)


def test_train_on_data_without_depth_fails_clearly(tmp_path, capsys):
    rc, err, out = _train(capsys, tmp_path, folder_dataset(tmp_path / "f", n=4))
    assert_clean_failure(rc, err, "no depth maps", out_dir=out)


def test_train_on_nan_depth_warns_and_trains(tmp_path, capsys):
    """Invalid depth values in training data: warned once per file, masked (0 = invalid), the loss stays finite."""
    d = np.full((16, 16), 2.0, np.float32)
    d[:4] = np.nan
    root = folder_dataset(tmp_path / "f", n=4, npy_depth=[d] * 4)
    rc, err, out = _train(capsys, tmp_path, root)
    assert rc == 0, err
    assert "Traceback" not in err and err.count("codeslam: warning:") == 4, err
    assert "64 depth values are NaN" in err
    assert {"weights.safetensors", "config.yaml", "log.csv"} <= listing(out)
    with open(out / "log.csv", newline="") as f:
        assert np.isfinite(float(list(csv.DictReader(f))[-1]["loss"]))
