"""EuRoC / ASL CSV trajectories.

The EuRoC MAV ground truth (``mav0/state_groundtruth_estimate0/data.csv``) and the estimate CSVs that many
VIO/SLAM systems write share one layout::

    #timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...

one pose per line, comma-separated, the timestamp an integer in nanoseconds, the position in metres and the
orientation a quaternion **w first** (the TUM format puts w last). The pose is body-to-world ``T_wb``; any
columns after ``q_z`` (velocities, IMU biases) are ignored. Lines starting with ``#`` are comments.

Timestamps become float64 seconds in :class:`~codeslam.data.trajectory.Trajectory`. A float64 holds a
Unix time in seconds to about 0.24 microseconds, so nanoseconds do not survive exactly, but
``read(write(read(f)))`` gives back the same seconds bit for bit (the writer rounds to the nearest ns).
"""

from __future__ import annotations

from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from codeslam.data.textfile import check_increasing, check_quaternion, data_lines, finite_floats
from codeslam.data.trajectory import Trajectory, poses_from_tum_rows, tum_rows_from_poses
from codeslam.errors import DatasetError
from codeslam.io import atomic_write

NS_PER_S = 1_000_000_000


def _parse_ns(field: str) -> int:
    """A timestamp field in nanoseconds -> int ns. Integers are exact; a decimal form (``1.4e18`` or
    ``1403636579763555584.0``, written by some tools) is accepted and rounded to the nearest ns."""
    try:
        return int(field)
    except ValueError:
        return int(Decimal(field).to_integral_value())  # raises decimal.InvalidOperation / ValueError


def read_euroc_csv(path: str | Path) -> Trajectory:
    """Read an EuRoC/ASL CSV trajectory ``timestamp[ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...``.

    Returns a :class:`Trajectory` with timestamps in seconds and (N, 4, 4) float64 poses. Lines with
    fewer than 8 fields, non-numbers, non-finite values, zero quaternions or timestamps that are not
    strictly increasing raise :class:`DatasetError` naming ``file:line``.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"trajectory file not found: {path}")
    stamps_ns: list[int] = []
    rows: list[list[float]] = []  # tx ty tz qx qy qz qw (TUM order, for poses_from_tum_rows)
    for where, line in data_lines(path, "trajectory file "):
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 8:
            raise DatasetError(
                f"{where}: expected 'timestamp[ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z', "
                f"got {len(parts)} comma-separated fields"
            )
        try:
            ns = _parse_ns(parts[0])
        except (ValueError, InvalidOperation):
            raise DatasetError(f"{where}: not a number in {line!r}") from None
        vals = finite_floats(parts[1:8], where, line)
        check_quaternion(vals[3:7], where)
        check_increasing(stamps_ns, ns, where, parts[0])
        stamps_ns.append(ns)
        qw, qx, qy, qz = vals[3:7]  # EuRoC: w first
        rows.append(vals[:3] + [qx, qy, qz, qw])
    if not rows:
        raise DatasetError(f"trajectory file {path} holds no poses")
    # int / int true division is correctly rounded in Python (unlike float(ns) / 1e9).
    stamps = np.array([ns / NS_PER_S for ns in stamps_ns], dtype=np.float64)
    return Trajectory(stamps, poses_from_tum_rows(np.array(rows)))


def seconds_to_ns(t: float) -> int:
    """Float seconds -> nearest integer nanosecond, computed exactly (``t * 1e9`` in float64 would lose
    up to ~100 ns on Unix times)."""
    return int((Decimal(float(t)) * NS_PER_S).to_integral_value())


def write_euroc_csv(path: str | Path, traj: Trajectory) -> None:
    """Write ``traj`` as an EuRoC CSV (``timestamp[ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z``), atomically."""
    rows = tum_rows_from_poses(traj.poses)  # (N, 7) tx ty tz qx qy qz qw
    with atomic_write(path, "w") as f:
        f.write("#timestamp [ns], p_x [m], p_y [m], p_z [m], q_w [], q_x [], q_y [], q_z []\n")
        for t, r in zip(traj.timestamps, rows, strict=True):
            vals = [r[0], r[1], r[2], r[6], r[3], r[4], r[5]]
            f.write(f"{seconds_to_ns(t)}," + ",".join(f"{v:.9f}" for v in vals) + "\n")
