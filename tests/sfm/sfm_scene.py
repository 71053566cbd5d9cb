"""Test helper imported by the tests/sfm modules: an analytically ray-cast textured room, exact grey images and
depths for any camera pose.

The scene is a room corner (back wall, floor, left wall) with a tilted panel in front; the texture is a smooth
sum of sinusoids of the 3D surface point, so every view of a point has the same intensity (photo-consistent)."""

from __future__ import annotations

import math

import torch

from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.lie import se3_exp
from codeslam.geometry.proximity import depth_to_prox
from codeslam.sfm.decoder import standin_decoder
from codeslam.sfm.keyframes import Keyframe

# (normal n, offset h with n . X = h, box lower corner, box upper corner) of each plane, world frame, y down.
_PLANES = [
    ((0.0, 0.0, 1.0), 4.0, (-9, -9, -9), (9, 9, 9)),  # back wall z = 4
    ((0.0, 1.0, 0.0), 1.2, (-9, -9, -9), (9, 9, 9)),  # floor y = 1.2
    ((1.0, 0.0, 0.0), -2.2, (-9, -9, -9), (9, 9, 9)),  # left wall x = -2.2
    ((0.35, 0.0, -1.0), -2.3, (0.0, -0.9, -9), (1.4, 0.6, 9)),  # tilted panel, finite
]
_FREQS = torch.tensor(
    [[3.1, 1.7, 2.3], [-1.9, 4.3, 0.7], [2.6, -2.9, 3.7], [7.3, 5.1, -4.4], [-6.1, 3.3, 6.7]], dtype=torch.float64
)
_AMPS = torch.tensor([0.16, 0.14, 0.1, 0.05, 0.05], dtype=torch.float64)


def texture(X: torch.Tensor) -> torch.Tensor:
    """(..., 3) world points -> (...) grey level in about [0.1, 0.9]."""
    return 0.5 + (torch.sin(X @ _FREQS.T.to(X) + torch.arange(5, dtype=X.dtype)) * _AMPS.to(X)).sum(-1)


def render(
    T_wc: torch.Tensor, params: torch.Tensor, height: int, width: int, panel: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast the room (with the occluding panel if ``panel``): T_wc (4, 4), params (4,) -> grey (H, W),
    z-depth (H, W) (float64)."""
    fx, fy, cx, cy = params.tolist()
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64),
                          indexing="ij")
    ray_c = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u)], dim=-1)  # z = 1: lambda is z-depth
    R, o = T_wc[:3, :3].double(), T_wc[:3, 3].double()
    d = ray_c @ R.T  # (H, W, 3)
    best = torch.full((height, width), math.inf, dtype=torch.float64)
    for n, h, lo, hi in _PLANES if panel else _PLANES[:3]:
        n = torch.tensor(n, dtype=torch.float64)
        lam = (h - n @ o) / (d @ n)
        X = o + lam[..., None] * d
        inside = ((X >= torch.tensor(lo) - 1e-9) & (X <= torch.tensor(hi) + 1e-9)).all(-1) & (lam > 0.05)
        best = torch.where(inside & (lam < best), lam, best)
    X = o + best[..., None] * d
    return texture(X), best


def render_rolling_shutter(
    T_wc: torch.Tensor, params: torch.Tensor, height: int, width: int, omega: torch.Tensor, panel: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`render` by a rolling-shutter camera: row y is exposed by the camera turned by s(y) omega about its
    own centre (omega (3,), rotation vector over the readout in the camera frame, s(y) = (y - (H - 1) / 2) / H),
    exactly (not to first order). -> grey (H, W), z-depth (H, W) in each row's own camera."""
    from codeslam.geometry.lie import so3_exp

    gray = torch.empty(height, width, dtype=torch.float64)
    depth = torch.empty_like(gray)
    for y in range(height):
        T_row = T_wc.clone().double()
        T_row[:3, :3] = T_row[:3, :3] @ so3_exp(((y - 0.5 * (height - 1)) / height) * omega.double())
        g, d = render(T_row, params, height, width, panel)
        gray[y], depth[y] = g[y], d[y]
    return gray, depth


def look_pose(t=(0.0, 0.0, 0.0), rot=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """T_wc = exp((t, rot)) (float64)."""
    return se3_exp(torch.tensor([*t, *rot], dtype=torch.float64))


def make_frames(poses, width=64, height=48, code_size=8, levels=4, seed=0, code_scale=1.0, avg_depth=2.0,
                panel=True, readout=None):
    """Frames of the room at the T_wc ``poses`` with stand-in decoders whose span contains the true proximity:
    -> (keyframes, gt_codes (F, C), gt_poses (F, 4, 4)). ``readout`` (F, 3): rolling-shutter rotations of the
    frames (:func:`render_rolling_shutter`), None for global shutters."""
    cam = canonical_camera(width, height)
    gen = torch.Generator().manual_seed(seed)
    kfs, codes = [], []
    for k, T in enumerate(poses):
        if readout is None:
            gray, depth = render(T, cam.params(torch.float64), height, width, panel)
        else:
            gray, depth = render_rolling_shutter(T, cam.params(torch.float64), height, width, readout[k], panel)
        c = code_scale * torch.randn(code_size, generator=gen, dtype=torch.float64)
        dec = standin_decoder(depth_to_prox(depth, avg_depth), code_size, levels, avg_depth, code_offset=c,
                              image=gray)
        kfs.append(Keyframe(gray, cam, dec))
        codes.append(c)
    return kfs, torch.stack(codes), torch.stack(list(poses))
