"""Trajectory loading with format detection."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from codeslam.data.euroc_csv import write_euroc_csv
from codeslam.data.trajectory import Trajectory, poses_from_tum_rows, write_tum
from codeslam.data.trajectory_file import detect_format, load_trajectory
from codeslam.errors import DatasetError


@pytest.fixture
def traj() -> Trajectory:
    rng = np.random.default_rng(0)
    rows = np.concatenate([rng.normal(size=(6, 3)), rng.normal(size=(6, 4))], axis=1)
    return Trajectory(1.4e9 + np.arange(6) * 0.05, poses_from_tum_rows(rows))


def test_detects_and_reads_both_formats(tmp_path, traj):
    write_tum(tmp_path / "a.txt", traj)
    write_euroc_csv(tmp_path / "b.csv", traj)
    assert detect_format(tmp_path / "a.txt") == "tum"
    assert detect_format(tmp_path / "b.csv") == "euroc"
    for name in ("a.txt", "b.csv"):
        back = load_trajectory(tmp_path / name)
        np.testing.assert_allclose(back.timestamps, traj.timestamps, atol=1e-6)
        torch.testing.assert_close(back.poses, traj.poses, rtol=0, atol=1e-8)


def test_comma_separated_tum_and_explicit_format(tmp_path, traj):
    p = tmp_path / "t.csv"
    p.write_text("# t,x,y,z,qx,qy,qz,qw\n1305031225.9334,1.3357,0.6698,1.6180,0.6504,0.6012,-0.3056,-0.3496\n")
    assert detect_format(p) == "tum"  # seconds, not integer nanoseconds
    assert len(load_trajectory(p)) == 1
    write_euroc_csv(tmp_path / "e.txt", traj)
    assert len(load_trajectory(tmp_path / "e.txt", format="euroc")) == 6
    with pytest.raises(DatasetError, match="unknown trajectory format"):
        load_trajectory(p, format="kitti")


@pytest.mark.parametrize(
    ("content", "match"),
    [("# only a comment\n", "holds no poses"), ("1 2 3\n", "t.txt:1: cannot tell")],
)
def test_undetectable(tmp_path, content, match):
    p = tmp_path / "t.txt"
    p.write_text(content)
    with pytest.raises(DatasetError, match=match):
        load_trajectory(p)
    with pytest.raises(DatasetError, match="not found"):
        load_trajectory(tmp_path / "missing.txt")
