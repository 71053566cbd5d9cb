"""Bad trajectories and output paths for ``codeslam eval``: one error line, exit 2, no JSON / plot / temporary
left behind. (tests/eval/test_eval_cli.py covers a missing file, a non-number, no overlap, 2 matches and a
collinear estimate against the real TUM ground truth; these use small generated files and add the rest.)"""

from __future__ import annotations

import os

import numpy as np
import pytest
from corpus import assert_clean_failure, listing, run_cli, temp_files, trajectory_file

STAMPS = 100.0 + np.arange(30) * 0.1


def _write(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return p


BAD_ESTIMATES = {
    "empty": (b"", ["holds no poses"]),
    "only_comments": ("# timestamp tx ty tz qx qy qz qw\n\n# nothing\n", ["holds no poses"]),
    "binary_garbage": (b"\x89\xff\xfe" + bytes(range(256)) * 4, ["cannot read trajectory file"]),
    "nul_bytes": (b"\x00" * 64, ["cannot tell the trajectory format"]),
    "seven_fields": ("100.0 0 0 0 0 0 1\n", ["cannot tell the trajectory format"]),
    "nan_position": ("100.0 nan 0 0 0 0 0 1\n100.1 0 0 0 0 0 0 1\n", ["est.txt:1", "non-finite"]),
    "inf_timestamp": ("inf 0 0 0 0 0 0 1\n", ["est.txt:1", "non-finite"]),
    "zero_quaternion": ("100.0 0 0 0 0 0 0 0\n", ["est.txt:1", "zero quaternion"]),
    "duplicate_timestamps": ("100.0 0 0 0 0 0 0 1\n100.0 1 0 0 0 0 0 1\n", ["est.txt:2", "not after the previous"]),
    "out_of_order": ("100.1 0 0 0 0 0 0 1\n100.0 1 0 0 0 0 0 1\n", ["est.txt:2", "not after the previous"]),
    "tum_line_then_junk": ("100.0 0 0 0 0 0 0 1\n100.1 0 0 0 0 0 0\n", ["est.txt:2", "expected"]),
    "euroc_bad_line": ("100000000000,0,0,0,1,0,0,0\n100100000000,0,0\n", ["est.txt:2"]),
    "euroc_not_a_number": ("100000000000,0,0,x,1,0,0,0\n", ["est.txt:1", "not a number"]),
    "single_pose": ("100.0 0 0 0 0 0 0 1\n", ["at least 3"]),
    "two_matches": ("100.0 0 0 0 0 0 0 1\n100.1 1 0 0 0 0 0 1\n", ["at least 3"]),
    "no_overlap": ("".join(f"{500 + k} {k} {k * k} 0 0 0 0 1\n" for k in range(10)), ["do not overlap"]),
    "identical_positions": ("".join(f"{100 + k / 10:.1f} 1 2 3 0 0 0 1\n" for k in range(10)), ["collinear"]),
}


@pytest.mark.parametrize("name", sorted(BAD_ESTIMATES))
def test_bad_estimate(tmp_path, capsys, name):
    content, needles = BAD_ESTIMATES[name]
    est = _write(tmp_path, "est.txt", content)
    gt = trajectory_file(tmp_path / "gt.txt", STAMPS)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, "eval", est, gt, "--json", out / "r.json", "--plot", out / "p.png")
    assert_clean_failure(rc, err, *needles, out_dir=out)


@pytest.mark.parametrize("name", ["empty", "binary_garbage", "single_pose"])
def test_bad_groundtruth(tmp_path, capsys, name):
    content, needles = BAD_ESTIMATES[name]
    est = trajectory_file(tmp_path / "e.txt", STAMPS)
    gt = _write(tmp_path, "est.txt", content)  # same name, so that the needles hold
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, "eval", est, gt, "--json", out / "r.json")
    assert_clean_failure(rc, err, *needles, out_dir=out)


def test_trajectory_path_is_a_folder(tmp_path, capsys):
    gt = trajectory_file(tmp_path / "gt.txt", STAMPS)
    rc, _, err = run_cli(capsys, "eval", tmp_path, gt)
    assert_clean_failure(rc, err, "not found")


@pytest.mark.parametrize("option", ["--json", "--plot", "--drift-plot"])
@pytest.mark.parametrize("where", ["is_a_folder", "parent_is_a_file"])
def test_unwritable_output_fails_before_the_work(tmp_path, capsys, option, where):
    """An output path that cannot be written is refused up front, with one line and nothing written."""
    est = trajectory_file(tmp_path / "e.txt", STAMPS, seed=1)
    gt = trajectory_file(tmp_path / "gt.txt", STAMPS)
    (tmp_path / "blocker").write_text("a file")
    (tmp_path / "adir").mkdir()
    target = tmp_path / "adir" if where == "is_a_folder" else tmp_path / "blocker" / "r.out"
    before = listing(tmp_path)
    rc, out, err = run_cli(capsys, "eval", est, gt, option, target)
    assert_clean_failure(rc, err, "cannot write", str(target) if where == "is_a_folder" else "blocker")
    assert "ATE" not in out  # refused before evaluating
    assert listing(tmp_path) == before and not temp_files(tmp_path)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes whatever the mode")
def test_read_only_output_folder(tmp_path, capsys):
    est = trajectory_file(tmp_path / "e.txt", STAMPS, seed=1)
    gt = trajectory_file(tmp_path / "gt.txt", STAMPS)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        rc, _, err = run_cli(capsys, "eval", est, gt, "--json", ro / "r.json")
        assert_clean_failure(rc, err, "cannot write", out_dir=ro)
    finally:
        ro.chmod(0o700)


def test_good_pair_still_evaluates(tmp_path, capsys):
    est = trajectory_file(tmp_path / "e.txt", STAMPS, seed=1)
    gt = trajectory_file(tmp_path / "gt.txt", STAMPS)
    rc, _, err = run_cli(capsys, "eval", est, gt, "--json", tmp_path / "o" / "r.json")
    assert rc == 0, err
    assert listing(tmp_path / "o") == {"r.json"}
