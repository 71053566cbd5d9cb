"""Image and list-file I/O shared by the dataset readers.

Every reading function turns every way a file can be bad (missing, empty, not an image, corrupt,
truncated, of the wrong bit depth) into a :class:`~codeslam.errors.DatasetError` that names the file.
Pillow opens files lazily and only decodes the pixels on ``load()``; a truncated PNG opens fine and fails
only then, so every reader forces ``load()`` inside the error handling.

Depth maps follow :class:`~codeslam.data.frame.Frame`: float32 metres, 0 where invalid. Values that cannot
be a depth (NaN, +-inf, negative) are set to 0 (invalid) with a :class:`DepthWarning`, not an error:
renderers and sensors write such values for sky, holes or windows, and a reader that refuses them would
refuse real datasets.

The writers (:func:`write_rgb_png`, :func:`write_depth_png`) go through :func:`codeslam.io.atomic_path`.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np
import torch
from PIL import Image, UnidentifiedImageError

from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera
from codeslam.io import atomic_path

#: Pillow modes of a 16-bit single-channel PNG ("I" is how older Pillow versions report it; a PNG has
#: no 32-bit integer grey, so "I" from a PNG is 16-bit data).
_MODES_16BIT = ("I;16", "I;16B", "I;16L", "I")
_MAX_UINT16 = 65535


class DepthWarning(UserWarning):
    """A depth map held values that cannot be depths (NaN, inf, negative); they were set to 0 (invalid)."""


def _open_loaded(path: Path) -> Image.Image:
    """Open ``path`` with Pillow and decode it fully; any failure -> DatasetError naming the file."""
    if not path.is_file():
        raise DatasetError(f"image file not found: {path}")
    if path.stat().st_size == 0:
        raise DatasetError(f"image file is empty: {path}")
    try:
        with Image.open(path) as im:
            im.load()  # Pillow is lazy: truncated or corrupt pixel data only fails here
    except UnidentifiedImageError:
        raise DatasetError(f"not a readable image: {path}") from None
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise DatasetError(f"corrupt or truncated image {path}: {e}") from None
    return im


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of an image from its header only (cheap); DatasetError if it is not an image."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"image file not found: {path}")
    if path.stat().st_size == 0:
        raise DatasetError(f"image file is empty: {path}")
    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError):
        raise DatasetError(f"not a readable image: {path}") from None


def read_rgb(path: str | os.PathLike) -> torch.Tensor:
    """Read a colour or grey image -> (3, H, W) float32 RGB in [0, 1].

    Grey images (8 or 16 bit) are repeated into three channels; an alpha channel is dropped; palette
    images are expanded. 16-bit grey is scaled by 1/65535, everything else by 1/255.
    """
    path = Path(path)
    im = _open_loaded(path)
    if im.mode in _MODES_16BIT:
        grey = np.asarray(im, dtype=np.float32) / _MAX_UINT16  # (H, W)
        rgb = np.repeat(grey[None], 3, axis=0)  # (3, H, W)
    else:
        try:
            arr = np.array(im.convert("RGB"))  # (H, W, 3) uint8, writable
        except (OSError, ValueError) as e:
            raise DatasetError(f"cannot convert image {path} (mode {im.mode}) to RGB: {e}") from None
        # The bytes reordered to (3, H, W) first, then one pass to float32 / 255: the same values as NumPy's float
        # array divided and transposed, in a quarter of the time (a 640x480 TUM frame: 3.2 -> 0.8 ms, on the
        # thread that reads frames ahead of the tracker).
        return torch.from_numpy(arr).permute(2, 0, 1).contiguous().float().div_(255.0)
    return torch.from_numpy(np.ascontiguousarray(rgb))


def read_depth_png(path: str | os.PathLike, factor: float) -> torch.Tensor:
    """Read a 16-bit single-channel depth PNG -> (H, W) float32 metres (``value / factor``, 0 = invalid).

    An 8-bit or colour image where 16-bit depth is expected is a DatasetError: its values would be
    depths quantised to 255 steps, almost certainly the wrong file.
    """
    path = Path(path)
    if not (math.isfinite(factor) and factor > 0):
        raise DatasetError(f"depth scale factor must be a positive number, got {factor} for {path}")
    im = _open_loaded(path)
    if im.mode not in _MODES_16BIT:
        raise DatasetError(
            f"depth image {path} is {im.mode!r} ({_describe_mode(im.mode)}); expected a 16-bit single-channel PNG"
        )
    raw = np.asarray(im, dtype=np.float32)  # (H, W) integer values
    if raw.ndim != 2:
        raise DatasetError(f"depth image {path} has shape {raw.shape}; expected one channel")
    return torch.from_numpy(np.ascontiguousarray(raw / np.float32(factor)))


def read_depth_npy(path: str | os.PathLike) -> torch.Tensor:
    """Read a ``.npy`` depth map in metres -> (H, W) float32 (invalid values set to 0 with a warning).

    ``allow_pickle=False``: a ``.npy`` file must never run code when it is read.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"depth file not found: {path}")
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise DatasetError(f"cannot read depth file {path}: {e}") from None
    if not isinstance(arr, np.ndarray) or arr.ndim != 2:
        shape = getattr(arr, "shape", None)
        raise DatasetError(f"depth file {path} must hold a 2-D array (H, W), got shape {shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise DatasetError(f"depth file {path} holds {arr.dtype} values; expected numbers (metres)")
    return sanitize_depth(torch.from_numpy(np.ascontiguousarray(arr, dtype=np.float32)), path)


def sanitize_depth(depth: torch.Tensor, path: str | os.PathLike) -> torch.Tensor:
    """Set NaN, +-inf and negative depths to 0 (invalid), warning once per file with the count.

    depth: (H, W) float32 metres. Returns the same shape.
    """
    bad = ~torch.isfinite(depth) | (depth < 0)
    n_bad = int(bad.sum())
    if n_bad:
        warnings.warn(
            f"{path}: {n_bad} depth values are NaN, infinite or negative; treated as invalid (0)",
            DepthWarning,
            stacklevel=2,
        )
        depth = torch.where(bad, torch.zeros((), dtype=depth.dtype), depth)
    return depth


def _describe_mode(mode: str) -> str:
    return {"L": "8-bit grey", "P": "8-bit palette", "RGB": "8-bit colour", "RGBA": "8-bit colour + alpha",
            "LA": "8-bit grey + alpha", "1": "1-bit", "F": "32-bit float"}.get(mode, "not 16-bit grey")


def check_frame_shapes(
    camera: PinholeCamera, image: torch.Tensor, depth: torch.Tensor | None, image_path, depth_path=None
) -> None:
    """Raise DatasetError when the image (3, H, W) is not the camera's size or the depth (H, W) is not the
    image's size, naming the offending file."""
    h, w = image.shape[-2:]
    if (w, h) != (camera.width, camera.height):
        raise DatasetError(
            f"image {image_path} is {w}x{h} but the camera is {camera.width}x{camera.height}"
        )
    if depth is not None and tuple(depth.shape[-2:]) != (h, w):
        dh, dw = depth.shape[-2:]
        raise DatasetError(f"depth {depth_path} is {dw}x{dh} but its image {image_path} is {w}x{h}")


def check_depth_shape(camera: PinholeCamera, depth: torch.Tensor, depth_path) -> None:
    """Raise DatasetError when the depth (H, W), read without its image, is not the camera's size."""
    dh, dw = depth.shape[-2:]
    if (dw, dh) != (camera.width, camera.height):
        raise DatasetError(f"depth {depth_path} is {dw}x{dh} but the camera is {camera.width}x{camera.height}")


def resolve_in_root(root: str | os.PathLike, entry: str, where: str) -> Path:
    """The file a list entry names, confined to the dataset folder ``root``.

    ``entry`` is relative to ``root``. An absolute path, or a relative one that leaves ``root`` (``..``,
    or a symbolic link pointing outside), is a DatasetError: a list file must not make the reader open
    files elsewhere on the machine. ``where`` (e.g. ``"rgb.txt:12"``) goes into the message.
    """
    root = Path(root)
    if not entry or Path(entry).is_absolute() or entry.startswith(("/", "\\")) or ":" in Path(entry).drive:
        raise DatasetError(f"{where}: path {entry!r} must be relative to the dataset folder {root}")
    root_real = root.resolve()
    target = (root / entry).resolve()
    if target != root_real and root_real not in target.parents:
        raise DatasetError(f"{where}: path {entry!r} points outside the dataset folder {root}")
    return root / entry


def require_file(path: Path, where: str) -> Path:
    """Raise DatasetError naming ``where`` when ``path`` is not an existing file."""
    if not path.is_file():
        raise DatasetError(f"{where}: file not found: {path}")
    return path


def write_rgb_png(path: str | os.PathLike, image: torch.Tensor | np.ndarray) -> None:
    """Write a (3, H, W) RGB image in [0, 1] as an 8-bit PNG, atomically (values are clipped, rounded)."""
    arr = torch.as_tensor(image).detach().cpu().float().numpy()
    if arr.ndim != 3 or arr.shape[0] != 3:
        raise ValueError(f"write_rgb_png expects a (3, H, W) image, got {arr.shape}")
    u8 = np.clip(np.rint(arr * 255.0), 0, 255).astype(np.uint8).transpose(1, 2, 0)  # (H, W, 3)
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(u8)).save(tmp, format="PNG")


