"""Matching timestamps between streams, and ground-truth poses at arbitrary times.

:func:`associate` pairs two timestamp lists one-to-one the way the TUM RGB-D benchmark's ``associate.py``
does: among all pairs closer than ``max_diff``, take the closest pair, remove both, repeat. Written here
(not imported) because the benchmark script is a stand-alone Python 2 file, not a library, and because
its all-pairs search is O(N M); this version only forms the pairs inside the ``max_diff`` window.

:func:`interpolate_poses` evaluates a ground-truth trajectory at frame timestamps: position linearly,
rotation by quaternion slerp, between the two neighbouring samples. A timestamp outside the trajectory's
span, or between two samples further apart than ``max_gap`` (a motion-capture dropout), gets no pose.
"""

from __future__ import annotations

import numpy as np
import torch

from codeslam.data.trajectory import Trajectory
from codeslam.geometry.quaternion import quat_slerp, quat_xyzw_to_rotmat, rotmat_to_quat_xyzw


def associate(
    ts_a: np.ndarray, ts_b: np.ndarray, max_diff: float, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy one-to-one nearest-timestamp association.

    Args:
        ts_a: (N,) seconds. ts_b: (M,) seconds (neither needs to be sorted).
        max_diff: pairs with ``|a - (b + offset)| > max_diff`` are never formed.
        offset: added to ``ts_b`` before comparing (a known clock offset).

    Returns:
        ``(idx_a, idx_b)``: (K,) int64 index arrays, sorted by ``idx_a``; ``ts_a[idx_a[k]]`` matches
        ``ts_b[idx_b[k]]``. Pairs are chosen in order of increasing time difference (ties broken by
        ``idx_a`` then ``idx_b``), each element used at most once.
    """
    a = np.asarray(ts_a, dtype=np.float64).reshape(-1)
    b = np.asarray(ts_b, dtype=np.float64).reshape(-1) + offset
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order_b = np.argsort(b, kind="stable")
    b_sorted = b[order_b]
    lo = np.searchsorted(b_sorted, a - max_diff, side="left")  # (N,) first candidate
    hi = np.searchsorted(b_sorted, a + max_diff, side="right")  # (N,) one past the last candidate
    counts = hi - lo
    cand_a = np.repeat(np.arange(len(a)), counts)  # (P,) every pair inside the window
    cand_pos = np.concatenate([np.arange(l, h) for l, h in zip(lo, hi)]) if counts.sum() else np.zeros(0, int)
    cand_b = order_b[cand_pos.astype(np.int64)]
    diff = np.abs(a[cand_a] - b[cand_b])
    keep = diff <= max_diff
    cand_a, cand_b, diff = cand_a[keep], cand_b[keep], diff[keep]
    order = np.lexsort((cand_b, cand_a, diff))  # smallest difference first
    used_a = np.zeros(len(a), dtype=bool)
    used_b = np.zeros(len(b), dtype=bool)
    out_a: list[int] = []
    out_b: list[int] = []
    for k in order:
        i, j = cand_a[k], cand_b[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out_a.append(int(i))
            out_b.append(int(j))
    idx_a = np.array(out_a, dtype=np.int64)
    idx_b = np.array(out_b, dtype=np.int64)
    s = np.argsort(idx_a, kind="stable")
    return idx_a[s], idx_b[s]


def interpolate_poses(
    traj: Trajectory, timestamps: np.ndarray, max_gap: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Poses of ``traj`` at ``timestamps``.

    Args:
        traj: ground truth with strictly increasing timestamps, poses (M, 4, 4) ``T_wc``.
        timestamps: (N,) seconds.
        max_gap: largest spacing (seconds) of the two samples around a timestamp for it to be valid.

    Returns:
        poses: (N, 4, 4) float64, NaN where invalid.
        valid: (N,) bool. A timestamp equal to a sample is always valid; otherwise it must lie strictly
        inside the trajectory's span between two samples at most ``max_gap`` apart.
    """
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    ts = traj.timestamps
    n, m = len(t), len(ts)
    poses = torch.full((n, 4, 4), float("nan"), dtype=torch.float64)
    valid = np.zeros(n, dtype=bool)
    if n == 0 or m == 0:
        return poses, torch.from_numpy(valid)
    exact = np.searchsorted(ts, t, side="left")  # (N,) index of a sample equal to t, if any
    exact_c = np.clip(exact, 0, m - 1)
    is_exact = ts[exact_c] == t
    if m >= 2:
        i0 = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, m - 2)  # (N,) left neighbour
        i1 = i0 + 1
        inside = (t >= ts[0]) & (t <= ts[-1])
        small_gap = (ts[i1] - ts[i0]) <= max_gap
        valid = is_exact | (inside & small_gap)
        alpha = np.clip((t - ts[i0]) / (ts[i1] - ts[i0]), 0.0, 1.0)  # (N,)
        P0, P1 = traj.poses[torch.from_numpy(i0)], traj.poses[torch.from_numpy(i1)]  # (N, 4, 4)
        a = torch.from_numpy(alpha)
        q = quat_slerp(rotmat_to_quat_xyzw(P0[:, :3, :3]), rotmat_to_quat_xyzw(P1[:, :3, :3]), a)  # (N, 4)
        interp = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
        interp[:, :3, :3] = quat_xyzw_to_rotmat(q)
        interp[:, :3, 3] = (1 - a)[:, None] * P0[:, :3, 3] + a[:, None] * P1[:, :3, 3]
    else:
        valid = is_exact
        interp = traj.poses[[0] * n].clone()
    # Exact hits take the sample itself (no round trip through quaternions).
    interp[torch.from_numpy(is_exact)] = traj.poses[torch.from_numpy(exact_c[is_exact])]
    v = torch.from_numpy(valid)
    poses[v] = interp[v]
    return poses, v
