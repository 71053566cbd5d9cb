"""Image formation of real cameras, applied to rendered training images on the fly (data version 2's sensor).

The generator renders ideal pinhole images with a fixed exposure. Real frames differ in ways that do not change
the scene's depth but do change the image: auto-exposure and gain, vignetting, sensor noise that grows with the
gain, motion blur, a rolling shutter's row-by-row readout, and lens distortion that the readers undistort
(leaving interpolation blur and black corners, :mod:`codeslam.geometry.resample`). Each effect is a small pure
function of a batch here; :func:`apply_camera_effects` draws every parameter from a torch Generator, so a
training step stays a function of (seed, step).

Images are (B, C, H, W) sRGB in [0, 1] (RGB, C = 3, for :func:`apply_camera_effects`); depth (B, 1, H, W)
metres, 0 = invalid. Only the geometric effects (rolling shutter, lens distortion) move pixels, and they move the
depth with the image (nearest sampling, so no depth is blended across an edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from kornia.color import linear_rgb_to_rgb, rgb_to_linear_rgb

#: Horizontal field of view (degrees) of the lens model (the canonical camera's).
LENS_HFOV_DEG = 60.0
#: Number of taps of the motion-blur line kernel (odd; lengths up to this many pixels).
BLUR_TAPS = 9


@dataclass(frozen=True)
class CameraEffects:
    """Strengths of the effects (0 switches one off); the TrainConfig fields of the same names."""

    # Exposure / gain change: linear intensities scaled by exp(u), u uniform in [-x, x] (then clipped).
    exposure: float = 0.0
    # Vignetting: linear intensities times 1 - v r² (r = 1 at the image corner), v uniform in [0, x].
    vignetting: float = 0.0
    # Sensor noise: shot noise of std x * sqrt(I * gain) plus read noise x / 4 * gain (linear units).
    sensor_noise: float = 0.0
    # Motion blur: a line of length uniform in [0, x] pixels at a random angle (x <= BLUR_TAPS).
    motion_blur: float = 0.0
    # Rolling shutter: row r is shifted horizontally by s (r / (H - 1) - 0.5) pixels, s uniform in [-x, x].
    rolling_shutter: float = 0.0
    # Lens distortion undistorted again: k1 uniform in [-x, x] (barrel to pincushion).
    distortion: float = 0.0
    # A source camera with a narrower field of view than the canonical one: in half the images, black bands
    # (depth invalid) at the top and bottom, each up to x of the height, and at the sides, each up to 2x/3 of
    # the width. The readers' resampling leaves them (the HoloLens walk: 21% of the canonical image).
    border: float = 0.0

    @property
    def any(self) -> bool:
        return any(v > 0 for v in (self.exposure, self.vignetting, self.sensor_noise, self.motion_blur,
                                   self.rolling_shutter, self.distortion, self.border))


def _radius2(B: int, H: int, W: int, device) -> torch.Tensor:
    """Squared distance from the image centre (1, 1, H, W), 1 at the corners."""
    v = (torch.arange(H, device=device, dtype=torch.float32) - (H - 1) / 2) / ((H - 1) / 2)
    u = (torch.arange(W, device=device, dtype=torch.float32) - (W - 1) / 2) / ((W - 1) / 2)
    return ((u[None, :] ** 2 * W**2 + v[:, None] ** 2 * H**2) / (W**2 + H**2))[None, None]


def exposure_gain(linear: torch.Tensor, log_gain: torch.Tensor) -> torch.Tensor:
    """Linear intensities (B, C, H, W) times exp(log_gain) (B,), clipped to [0, 1] (saturation)."""
    return (linear * torch.exp(log_gain).view(-1, 1, 1, 1)).clamp(0, 1)


def vignette(linear: torch.Tensor, strength: torch.Tensor) -> torch.Tensor:
    """Linear intensities (B, C, H, W) darkened towards the corners by 1 - strength (B,) r²."""
    B, _, H, W = linear.shape
    return linear * (1 - strength.view(-1, 1, 1, 1) * _radius2(B, H, W, linear.device))


def sensor_noise(linear: torch.Tensor, level: torch.Tensor, gain: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Shot noise (std level sqrt(I gain)) plus read noise (std level gain / 4) on linear intensities
    (B, C, H, W), with standard normal draws ``noise`` of the same shape; level, gain (B,)."""
    lv, g = level.view(-1, 1, 1, 1), gain.view(-1, 1, 1, 1)
    std = lv * torch.sqrt(linear.clamp_min(0) * g) + 0.25 * lv * g
    return (linear + std * noise).clamp(0, 1)


