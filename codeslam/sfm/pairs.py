"""Which frame pairs get residuals: a master keyframe with every other frame (the paper's Table 1 setup), all
pairs, or the pairs whose views overlap under a pose guess. A pair (A, B) warps A's pixels into B; with
``both_directions`` the reverse pair is added too, so every frame's image constrains its own code."""

from __future__ import annotations

import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, pixel_grid
from codeslam.geometry.image import inside_image
from codeslam.sfm.warp import relative_pose, warp


def master_pairs(num_frames: int, master: int = 0, both_directions: bool = True) -> list[tuple[int, int]]:
    """(master, k) for every other frame k (and (k, master) if ``both_directions``)."""
    if not 0 <= master < num_frames:
        raise CodeSLAMError(f"master frame {master} is not one of the {num_frames} frames")
    out = []
    for k in range(num_frames):
        if k != master:
            out.append((master, k))
            if both_directions:
                out.append((k, master))
    return out


def all_pairs(num_frames: int, both_directions: bool = True) -> list[tuple[int, int]]:
    """Every (i, j) with i < j (and (j, i) if ``both_directions``)."""
    return [(i, j) for i in range(num_frames) for j in range(num_frames)
            if i != j and (both_directions or i < j)]


def view_overlap(poses: torch.Tensor, camera: PinholeCamera, depth: float, step: int = 8) -> torch.Tensor:
    """(F, 4, 4) T_wc -> (F, F) fraction of A's pixels (a grid every ``step`` pixels, at constant ``depth``)
    that land inside B; entry [a, b]. The diagonal is 1."""
    F_ = poses.shape[0]
    uv = pixel_grid(camera.height, camera.width, poses.dtype, poses.device)[::step, ::step].reshape(1, -1, 2)
    idx = torch.arange(F_, device=poses.device)
    iA, iB = torch.meshgrid(idx, idx, indexing="ij")
    iA, iB = iA.reshape(-1), iB.reshape(-1)
    T_BA = relative_pose(poses[iA], poses[iB])  # (F F, 4, 4)
    params = camera.params(poses.dtype, poses.device)
    d = torch.full(uv.shape[:-1], float(depth), dtype=poses.dtype, device=poses.device).expand(F_ * F_, -1)
    v, x, _ = warp(uv.expand(F_ * F_, -1, -1), d, T_BA, params, params)
    ok = inside_image(v, camera.height, camera.width) & (x[..., 2] > 0)
    return ok.to(poses.dtype).mean(-1).reshape(F_, F_)


def overlapping_pairs(
    poses: torch.Tensor, camera: PinholeCamera, depth: float, min_overlap: float = 0.5, step: int = 8
) -> list[tuple[int, int]]:
    """Every (A, B), A != B, whose :func:`view_overlap` is at least ``min_overlap`` (directions decided apart)."""
    ov = view_overlap(poses, camera, depth, step)
    F_ = poses.shape[0]
    return [(a, b) for a in range(F_) for b in range(F_) if a != b and float(ov[a, b]) >= min_overlap]