def write_depth_png(path: str | os.PathLike, depth: torch.Tensor | np.ndarray, factor: float = 5000.0) -> None:
    """Write an (H, W) depth map in metres as a 16-bit PNG of ``round(depth * factor)``, atomically.

    Invalid depths (0, NaN, negative) are written as 0. A depth beyond ``65535 / factor`` metres cannot
    be stored and raises DatasetError rather than wrapping round or saturating silently.
    """
    d = torch.as_tensor(depth).detach().cpu().double().numpy()
    if d.ndim != 2:
        raise ValueError(f"write_depth_png expects an (H, W) depth map, got {d.shape}")
    if not (math.isfinite(factor) and factor > 0):
        raise DatasetError(f"depth scale factor must be a positive number, got {factor}")
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    scaled = np.rint(d * factor)
    if scaled.max(initial=0.0) > _MAX_UINT16:
        raise DatasetError(
            f"cannot write {path}: depth {d.max():.3f} m exceeds the 16-bit range {_MAX_UINT16 / factor:.3f} m "
            f"of scale factor {factor}"
        )
    u16 = scaled.astype(np.uint16)
    with atomic_path(path) as tmp:
        Image.fromarray(u16).save(tmp, format="PNG")  # uint16 (H, W) -> mode I;16, 16-bit grey PNG


