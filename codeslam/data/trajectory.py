"""Camera trajectories and their files.

A :class:`Trajectory` holds timestamps and camera-to-world poses ``T_wc``. The TUM format is one pose per
line, ``timestamp tx ty tz qx qy qz qw`` (camera-to-world, the position of the optical centre in the world);
``#`` starts a comment.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from codeslam.data.textfile import check_increasing, check_quaternion, data_lines, finite_floats
from codeslam.errors import DatasetError
from codeslam.geometry.quaternion import quat_xyzw_to_rotmat, rotmat_to_quat_xyzw
from codeslam.io import atomic_write


@dataclass
class Trajectory:
    """Timestamped camera-to-world poses.

    Attributes:
        timestamps: (N,) float64 seconds, strictly increasing.
        poses: (N, 4, 4) float64 ``T_wc``.
    """

    timestamps: np.ndarray
    poses: torch.Tensor

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64)
        self.poses = torch.as_tensor(self.poses, dtype=torch.float64)
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise ValueError(f"poses must be (N, 4, 4), got {tuple(self.poses.shape)}")
        if len(self.timestamps) != len(self.poses):
            raise ValueError(f"{len(self.timestamps)} timestamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions_xyz(self) -> torch.Tensor:
        """(N, 3) camera centres in the world."""
        return self.poses[:, :3, 3]

    @property
    def path_length(self) -> float:
        """Travelled distance in metres (sum of distances between consecutive positions)."""
        if len(self) < 2:
            return 0.0
        return float((self.positions_xyz[1:] - self.positions_xyz[:-1]).norm(dim=-1).sum())

    def subset(self, idx) -> Trajectory:
        idx = np.asarray(idx)
        return Trajectory(self.timestamps[idx], self.poses[torch.as_tensor(idx)])


def poses_from_tum_rows(rows: np.ndarray) -> torch.Tensor:
    """(N, 7) ``tx ty tz qx qy qz qw`` -> (N, 4, 4) float64 ``T_wc``."""
    rows_t = torch.as_tensor(rows, dtype=torch.float64)
    T = torch.eye(4, dtype=torch.float64).repeat(len(rows_t), 1, 1)
    T[:, :3, :3] = quat_xyzw_to_rotmat(rows_t[:, 3:7])
    T[:, :3, 3] = rows_t[:, :3]
    return T


def tum_rows_from_poses(poses: torch.Tensor) -> np.ndarray:
    """(N, 4, 4) ``T_wc`` -> (N, 7) ``tx ty tz qx qy qz qw``."""
    poses = torch.as_tensor(poses, dtype=torch.float64)
    q = rotmat_to_quat_xyzw(poses[:, :3, :3])
    return torch.cat([poses[:, :3, 3], q], dim=-1).numpy()


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file. Malformed lines, non-finite values, zero quaternions and timestamps
    that are not strictly increasing raise :class:`DatasetError` naming the file and line."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"trajectory file not found: {path}")
    stamps: list[float] = []
    rows: list[list[float]] = []
    for where, line in data_lines(path, "trajectory file "):
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise DatasetError(f"{where}: expected 'timestamp tx ty tz qx qy qz qw', got {len(parts)} fields")
        vals = finite_floats(parts, where, line)
        check_quaternion(vals[4:8], where)
        check_increasing(stamps, vals[0], where, parts[0])
        stamps.append(vals[0])
        rows.append(vals[1:])
    if not rows:
        raise DatasetError(f"trajectory file {path} holds no poses")
    return Trajectory(np.array(stamps), poses_from_tum_rows(np.array(rows)))


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Write ``traj`` in TUM format, atomically."""
    rows = tum_rows_from_poses(traj.poses)
    with atomic_write(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw (camera-to-world)\n")
        for t, r in zip(traj.timestamps, rows, strict=True):
            f.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in r) + "\n")
