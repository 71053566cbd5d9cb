"""scripts/issue13/exposure_copy.py: the copies with an exposure change that the depth-prior and SLAM measurements
of a brightness change are made on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "issue13" / "exposure_copy.py"


def _sequence(root: Path, n: int) -> list[np.ndarray]:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    images = [np.full((6, 8, 3), 40 * (i + 1), np.uint8) for i in range(n)]
    lines = []
    for i, img in enumerate(images):
        cv2.imwrite(str(root / "rgb" / f"{i}.png"), img)
        cv2.imwrite(str(root / "depth" / f"{i}.png"), np.full((6, 8), 5000 + i, np.uint16))
        lines.append(f"{i}.0 rgb/{i}.png")
    (root / "rgb.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")
    (root / "depth.txt").write_text("".join(f"{i}.0 depth/{i}.png\n" for i in range(n)))
    (root / "calib.txt").write_text("10 10 4 3\n")
    return images


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_a_step_multiplies_the_frames_from_its_start_and_clips_at_white(tmp_path):
    images = _sequence(tmp_path / "src", 4)
    assert _run(tmp_path / "src", tmp_path / "out", "--gain", 1.8, "--start", 2).returncode == 0
    for i, img in enumerate(images):
        out = cv2.imread(str(tmp_path / "out" / "rgb" / f"{i}.png"), cv2.IMREAD_UNCHANGED)
        want = img if i < 2 else np.clip(img.astype(np.float32) * 1.8, 0, 255).astype(np.uint8)
        assert np.array_equal(out, want)
    assert int(cv2.imread(str(tmp_path / "out" / "rgb" / "3.png"))[0, 0, 0]) == 255  # 160 x 1.8, clipped
    depth = cv2.imread(str(tmp_path / "out" / "depth" / "3.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and int(depth[0, 0]) == 5003  # depth and lists as they were
    assert (tmp_path / "out" / "rgb.txt").read_text() == (tmp_path / "src" / "rgb.txt").read_text()


def test_a_ramp_rises_to_the_gain_and_falls_back_to_one(tmp_path):
    images = _sequence(tmp_path / "src", 6)
    assert _run(tmp_path / "src", tmp_path / "out", "--gain", 0.5, "--start", 1, "--ramp", 2).returncode == 0
    gains = [1.0, 1.0, 0.75, 0.5, 0.75, 1.0]  # frames 1..5: x = 0, 0.5, 1, 1.5, 2
    for i, (img, g) in enumerate(zip(images, gains)):
        out = cv2.imread(str(tmp_path / "out" / "rgb" / f"{i}.png"))
        assert int(out[0, 0, 0]) == int(img[0, 0, 0] * g)


def test_a_bad_gain_or_list_is_refused_in_one_line(tmp_path):
    _sequence(tmp_path / "src", 2)
    r = _run(tmp_path / "src", tmp_path / "out", "--gain", 0)
    assert r.returncode == 2 and "--gain must be positive" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()
    (tmp_path / "src" / "rgb.txt").write_text("0.0 rgb/0.png\n1.0 rgb/9.png\n")  # a list naming a missing file
    r = _run(tmp_path / "src", tmp_path / "out", "--gain", 0.5)
    assert r.returncode == 2 and "rgb.txt:2" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()
