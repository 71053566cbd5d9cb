"""Poses kept by the SLAM system: float64 on the CPU, with rotations that stay rotations.

The solver may run in float32, where every pose carries rotation errors of ~1e-7. The system composes poses
for its motion model (``T_last T_prev^-1 T_cur``) with :func:`~codeslam.geometry.lie.se3_inverse`, which
transposes the rotation; that is exact only for orthonormal rotations, and otherwise the determinant error
compounds geometrically from frame to frame (measured on a generator sequence: det(R) 1 - 1e-7 at frame 1,
0.85 by frame 17). Every pose that leaves the solver is therefore projected back onto SE(3).
"""

from __future__ import annotations

import torch


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
