"""Poses kept by the SLAM system: float64 on the CPU, with rotations that stay rotations.

The solver may run in float32, where every pose carries rotation errors of ~1e-7. The system composes poses
for its motion model (``T_last T_prev^-1 T_cur``) with :func:`~codeslam.geometry.lie.se3_inverse`, which
transposes the rotation; that is exact only for orthonormal rotations, and otherwise the determinant error
compounds geometrically from frame to frame (measured on a generator sequence: det(R) 1 - 1e-7 at frame 1,
0.85 by frame 17). Every pose that leaves the solver is therefore projected back onto SE(3).
"""

from __future__ import annotations

import math

import torch

from codeslam.geometry.lie import se3_exp, se3_exp_host, se3_inverse, se3_log, se3_log_host, so3_angle_host


def project_to_se3(T: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) -> the same transforms in float64 on the CPU with the rotation replaced by the closest rotation
    in the Frobenius norm, ``U diag(1, 1, det(U V^T)) V^T`` from the SVD ``R = U S V^T``, and the last row
    ``[0, 0, 0, 1]``."""
    T = T.detach().to(device="cpu", dtype=torch.float64)
    U, _, Vt = torch.linalg.svd(T[..., :3, :3])
    d = torch.det(U @ Vt)  # (...,) +-1: flip the smallest axis of a reflection
    S = torch.ones(T.shape[:-2] + (3,), dtype=T.dtype)
    S[..., 2] = d
    out = T.clone()
    out[..., :3, :3] = (U * S.unsqueeze(-2)) @ Vt
    out[..., 3, :] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=T.dtype)
    return out


def spread_correction(T_ref: torch.Tensor, T_next: torch.Tensor, fraction: torch.Tensor) -> torch.Tensor:
    """Poses of the frames between two keyframes, moved part of the way from where their own keyframe puts them
    to where the next keyframe does: T_ref, T_next (n, 4, 4), fraction (n,) in [0, 1] ->
    ``T_ref Exp(f Log(T_ref^-1 T_next))`` (n, 4, 4), float64 on the CPU and projected onto SE(3).

    ``T_ref`` is a frame's pose through its reference keyframe (``T_wk T_kf``); ``T_next`` through the next
    keyframe, which was tracked against the same reference (``T_wk' T_k'k T_kf``). The two differ by what the
    window solves changed between the two keyframes after tracking; the frame takes that change in proportion to
    its time between them (``fraction`` 0 at its keyframe, 1 at the next), so the trajectory does not jump where
    the frames switch keyframe. Written by hand: the geodesic between two poses, nothing a library gives."""
    T_ref = T_ref.to(dtype=torch.float64, device="cpu")
    T_next = T_next.to(dtype=torch.float64, device="cpu")
    xi = se3_log(se3_inverse(T_ref) @ T_next)  # (n, 6)
    f = fraction.to(torch.float64).clamp(0.0, 1.0).unsqueeze(-1)
    return project_to_se3(T_ref @ se3_exp(f * xi))


def path_fractions(T_path: torch.Tensor, median_depth: float) -> torch.Tensor | None:
    """How far along the tracked path from a keyframe to the next one each frame between them lies: T_path (n + 1,
    4, 4) the frames' poses in the keyframe, in order, the last one the next keyframe's -> (n,) fractions in [0, 1]
    of the path's length at each of the first n; None where the path has no length (no motion was tracked).

    A step's length is its parallax, ``|t| / median_depth + angle`` (radians; :func:`~codeslam.slam.keyframes.
    motion_since_keyframe`'s two measures, a rotation by ``a`` moving the scene about as far as a translation by
    ``a`` times its depth), so a camera that stands still adds nothing. What :func:`spread_correction` spreads is
    what the window changed after tracking, which grows with the motion tracked, not with the time: spread by time,
    frames of a camera held still for 4 s between two keyframes turned by 0.5 deg and moved by 14 mm one after
    another (the HoloLens walk with its frame 60 shown 40 times, with noise; docs/results/slam_table.md,
    forty-ninth session)."""
    T = T_path.detach().to(device="cpu", dtype=torch.float64)
    prev = torch.cat([torch.eye(4, dtype=torch.float64)[None], T[:-1]])
    steps = se3_inverse(prev) @ T  # (n + 1, 4, 4) one frame to the next
    length = [float(s[:3, 3].norm()) / median_depth + so3_angle_host(s[:3, :3]) for s in steps]
    cum = torch.tensor(length, dtype=torch.float64).cumsum(0)
    total = float(cum[-1])
    if not (math.isfinite(total) and total > 0.0):
        return None
    return (cum[:-1] / total).clamp(0.0, 1.0)


def scale_motion(motion: torch.Tensor, s: float) -> torch.Tensor:
    """A constant velocity's motion over ``s`` times the interval of ``motion``: (4, 4) ``T_prev^-1 T_cur`` ->
    ``Exp(s Log(motion))`` (the same camera-frame twist for s times as long; s = 0 gives the identity); ``motion``
    itself when s is 1 or not finite (frames without usable timestamps: one motion a frame)."""
    if not math.isfinite(s) or s == 1.0:
        return motion
    return se3_exp_host(s * se3_log_host(motion.to(torch.float64))).to(motion.dtype)
