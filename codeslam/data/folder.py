"""A plain folder of images with a camera file: the way to bring your own data.

Layout::

    camera.yaml          the camera and options (below)
    images/              the frames (.png, .jpg, .jpeg), sorted by name; without images/ the images
                         lie in the folder itself
    depth/<stem>.png     optional: 16-bit depth, value / depth_factor = metres, 0 = invalid
    depth/<stem>.npy     optional: float depth in metres (NaN / inf / negative = invalid)
    poses.txt            optional: TUM format 'timestamp tx ty tz qx qy qz qw', camera-to-world

``camera.yaml`` (read with ``yaml.safe_load``; an unknown key is an error, to catch typos)::

    fx: 525.0            # required, pixels
    fy: 525.0            # required
    cx: 319.5            # required (pixel (0, 0) is the centre of the top-left pixel)
    cy: 239.5            # required
    width: 640           # optional; checked against the images when given
    height: 480          # optional
    dist: [k1, k2, p1, p2, k3]   # optional radial-tangential distortion (4 or 5 numbers); images are undistorted
    depth_factor: 5000   # optional, for 16-bit depth PNGs (default 5000, like TUM)
    fps: 30              # optional, for timestamps when the file names are not numbers (default 30)

**Timestamps.** When every image name (without extension) is a number, it is the timestamp in seconds
and the images are ordered by it; otherwise frame ``i`` (in name order) is at ``i / fps``.
**Poses** are matched by timestamp: ``poses.txt`` is interpolated (linear position, slerp rotation) to the
frame timestamps, on the same clock, so with index timestamps its line ``k`` belongs to time ``k / fps``.
A frame outside its span, or between two poses more than ``pose_max_gap`` apart, has no pose.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
import yaml

from codeslam.data.base import ImageFileSequence
from codeslam.data.imageio import image_size, read_depth_npy, read_depth_png
from codeslam.data.trajectory import read_tum
from codeslam.errors import CodeSLAMError, ConfigError, DatasetError
from codeslam.geometry.camera import PinholeCamera

CAMERA_FILE = "camera.yaml"
POSES_FILE = "poses.txt"
FOLDER_DEFAULT_DEPTH_FACTOR = 5000.0
FOLDER_DEFAULT_FPS = 30.0
#: Largest spacing (s) of the two poses a frame's pose is interpolated between.
FOLDER_POSE_MAX_GAP_S = 0.5
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
_REQUIRED = ("fx", "fy", "cx", "cy")
_OPTIONAL = ("width", "height", "dist", "depth_factor", "fps")


def yaml_error_text(e: Exception) -> str:
    """A PyYAML error as ``line L, column C: problem`` (its own text spans several lines)."""
    mark, problem = getattr(e, "problem_mark", None), getattr(e, "problem", None)
    if mark is not None and problem:
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    return " ".join(str(e).split())


def _positive_number(d: dict, key: str, path: Path, default: float | None = None) -> float:
    val = d.get(key, default)
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val) or val <= 0:
        raise ConfigError(f"{path}: '{key}' must be a positive number, got {val!r}")
    return float(val)


def read_camera_yaml(path: Path) -> tuple[dict, tuple[float, ...]]:
    """Parse ``camera.yaml`` -> (checked option dict, distortion (5,)); ConfigError when malformed."""
    try:
        d = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {path}: {e}") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"{path} is not valid YAML: {yaml_error_text(e)}") from None
    if not isinstance(d, dict):
        raise ConfigError(f"{path} must be a YAML mapping with fx, fy, cx, cy")
    unknown = sorted(str(k) for k in d if k not in _REQUIRED + _OPTIONAL)
    if unknown:
        raise ConfigError(f"{path}: unknown keys {unknown}; allowed: {list(_REQUIRED + _OPTIONAL)}")
    missing = [k for k in _REQUIRED if k not in d]
    if missing:
        raise ConfigError(f"{path}: missing keys {missing}")
    for k in ("cx", "cy"):
        if isinstance(d[k], bool) or not isinstance(d[k], (int, float)) or not math.isfinite(d[k]):
            raise ConfigError(f"{path}: '{k}' must be a number, got {d[k]!r}")
    for k in ("width", "height"):
        if k in d and (isinstance(d[k], bool) or not isinstance(d[k], int) or d[k] <= 0):
            raise ConfigError(f"{path}: '{k}' must be a positive integer, got {d[k]!r}")
    dist = d.get("dist", [0.0] * 5)
    if (
        not isinstance(dist, list)
        or len(dist) not in (4, 5)
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in dist)
    ):
        raise ConfigError(f"{path}: 'dist' must be a list of 4 or 5 numbers [k1, k2, p1, p2, k3], got {dist!r}")
    opts = {
        "fx": _positive_number(d, "fx", path),
        "fy": _positive_number(d, "fy", path),
        "cx": float(d["cx"]),
        "cy": float(d["cy"]),
        "width": d.get("width"),
        "height": d.get("height"),
        "depth_factor": _positive_number(d, "depth_factor", path, FOLDER_DEFAULT_DEPTH_FACTOR),
        "fps": _positive_number(d, "fps", path, FOLDER_DEFAULT_FPS),
    }
    return opts, tuple(float(v) for v in dist) + (0.0,) * (5 - len(dist))


def _as_number(stem: str) -> float | None:
    try:
        v = float(stem)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


class FolderSequence(ImageFileSequence):
    """A folder of images + ``camera.yaml`` (see the module docstring)."""

    format_name = "folder"

    def __init__(
        self, root: str | Path, undistort: bool = True, pose_max_gap: float = FOLDER_POSE_MAX_GAP_S
    ) -> None:
        super().__init__(root)
        root = self.root
        if not root.is_dir():
            raise DatasetError(f"dataset folder not found: {root}")
        cam_file = root / CAMERA_FILE
        if not cam_file.is_file():
            raise DatasetError(f"{root} is not an image folder dataset: {CAMERA_FILE} is missing")
        opts, dist = read_camera_yaml(cam_file)
        self.depth_factor = opts["depth_factor"]

        img_dir = root / "images" if (root / "images").is_dir() else root
        images = sorted(p for p in img_dir.iterdir() if p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES)
        if not images:
            raise DatasetError(f"{img_dir} holds no images (.png, .jpg)")
        numbers = [_as_number(p.stem) for p in images]
        if all(v is not None for v in numbers):  # names are timestamps
            order = sorted(range(len(images)), key=lambda k: numbers[k])
            images = [images[k] for k in order]
            stamps = np.array([numbers[k] for k in order], dtype=np.float64)
            dup = np.nonzero(np.diff(stamps) <= 0)[0]
            if len(dup):
                raise DatasetError(
                    f"{images[dup[0]].name} and {images[dup[0] + 1].name} have the same timestamp {stamps[dup[0]]}"
                )
        else:
            stamps = np.arange(len(images), dtype=np.float64) / opts["fps"]
        self._images, self._stamps = images, stamps

        w, h = image_size(images[0])
        if (opts["width"] or w, opts["height"] or h) != (w, h):
            raise DatasetError(
                f"image {images[0]} is {w}x{h} but {cam_file} says {opts['width']}x{opts['height']}"
            )
        try:
            camera = PinholeCamera(opts["fx"], opts["fy"], opts["cx"], opts["cy"], w, h, dist)
        except CodeSLAMError as e:
            raise ConfigError(f"{cam_file}: {e}") from None
        self.source_camera = camera
        self.undistort = undistort and camera.has_distortion
        self._camera = camera.without_distortion()

        self._depths: list[Path] | None = None
        depth_dir = root / "depth"
        if depth_dir.is_dir():
            depths = []
            for p in images:
                cands = [depth_dir / f"{p.stem}{ext}" for ext in (".png", ".npy")]
                found = [c for c in cands if c.is_file()]
                if not found:
                    raise DatasetError(f"image {p.name} has no depth map {p.stem}.png or {p.stem}.npy in {depth_dir}")
                depths.append(found[0])
            self._depths = depths

        self._gt = self._read_gt(root / POSES_FILE, read_tum, stamps, pose_max_gap)

    @staticmethod
    def detect(root: Path) -> bool:
        return (Path(root) / CAMERA_FILE).is_file()

    def _read_depth(self, path: Path) -> torch.Tensor:
        return read_depth_npy(path) if path.suffix == ".npy" else read_depth_png(path, self.depth_factor)
