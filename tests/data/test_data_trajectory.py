import numpy as np
import pytest
import torch

from codeslam.data.trajectory import Trajectory, read_tum, write_tum
from codeslam.errors import DatasetError


def test_tum_groundtruth_reads(tum_rpy):
    traj = read_tum(tum_rpy / "groundtruth.txt")
    assert len(traj) == 2742  # the README's count
    assert np.all(np.diff(traj.timestamps) > 0)
    R = traj.poses[:, :3, :3]
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(R), atol=1e-6)
    # first line: 1305031225.9334 1.3357 0.6698 1.6180 ...
    assert traj.timestamps[0] == pytest.approx(1305031225.9334)
    assert torch.allclose(traj.poses[0, :3, 3], torch.tensor([1.3357, 0.6698, 1.6180], dtype=torch.float64))


def test_round_trip(tmp_path, tum_rpy):
    traj = read_tum(tum_rpy / "groundtruth.txt").subset(np.arange(0, 2742, 50))
    write_tum(tmp_path / "t.txt", traj)
    back = read_tum(tmp_path / "t.txt")
    assert np.allclose(back.timestamps, traj.timestamps, atol=1e-6)
    assert torch.allclose(back.poses, traj.poses, atol=1e-8)


@pytest.mark.parametrize(
    "content, match",
    [
        ("1 0 0 0 0 0 0\n", "expected"),
        ("1 0 0 0 0 0 0 x\n", "not a number"),
        ("1 0 0 nan 0 0 0 1\n", "non-finite"),
        ("1 0 0 0 0 0 0 0\n", "zero quaternion"),
        ("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", "not after"),
        ("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", "not after"),
        ("# only a comment\n", "no poses"),
    ],
)
def test_malformed_files_fail_with_line(tmp_path, content, match):
    p = tmp_path / "bad.txt"
    p.write_text(content)
    with pytest.raises(DatasetError, match=match):
        read_tum(p)


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        read_tum(tmp_path / "nope.txt")


def test_shape_checks():
    with pytest.raises(ValueError):
        Trajectory(np.zeros(2), torch.zeros(3, 4, 4))
