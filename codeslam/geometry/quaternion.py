"""Unit quaternions in the TUM/ROS order ``(qx, qy, qz, qw)`` and rotation matrices."""

from __future__ import annotations

import torch


def quat_xyzw_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternion ``(x, y, z, w)`` -> (..., 3, 3) rotation matrix. The quaternion is normalised first."""
    q = q / q.norm(dim=-1, keepdim=True)
    x, y, z, w = q.unbind(-1)
    R = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat_xyzw(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation matrix -> (..., 4) unit quaternion ``(x, y, z, w)`` with ``w >= 0``.

    Shepperd's method: pick the largest of the four squared components to divide by, which keeps the
    conversion stable for every rotation.
    """
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # 4 * component^2 for w, x, y, z
    cand = torch.stack(
        [
            1 + tr,
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ],
        dim=-1,
    )
    idx = cand.argmax(dim=-1, keepdim=True)
    s = 2 * torch.sqrt(cand.gather(-1, idx).clamp_min(1e-30)).squeeze(-1)  # 4 * largest component
    w_ = torch.stack([s / 4, (m[..., 2, 1] - m[..., 1, 2]) / s, (m[..., 0, 2] - m[..., 2, 0]) / s,
                      (m[..., 1, 0] - m[..., 0, 1]) / s], -1)
    x_ = torch.stack([(m[..., 2, 1] - m[..., 1, 2]) / s, s / 4, (m[..., 0, 1] + m[..., 1, 0]) / s,
                      (m[..., 0, 2] + m[..., 2, 0]) / s], -1)
    y_ = torch.stack([(m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s, s / 4,
                      (m[..., 1, 2] + m[..., 2, 1]) / s], -1)
    z_ = torch.stack([(m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
                      (m[..., 1, 2] + m[..., 2, 1]) / s, s / 4], -1)
    wxyz = torch.stack([w_, x_, y_, z_], dim=-2)  # (..., 4 cases, 4 comps)
    q_wxyz = wxyz.gather(-2, idx.unsqueeze(-1).expand(idx.shape[:-1] + (1, 4))).squeeze(-2)
    q_wxyz = q_wxyz * torch.where(q_wxyz[..., :1] < 0, -1.0, 1.0).to(q_wxyz.dtype)
    q = torch.cat([q_wxyz[..., 1:], q_wxyz[..., :1]], dim=-1)
    return q / q.norm(dim=-1, keepdim=True)


def quat_slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation between unit quaternions (..., 4) at fraction ``t`` (...,) in [0, 1]."""
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)  # take the short way round
    dot = dot.abs().clamp(max=1.0)
    t = t.unsqueeze(-1)
    theta = torch.arccos(dot)
    sin_theta = torch.sin(theta)
    small = sin_theta < 1e-9
    w0 = torch.where(small, 1 - t, torch.sin((1 - t) * theta) / torch.where(small, 1.0, sin_theta))
    w1 = torch.where(small, t, torch.sin(t * theta) / torch.where(small, 1.0, sin_theta))
    q = w0 * q0 + w1 * q1
    return q / q.norm(dim=-1, keepdim=True)
