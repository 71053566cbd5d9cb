"""Resampling images and depth maps between cameras: the paper's intrinsics correction and undistortion.

The network only ever sees its canonical camera (``canonical_camera()``); the paper reports that its decoder
generalises to other datasets "after correcting for camera intrinsics" (Sec. 5, Fig. 9). We correct by
resampling: every destination pixel's ray ``K_dst^-1 (u, v, 1)`` is looked up in the source image through the
source intrinsics (and the source's radial-tangential distortion, if any). Both cameras share the optical centre
and axes, so a pure intrinsics change keeps every ray, and z-depth values carry over unchanged.

Pixels whose ray leaves the source image (beyond its pixel footprint ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``) are
set to 0; :func:`resample_valid_mask` returns where the result is valid. The functions work in both directions
(source -> canonical and back). Undistortion is resampling to ``camera.without_distortion()``; a reader that
needs both can go straight from the distorted camera to the canonical one in one interpolation.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from kornia.geometry.calibration import distort_points

from codeslam.constants import ANTIALIAS_MIN_SHRINK
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, pixel_grid, project, unproject_jac_depth
from codeslam.geometry.image import inside_image, pixels_to_grid


def _check(image: torch.Tensor, src: PinholeCamera, dst: PinholeCamera, what: str) -> None:
    if image.dim() != 4:
        raise CodeSLAMError(f"{what} must have shape (B, C, H, W), got {tuple(image.shape)}")
    if not image.is_floating_point():
        raise CodeSLAMError(f"{what} must be a floating-point tensor, got {image.dtype}")
    if (image.shape[-2], image.shape[-1]) != (src.height, src.width):
        raise CodeSLAMError(
            f"{what} is {image.shape[-1]}x{image.shape[-2]} but its camera is {src.width}x{src.height}"
        )
    if dst.has_distortion:
        raise CodeSLAMError("the destination camera of a resampling must have no distortion")


def source_pixels(
    src: PinholeCamera, dst: PinholeCamera, dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """For every pixel of ``dst`` (undistorted), the source pixel seeing the same ray: (dst.height, dst.width, 2).

    Without source distortion this is ``pi_src(pi_dst^-1(u, 1))``; with it, kornia's ``distort_points`` (the
    OpenCV k1, k2, p1, p2, k3 model) maps the ray's normalised coordinates to the distorted source pixel.

    The map depends only on the two cameras, so it is cached (a sequence resamples every frame with the
    same pair: measured 72 ms per 640x480 TUM frame for rebuilding the distortion map each time). The
    cached tensor is shared: do not modify it in place.
    """
    return _source_pixels_cached(src, dst, dtype, str(torch.device(device)) if device is not None else "cpu")


@functools.lru_cache(maxsize=16)
def _source_pixels_cached(src: PinholeCamera, dst: PinholeCamera, dtype: torch.dtype, device: str) -> torch.Tensor:
    grid = pixel_grid(dst.height, dst.width, dtype, device)  # (H_dst, W_dst, 2)
    if src.has_distortion:
        dist = torch.tensor(src.dist, dtype=dtype, device=device)
        pts = distort_points(grid.reshape(-1, 2), src.K(dtype, device), dist, new_K=dst.K(dtype, device))
        return pts.reshape(dst.height, dst.width, 2)
    ray = unproject_jac_depth(grid, dst.params(dtype, device))  # (H_dst, W_dst, 3), z = 1
    return project(ray, src.params(dtype, device))


def resample_valid_mask(
    src: PinholeCamera, dst: PinholeCamera, device: torch.device | str | None = None
) -> torch.Tensor:
    """(dst.height, dst.width) bool: the destination pixels whose ray falls inside the source image's pixel
    footprint; :func:`resample_image` and :func:`resample_depth` write 0 everywhere else. The caller's own copy."""
    return _valid_mask_cached(src, dst).to(device, copy=True)


@functools.lru_cache(maxsize=16)
def _valid_mask_cached(src: PinholeCamera, dst: PinholeCamera) -> torch.Tensor:
    # Depends on the two cameras only, like the map: rebuilding it cost 2-3 ms per 640x480 call, and a TUM frame
    # makes five such calls (undistortion, the network's camera, the feature camera).
    uv = source_pixels(src, dst, torch.float64)  # on the CPU: float64 everywhere (MPS has none)
    return inside_image(uv, src.height, src.width, margin=0.5)


@functools.lru_cache(maxsize=16)
def _sampling_grid(src: PinholeCamera, dst: PinholeCamera, dtype: torch.dtype, device: str,
                   map_dtype: torch.dtype | None) -> torch.Tensor:
    """(1, 1, dst.height * dst.width, 2) ``grid_sample`` coordinates of :func:`source_pixels` (computed in ``dtype``
    on ``device``, or with ``map_dtype`` in that dtype on the CPU, then moved): what
    :func:`~codeslam.geometry.image.bilinear_sample` and :func:`~codeslam.geometry.image.nearest_sample` compute
    from the map on every call, with the same arithmetic, so the resampled values are bit for bit theirs.
    Shared: do not modify it in place."""
    if map_dtype is None:
        uv = source_pixels(src, dst, dtype, device)
    else:
        uv = source_pixels(src, dst, map_dtype).to(device, dtype)
    return pixels_to_grid(uv.reshape(1, 1, -1, 2), src.height, src.width)