def motion_blur(image: torch.Tensor, length: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Blur every image (B, C, H, W) along a line of ``length`` pixels (B,) at ``angle`` (B,) radians:
    a normalised kernel of BLUR_TAPS x BLUR_TAPS taps (a line rasterised with a 1-pixel tent), replicate
    borders."""
    B, C, H, W = image.shape
    r = BLUR_TAPS // 2
    t = torch.linspace(-0.5, 0.5, 4 * BLUR_TAPS, device=image.device)  # samples along the line
    pts_x = t[None, :] * length[:, None] * torch.cos(angle)[:, None]  # (B, S)
    pts_y = t[None, :] * length[:, None] * torch.sin(angle)[:, None]
    g = torch.arange(-r, r + 1, device=image.device, dtype=torch.float32)
    wx = (1 - (g[None, None, :] - pts_x[..., None]).abs()).clamp_min(0)  # (B, S, taps)
    wy = (1 - (g[None, None, :] - pts_y[..., None]).abs()).clamp_min(0)
    k = torch.einsum("bsy,bsx->byx", wy, wx)  # (B, taps, taps)
    k = k / k.sum(dim=(1, 2), keepdim=True)
    pad = F.pad(image, (r, r, r, r), mode="replicate")  # (B, C, H + 2r, W + 2r)
    weight = k[:, None].expand(B, C, BLUR_TAPS, BLUR_TAPS).reshape(B * C, 1, BLUR_TAPS, BLUR_TAPS)
    out = F.conv2d(pad.reshape(1, B * C, H + 2 * r, W + 2 * r), weight, groups=B * C)  # one kernel per image
    return out.reshape(B, C, H, W)


def _warp(image: torch.Tensor, depth: torch.Tensor, grid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample image (bilinear) and depth (nearest) at normalised grid (B, H, W, 2); 0 outside."""
    img = F.grid_sample(image, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    dep = F.grid_sample(depth, grid, mode="nearest", padding_mode="zeros", align_corners=True)
    return img, dep


def rolling_shutter(image: torch.Tensor, depth: torch.Tensor, shift: torch.Tensor):
    """Shift row r of image and depth (B, C, H, W), (B, 1, H, W) horizontally by shift (B,) (r / (H - 1) - 0.5)
    pixels: the image of a camera turning about its vertical axis while its rows are read out one by one
    (the depth moves with the image, as each row's depth is that row's)."""
    B, _, H, W = image.shape
    ys = torch.linspace(-1, 1, H, device=image.device)
    xs = torch.linspace(-1, 1, W, device=image.device)
    dx = shift.view(B, 1, 1) * (ys.view(1, H, 1) / 2) * 2 / (W - 1)  # pixels -> normalised units
    gx = xs.view(1, 1, W) - dx
    grid = torch.stack([gx.expand(B, H, W), ys.view(1, H, 1).expand(B, H, W)], -1)
    return _warp(image, depth, grid)


def lens_distortion(image: torch.Tensor, depth: torch.Tensor, k1: torch.Tensor):
    """What a reader's undistortion leaves of a lens with radial distortion k1 (B,): the pinhole image is
    seen through the lens (x_d = x (1 + k1 |x|²) in normalised coordinates of a camera with the same focal
    length) and undistorted back, so pixels are interpolated twice and, for k1 > 0 (as TUM fr1's lens), the
    corners that the distorted image does not cover come out black (depth 0), as after a reader's
    undistortion. Focal length that of the canonical camera (LENS_HFOV_DEG horizontal field of view)."""
    B, _, H, W = image.shape
    f = (W / 2) / math.tan(math.radians(LENS_HFOV_DEG / 2))
    ys = (torch.arange(H, device=image.device, dtype=torch.float32) - (H - 1) / 2) / f
    xs = (torch.arange(W, device=image.device, dtype=torch.float32) - (W - 1) / 2) / f
    x, y = xs.view(1, 1, W).expand(B, H, W), ys.view(1, H, 1).expand(B, H, W)
    k = k1.view(B, 1, 1)
    # the distorted image: its pixel x_d shows the ray x_u with x_u (1 + k |x_u|²) = x_d (fixed-point inverse)
    xu, yu = x.clone(), y.clone()
    for _ in range(8):
        s = 1 + k * (xu * xu + yu * yu)
        xu, yu = x / s, y / s
    to_norm = torch.tensor([f * 2 / (W - 1), f * 2 / (H - 1)], device=image.device)
    img_d, dep_d = _warp(image, depth, torch.stack([xu, yu], -1) * to_norm)
    # undistortion: the canonical pixel x reads the distorted image at x (1 + k |x|²)
    s = 1 + k * (x * x + y * y)
    return _warp(img_d, dep_d, torch.stack([x * s, y * s], -1) * to_norm)


def narrow_field_of_view(image: torch.Tensor, depth: torch.Tensor, bands: torch.Tensor):
    """Black out bands of image (B, C, H, W) and invalidate them in depth (B, 1, H, W): ``bands`` (B, 4) are the
    fractions of the height (top, bottom) and of the width (left, right) that a narrower source camera did not
    see (0 = none)."""
    B, _, H, W = image.shape
    rows = torch.arange(H, device=image.device, dtype=torch.float32)[None, :, None] + 0.5
    cols = torch.arange(W, device=image.device, dtype=torch.float32)[None, None, :] + 0.5
    top, bottom = (bands[:, 0] * H)[:, None, None], (H - bands[:, 1] * H)[:, None, None]
    left, right = (bands[:, 2] * W)[:, None, None], (W - bands[:, 3] * W)[:, None, None]
    seen = ((rows >= top) & (rows <= bottom) & (cols >= left) & (cols <= right))[:, None]  # (B, 1, H, W)
    return image * seen, depth * seen


def apply_camera_effects(image: torch.Tensor, depth: torch.Tensor, fx: CameraEffects, generator: torch.Generator):
    """All enabled effects on a batch: image (B, C, H, W) sRGB [0, 1], depth (B, 1, H, W) -> both, changed.
    Order as in a camera: geometry (lens, rolling shutter), then in linear light exposure and vignetting,
    motion blur, noise, and last the black bands of a narrower field of view. Every random draw comes from
    ``generator`` (CPU), one fixed-size block per batch and effect."""
    B, _, H, W = image.shape
    dev = image.device
    u = torch.rand(B, 8, generator=generator).to(dev)
    noise = torch.randn(image.shape, generator=generator).to(dev) if fx.sensor_noise > 0 else None
    band = torch.rand(B, 5, generator=generator).to(dev) if fx.border > 0 else None
    if fx.distortion > 0:
        image, depth = lens_distortion(image, depth, fx.distortion * (2 * u[:, 0] - 1))
    if fx.rolling_shutter > 0:
        image, depth = rolling_shutter(image, depth, fx.rolling_shutter * (2 * u[:, 1] - 1))
    lin = rgb_to_linear_rgb(image.clamp(0, 1))  # (B, 3, H, W)
    gain = torch.ones(B, device=dev)
    if fx.exposure > 0:
        log_gain = fx.exposure * (2 * u[:, 2] - 1)
        lin = exposure_gain(lin, log_gain)
        gain = torch.exp(-log_gain)  # a darker scene needs more gain, hence more noise
    if fx.vignetting > 0:
        lin = vignette(lin, fx.vignetting * u[:, 3])
    if fx.motion_blur > 0:
        lin = motion_blur(lin, fx.motion_blur * u[:, 4], torch.pi * u[:, 5])
    if noise is not None:
        lin = sensor_noise(lin, fx.sensor_noise * u[:, 6], gain, noise)
    image = linear_rgb_to_rgb(lin.clamp(0, 1))
    if band is not None:  # last: the reader's resampling blacks out what the source camera did not see
        scale = torch.tensor([1.0, 1.0, 2 / 3, 2 / 3], device=dev) * fx.border
        image, depth = narrow_field_of_view(image, depth, band[:, 1:] * scale * (band[:, :1] < 0.5))
    return image, depth
