"""Forward warping of a depth map into another view of the same camera: each pixel's 3D point is moved into the
other view and written to the pixel it lands on, the nearest surface winning where several land (a z-buffer).

Written by hand: the warps of torch and kornia sample a source image at the pixels of a destination whose depth is
known (backward warping); here the destination's depth is what is sought, so the source must be pushed forward.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from codeslam.geometry.camera import PinholeCamera, pixel_grid, project, unproject
from codeslam.geometry.lie import se3_act


def splat_depth(depth: torch.Tensor, camera: PinholeCamera, T_dst_src: torch.Tensor,
                valid: torch.Tensor | None = None) -> torch.Tensor:
    """(H, W) z-depth of a source view -> (H, W) z-depth of the same surface in a destination view of the same
    camera at ``T_dst_src`` (4, 4; source to destination coordinates), +inf where nothing lands.

    Each source pixel (finite positive depth, and ``valid`` where given) goes to the destination pixel nearest to
    its projection; where several land on one pixel the nearest surface wins; a pixel that none reached takes the
    nearest depth among its 3x3 neighbours (the one-pixel cracks that a slanted or approaching surface leaves when
    its pixels spread apart). Computed in float64."""
    H, W = depth.shape
    d = depth.to(torch.float64)
    params = camera.params(torch.float64, d.device)
    ok = torch.isfinite(d) & (d > 0)
    if valid is not None:
        ok &= valid.to(d.device)
    xyz = se3_act(T_dst_src.to(d), unproject(pixel_grid(H, W, torch.float64, d.device), d.nan_to_num(0.0), params))
    z = xyz[..., 2]
    ok &= z > 1e-6
    uv = project(torch.where(ok.unsqueeze(-1), xyz, torch.ones_like(xyz)), params).round()
    u, v = uv[..., 0], uv[..., 1]
    ok &= (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    idx = (v[ok] * W + u[ok]).long()
    zbuf = torch.full((H * W,), float("inf"), dtype=torch.float64, device=d.device)
    zbuf.scatter_reduce_(0, idx, z[ok], reduce="amin")
    zbuf = zbuf.view(1, 1, H, W)
    nearest = -F.max_pool2d(-zbuf, 3, stride=1, padding=1)
    return torch.where(torch.isfinite(zbuf), zbuf, nearest)[0, 0]
