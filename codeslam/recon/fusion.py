"""Fusing keyframe depth maps into one coloured point cloud, as the paper renders its reconstructions
(Sec. 5.2, Fig. 8): "high frequency elements are removed from the depth maps with bilateral filtering and
highly slanted mesh elements are cropped", then every keyframe's depth is back-projected with its pose.

* The bilateral filter is kornia's joint bilateral filter applied as a normalised convolution: it smooths
  ``[d * valid, valid]`` guided by log-depth and divides, so holes (depth 0) never bleed into valid depths and
  the range kernel is relative (a ``sigma_log_depth`` of 0.05 treats depths 5% apart as one surface, at any
  scale, which matters for monocular reconstructions of arbitrary scale).
* A surface element is "highly slanted" when the angle between its normal (the cross product of the Sobel
  derivatives of the back-projected points, :func:`codeslam.geometry.image.slant_cosine`) and the pixel's
  viewing ray exceeds ``max_slant_deg``. Across a depth discontinuity the Sobel derivative spans both
  surfaces, so the normal there is nearly perpendicular to the ray: the same test drops the "rubber sheet"
  between foreground and background. Pixels next to invalid depth (whose normal mixes in a hole) are dropped too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import kornia
import torch
import torch.nn.functional as F

from codeslam.constants import MIN_DEPTH
from codeslam.errors import ConfigError
from codeslam.geometry.camera import PinholeCamera, pixel_grid, unproject
from codeslam.geometry.image import slant_cosine
from codeslam.geometry.lie import se3_act


@dataclass(frozen=True)
class FusionConfig:
    """How depth maps become points."""

    bilateral: bool = True
    """Bilateral-filter every depth map before back-projecting (the paper's "high frequency elements removed")."""
    kernel_size: int = 5
    """Side of the bilateral filter's window (pixels, odd)."""
    sigma_space: float = 1.5
    """Spatial standard deviation of the bilateral filter (pixels)."""
    sigma_log_depth: float = 0.05
    """Range standard deviation of the bilateral filter in log-depth: neighbours this relative depth apart
    weigh exp(-1/2); across a depth edge of 30% or more they weigh < 1e-7."""
    max_slant_deg: float = 75.0
    """Drop elements whose normal is more than this angle from the viewing ray (the paper's "highly slanted
    mesh elements are cropped"); 90 keeps everything except pixels next to holes."""
    min_depth: float = MIN_DEPTH
    """Drop depths below this (metres)."""
    max_depth: float = 10.0
    """Drop depths beyond this (metres): far-away proximities near 0 decode to huge, meaningless depths."""
    stride: int = 1
    """Keep every stride-th pixel in both directions (a lighter cloud)."""

    def __post_init__(self) -> None:
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise ConfigError(f"fusion: kernel_size must be a positive odd number, got {self.kernel_size}")
        if not (self.sigma_space > 0 and self.sigma_log_depth > 0):
            raise ConfigError("fusion: sigma_space and sigma_log_depth must be positive")
        if not 0 < self.max_slant_deg <= 90:
            raise ConfigError(f"fusion: max_slant_deg must lie in (0, 90], got {self.max_slant_deg}")
        if not 0 <= self.min_depth < self.max_depth:
            raise ConfigError(f"fusion: need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.stride < 1:
            raise ConfigError(f"fusion: stride must be >= 1, got {self.stride}")


@dataclass(frozen=True)
class FusionView:
    """One keyframe to fuse: image (3, H, W) RGB in [0, 1], depth (H, W) metres (0 = invalid), its camera and
    its pose T_wc (4, 4)."""

    image: torch.Tensor
    depth: torch.Tensor
    camera: PinholeCamera
    T_wc: torch.Tensor


@dataclass
class PointCloud:
    """xyz (N, 3) float32 world points, rgb (N, 3) uint8 colours."""

    xyz: torch.Tensor
    rgb: torch.Tensor

    def __len__(self) -> int:
        return self.xyz.shape[0]

    @staticmethod
    def concat(clouds: Sequence[PointCloud]) -> PointCloud:
        if not clouds:
            return PointCloud(torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.uint8))
        return PointCloud(torch.cat([c.xyz for c in clouds]), torch.cat([c.rgb for c in clouds]))


def _valid(depth: torch.Tensor) -> torch.Tensor:
    return torch.isfinite(depth) & (depth > 0)


def bilateral_depth(depth: torch.Tensor, kernel_size: int, sigma_space: float, sigma_log_depth: float) -> torch.Tensor:
    """(B, 1, H, W) depth (0 = invalid) -> the bilateral-filtered depth (B, 1, H, W), still 0 where invalid.

    Normalised convolution ``sum w d v / sum w v`` with w kornia's joint bilateral weights guided by log-depth,
    so invalid pixels get no weight and the range kernel is relative to depth.
    """
    valid = _valid(depth)
    v = valid.to(depth.dtype)
    d = torch.where(valid, depth, torch.zeros_like(depth))
    guide = torch.where(valid, d.clamp_min(MIN_DEPTH).log(), torch.zeros_like(d))  # (B, 1, H, W)
    stack = torch.cat([d * v, v], dim=1)  # (B, 2, H, W)
    out = kornia.filters.joint_bilateral_blur(
        stack, guide, kernel_size, sigma_log_depth, (sigma_space, sigma_space), border_type="replicate",
        color_distance_type="l2",
    )  # (B, 2, H, W): both channels divided by the same sum of weights
    num, den = out[:, :1], out[:, 1:]
    return torch.where(valid & (den > 0), num / den.clamp_min(torch.finfo(den.dtype).tiny), torch.zeros_like(d))


def keep_mask(depth: torch.Tensor, camera: PinholeCamera, cfg: FusionConfig) -> torch.Tensor:
    """(B, 1, H, W) depth -> (B, 1, H, W) bool: valid, within [min_depth, max_depth], all 3x3 neighbours valid
    (the normal's Sobel footprint) and not slanted beyond ``cfg.max_slant_deg``."""
    valid = _valid(depth)
    in_range = valid & (depth >= cfg.min_depth) & (depth <= cfg.max_depth)
    # erosion of the valid mask by the 3x3 Sobel footprint (a min-pool); replicate keeps the border
    interior = -F.max_pool2d(-F.pad(in_range.to(depth.dtype), (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    safe = torch.where(valid, depth, torch.ones_like(depth))  # finite everywhere for the normals
    cos = slant_cosine(safe, camera.params(depth.dtype, depth.device))
    cos_min = math.cos(math.radians(cfg.max_slant_deg))
    return in_range & (interior > 0.5) & (cos >= cos_min)


def view_points(view: FusionView, cfg: FusionConfig | None = None) -> PointCloud:
    """One keyframe -> its coloured world points after filtering (bilateral) and cropping (slant, range)."""
    cfg = cfg or FusionConfig()
    depth = view.depth[None, None].to(torch.float64)  # (1, 1, H, W)
    H, W = depth.shape[-2:]
    if view.image.shape != (3, H, W) or (view.camera.height, view.camera.width) != (H, W):
        raise ValueError(f"fusion view: image {tuple(view.image.shape)}, depth {(H, W)} and camera "
                         f"{view.camera.width}x{view.camera.height} disagree")
    if cfg.bilateral:
        depth = bilateral_depth(depth, cfg.kernel_size, cfg.sigma_space, cfg.sigma_log_depth)
    keep = keep_mask(depth, view.camera, cfg)[0, 0]  # (H, W)
    if cfg.stride > 1:
        sub = torch.zeros_like(keep)
        sub[:: cfg.stride, :: cfg.stride] = True
        keep &= sub
    uv = pixel_grid(H, W, torch.float64, depth.device)[keep]  # (N, 2)
    xyz_c = unproject(uv, depth[0, 0][keep], view.camera.params(torch.float64, depth.device))  # (N, 3)
    xyz_w = se3_act(view.T_wc.to(torch.float64).to(depth.device), xyz_c)  # (N, 3)
    rgb = (view.image.permute(1, 2, 0)[keep.to(view.image.device)].clamp(0, 1) * 255).round().to(torch.uint8)
    return PointCloud(xyz_w.to(torch.float32).cpu(), rgb.cpu())


def fuse(views: Sequence[FusionView], cfg: FusionConfig | None = None) -> PointCloud:
    """Back-project every view's filtered depth with its pose into one coloured cloud (at most sum H W points)."""
    return PointCloud.concat([view_points(v, cfg) for v in views])
