"""scripts/reorder_copy.py: the copies of a sequence played backwards, or there and back, that the SLAM probes of a
camera coming back the way it went run on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from codeslam.data.tum import TumSequence

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "reorder_copy.py"


def _sequence(root: Path, n: int) -> None:
    """``n`` frames at 10 frames/s with jittered stamps, depth 5 ms off the colour, a pose per frame."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, depth, gt = [], [], []
    for i in range(n):
        t = 1.0 + 0.1 * i + (0.01 if i == 2 else 0.0)
        cv2.imwrite(str(root / "rgb" / f"{t:.3f}.png"), np.full((6, 8, 3), 30 * (i + 1), np.uint8))
        cv2.imwrite(str(root / "depth" / f"{t + 0.005:.3f}.png"), np.full((6, 8), 5000 + 100 * i, np.uint16))
        rgb.append(f"{t:.3f} rgb/{t:.3f}.png\n")
        depth.append(f"{t + 0.005:.3f} depth/{t + 0.005:.3f}.png\n")
        gt.append(f"{t:.3f} {i} {2 * i} 0 0 0 0 1\n")
    (root / "rgb.txt").write_text("# colour\n" + "".join(rgb))
    (root / "depth.txt").write_text("".join(depth))
    (root / "groundtruth.txt").write_text("".join(gt))
    (root / "calib.txt").write_text("10 10 4 3\n")


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


def test_a_missing_sequence_is_a_one_line_error_and_writes_nothing(tmp_path):
    done = _run(tmp_path / "nowhere", tmp_path / "out", "--order", "reverse")
    assert done.returncode == 2
    assert "nowhere" in done.stderr.strip().splitlines()[-1] and "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists()