def undistort_frame(
    camera: PinholeCamera, image: torch.Tensor, depth: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """Resample a frame of a distorted ``camera`` to ``camera.without_distortion()``.

    image: (3, H, W) bilinear; depth: (H, W) or None, nearest (never mixes depths across edges). Both go
    through the same map, so a depth map registered pixel-for-pixel to the distorted image stays
    registered to the undistorted one. Pixels whose ray leaves the original image become 0; the third result is
    the (H, W) bool mask of the real pixels (None when all are), for :attr:`Frame.valid`.
    """
    from codeslam.geometry.resample import resample_validity, undistort_image

    image = undistort_image(image[None], camera)[0]
    if depth is not None:
        depth = undistort_depth_map(camera, depth)
    return image, depth, resample_validity(None, camera, camera.without_distortion())


def undistort_depth_map(camera: PinholeCamera, depth: torch.Tensor) -> torch.Tensor:
    """(H, W) depth of a distorted ``camera`` -> (H, W) of ``camera.without_distortion()``, nearest, through the
    same map as :func:`undistort_frame` (which it serves), for a depth read without its image."""
    from codeslam.geometry.resample import undistort_depth

    return undistort_depth(depth[None, None], camera)[0, 0]


def frame_index(i: int, n: int) -> int:
    """Python indexing (negative counts from the end) into ``n`` frames; IndexError when out of range."""
    i = int(i)
    if i < 0:
        i += n
    if not 0 <= i < n:
        raise IndexError(f"frame index out of range for a sequence of {n} frames")
    return i