def _sample(image: torch.Tensor, src: PinholeCamera, dst: PinholeCamera, mode: str, padding_mode: str,
            map_dtype: torch.dtype | None = None) -> torch.Tensor:
    """(B, C, src.height, src.width) -> (B, C, dst.height, dst.width), looked up at the cached grid with
    ``grid_sample``'s ``mode`` and ``padding_mode``."""
    B, C = image.shape[:2]
    grid = _sampling_grid(src, dst, image.dtype, str(image.device), map_dtype)
    out = F.grid_sample(image, grid.expand(B, -1, -1, -1), mode=mode, padding_mode=padding_mode,
                        align_corners=True)  # (B, C, 1, N)
    return out.reshape(B, C, dst.height, dst.width)


def _antialias(image: torch.Tensor, src: PinholeCamera, dst: PinholeCamera) -> tuple[torch.Tensor, PinholeCamera]:
    """Shrink ``image`` towards dst's pixel density with an anti-aliased (triangle-filter) resize when dst is more
    than ANTIALIAS_MIN_SHRINK times coarser, returning the shrunk image and its camera; else pass through."""
    shrink_x, shrink_y = src.fx / dst.fx, src.fy / dst.fy
    if max(shrink_x, shrink_y) <= ANTIALIAS_MIN_SHRINK:
        return image, src
    width = max(1, round(src.width / shrink_x)) if shrink_x > 1 else src.width
    height = max(1, round(src.height / shrink_y)) if shrink_y > 1 else src.height
    # torch's antialiased bilinear resize is an area-like pre-filter; align_corners=False matches
    # PinholeCamera.resized's pixel-centre convention, so the shrunk image's camera is exact.
    small = F.interpolate(image, size=(height, width), mode="bilinear", antialias=True, align_corners=False)
    return small, src.resized(width, height)


def resample_image(
    image: torch.Tensor, src: PinholeCamera, dst: PinholeCamera, antialias: bool = True
) -> torch.Tensor:
    """Bilinear intrinsics correction of an image. (B, C, src.height, src.width) -> (B, C, dst.height, dst.width).

    Pixels whose ray leaves the source image are 0 (see :func:`resample_valid_mask`). With ``antialias`` a large
    shrink (e.g. 640x480 -> 128x96) is pre-filtered so that fine texture does not alias.
    """
    _check(image, src, dst, "image")
    if antialias:
        image, src_used = _antialias(image, src, dst)
    else:
        src_used = src
    values = _sample(image, src_used, dst, "bilinear", "border")  # (B, C, H_dst, W_dst)
    return values * _valid_mask_cached(src, dst).to(image.device, values.dtype)


def resample_depth(depth: torch.Tensor, src: PinholeCamera, dst: PinholeCamera) -> torch.Tensor:
    """Nearest-neighbour intrinsics correction of a z-depth map, (B, 1, src.height, src.width) ->
    (B, 1, dst.height, dst.width). Never mixes depths across edges; invalid (0 or non-finite) stays 0, and
    pixels whose ray leaves the source image are 0. Depth values are unchanged (same rays, same z)."""
    _check(depth, src, dst, "depth map")
    depth = torch.where(torch.isfinite(depth) & (depth > 0), depth, torch.zeros_like(depth))
    values = _sample(depth, src, dst, "nearest", "zeros", torch.float64)  # the map in float64 on the CPU, moved
    return values * _valid_mask_cached(src, dst).to(depth.device, values.dtype)


# (src, dst) -> (the source mask, the result) of the last resample_validity between those cameras
_last_validity: dict[tuple[PinholeCamera, PinholeCamera], tuple[torch.Tensor, torch.Tensor | None]] = {}


def resample_validity(
    valid: torch.Tensor | None, src: PinholeCamera, dst: PinholeCamera
) -> torch.Tensor | None:
    """Where a resampled image holds real pixels. valid: (src.height, src.width) bool of the source's real pixels
    (None: all of them) -> (dst.height, dst.width) bool: inside the source (:func:`resample_valid_mask`) and with
    no invalid source pixel in the bilinear / anti-aliasing footprint; None when every pixel is valid."""
    if valid is None:
        out = resample_valid_mask(src, dst)
        return None if bool(out.all()) else out
    # A reader that masks a fixed border gives every frame the same mask: the last result per pair of cameras is
    # kept (the share below, an anti-aliased resampling of the whole mask, took 2-5 ms of every 640x480 frame).
    last = _last_validity.get((src, dst))
    if (last is not None and last[0].shape == valid.shape and last[0].device == valid.device
            and torch.equal(last[0], valid)):
        return None if last[1] is None else last[1].clone()
    share = resample_image(valid[None, None].to(torch.float32), src, dst)[0, 0]  # share of real pixels
    out = resample_valid_mask(src, dst, valid.device) & (share >= 1.0 - 1e-4)
    out = None if bool(out.all()) else out
    if len(_last_validity) >= 16:
        _last_validity.clear()
    _last_validity[(src, dst)] = (valid.clone(), out)  # one item: a reader on another thread sees all or none
    return None if out is None else out.clone()


def undistort_image(image: torch.Tensor, camera: PinholeCamera) -> torch.Tensor:
    """(B, C, H, W) image of a distorted camera -> the same-size image of ``camera.without_distortion()``
    (bilinear; pixels whose ray leaves the original image are 0)."""
    return resample_image(image, camera, camera.without_distortion())


def undistort_depth(depth: torch.Tensor, camera: PinholeCamera) -> torch.Tensor:
    """(B, 1, H, W) z-depth of a distorted camera -> that of ``camera.without_distortion()`` (nearest)."""
    return resample_depth(depth, camera, camera.without_distortion())
