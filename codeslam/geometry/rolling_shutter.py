"""Rolling-shutter rectification by a known rotation: an image (or keypoints) as a global shutter at mid-readout
would have seen it.

A rolling-shutter sensor exposes its rows one after the other. While the camera turns by ``omega`` (rotation
vector in the camera frame) over the readout, row y is seen by the camera turned by ``s(y) omega`` about its own
centre, ``s(y) = (y - (H - 1) / 2) / H`` in the *sensor's* rows (the convention of the SfM's readout rotation,
:class:`codeslam.sfm.config.SfMConfig`). The camera's translation over the readout is neglected: at a few
centimetres per frame and metres of depth it moves a pixel by a small fraction of what the rotation does.

Why (measured, docs/results/slam_table.md, session of 2026-11-26): on TUM fr1/rpy the tracked rotation of a frame
against its keyframe is off by 0.5-5 degrees, and that error follows the *difference* of the two frames' angular
velocities (correlation +0.62 with the network's depth, +0.69 with the sensor's), not the rotation between them
(+0.11, +0.16) nor the frame's own speed: the signature of two images distorted by their own readouts.

A phone filming in portrait stores landscape frames with a display rotation; turned upright, its sensor's rows
run along the image's *columns*. ``axis`` says which: ``"rows"`` (the time of a pixel follows its y) or
``"columns"`` (its x: ``s(x) = (x - (W - 1) / 2) / W``); a sensor read the other way along either axis (a camera
upside down) is a negative readout, the sign of ``omega``'s factor. Measured (``docs/results/slam_table.md``,
forty-sixth session): TUM fr1/rpy as a portrait video (H.264, display rotation 90; four encodings at 29-31
frames/s) ended 0.040-0.044 m off with a readout along the rows only, which settled as a global shutter; along
the columns (readouts 0.50-0.60) 0.023-0.028 m in three of them and 0.045 m in the fourth; as a landscape video
0.020-0.023 m.

The maths here is our own (a rotation-only row warp, first order in the readout rotation: the row time of the
rectified pixel is used for the source pixel, which differs from the exact one by s' omega, a second-order term).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from codeslam.geometry.camera import PinholeCamera, pixel_grid, project, unproject_jac_depth
from codeslam.geometry.image import pixels_to_grid
from codeslam.geometry.lie import so3_exp

AXES = ("rows", "columns")
"""Along which image axis a sensor's rows follow one another: ``"rows"`` (its rows are the image's) or
``"columns"`` (a portrait video turned upright from a landscape sensor)."""


def row_times(rays: torch.Tensor, sensor: PinholeCamera, axis: str = "rows") -> torch.Tensor:
    """(..., 3) camera rays (any scale, z > 0) -> (...) the readout time s of the sensor row each ray falls on,
    ``s = (y - (H - 1) / 2) / H`` in [-1/2, 1/2] over the sensor's rows (y = fy ray_y / ray_z + cy); with ``axis``
    "columns" ``s = (x - (W - 1) / 2) / W`` (x = fx ray_x / ray_z + cx)."""
    if axis not in AXES:
        raise ValueError(f"readout axis must be one of {AXES}, got {axis!r}")
    if axis == "columns":
        x = sensor.fx * rays[..., 0] / rays[..., 2] + sensor.cx
        return (x - 0.5 * (sensor.width - 1)) / sensor.width
    y = sensor.fy * rays[..., 1] / rays[..., 2] + sensor.cy
    return (y - 0.5 * (sensor.height - 1)) / sensor.height


def _row_rotations(s: torch.Tensor, omega: torch.Tensor) -> torch.Tensor:
    """(...) readout times, (3,) readout rotation -> (..., 3, 3) Exp(s omega)."""
    phi = s.reshape(-1, 1) * omega.to(s.dtype).reshape(1, 3)
    return so3_exp(phi).reshape(*s.shape, 3, 3)


def rectify_points(uv: torch.Tensor, camera: PinholeCamera, sensor: PinholeCamera,
                   omega: torch.Tensor, axis: str = "rows") -> torch.Tensor:
    """(N, 2) pixels of ``camera`` in a rolling-shutter image (rows read by ``sensor`` along ``axis``) -> (N, 2)
    where a global shutter at mid-readout would have seen the same scene points: ray r -> Exp(s(r) omega) r."""
    params = camera.params(uv.dtype, uv.device)
    rays = unproject_jac_depth(uv, params)  # (N, 3)
    R = _row_rotations(row_times(rays, sensor, axis), omega)  # (N, 3, 3)
    return project((R @ rays.unsqueeze(-1)).squeeze(-1), params)


def source_pixels(camera: PinholeCamera, sensor: PinholeCamera, omega: torch.Tensor,
                  dtype: torch.dtype = torch.float32, axis: str = "rows") -> torch.Tensor:
    """(H, W, 2): for each pixel of the rectified (global-shutter) image of ``camera``, where the rolling-shutter
    image shows its scene point: ray r' -> Exp(-s(r') omega) r' (first order: the row time of r' itself). The rays
    of one pixel row share their sensor row (same optical axes), so one rotation per row; with ``axis``
    "columns" one per pixel column."""
    params = camera.params(torch.float64)
    rays = unproject_jac_depth(pixel_grid(camera.height, camera.width, torch.float64), params)  # (H, W, 3)
    line = rays[:1] if axis == "columns" else rays[:, :1]  # (1, W, 3) or (H, 1, 3): one ray per sensor row
    R = _row_rotations(-row_times(line, sensor, axis), omega.to(torch.float64))  # (1, W, 3, 3) or (H, 1, 3, 3)
    return project((R @ rays.unsqueeze(-1)).squeeze(-1), params).to(dtype)  # R r' for every pixel of the line


def rectify_image(image: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear") -> tuple[torch.Tensor, torch.Tensor]:
    """(C, H, W) rolling-shutter image, ``uv`` (H, W, 2) from :func:`source_pixels` -> (the rectified image
    (C, H, W), (H, W) bool: pixels whose source lies inside the image). Outside pixels are 0. ``mode``:
    'bilinear' for intensities, 'nearest' for depth and masks."""
    H, W = image.shape[-2:]
    x = image[None] if image.is_floating_point() else image[None].float()
    uv = uv.to(x.device, x.dtype)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
    grid = pixels_to_grid(uv[None], H, W)  # (1, H, W, 2)
    out = F.grid_sample(x, grid, mode=mode, padding_mode="zeros", align_corners=True)[0]
    return out * inside.to(out.dtype), inside
