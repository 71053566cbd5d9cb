"""TUM RGB-D benchmark folders (Sturm et al., IROS 2012).

Layout::

    rgb.txt            timestamp filename   (e.g. ``1305031232.525781 rgb/1305031232.525781.png``)
    depth.txt          timestamp filename   (16-bit PNG, value / 5000 = metres, 0 = no measurement); optional
    groundtruth.txt    timestamp tx ty tz qx qy qz qw  (T_wc of the colour camera); optional
    calib.txt          fx fy cx cy [k1 k2 p1 p2 [k3]]  (not a TUM file, see below); optional

Choices (documented here because the benchmark leaves them to the user):

- **Frames.** One frame per ``rgb.txt`` line. When ``depth.txt`` exists, colour and depth are paired by
  nearest timestamp (:func:`~codeslam.data.association.associate`, at most ``max_diff`` = 0.02 s apart, as
  the benchmark's ``associate.py``); colour frames with no depth partner are dropped (with a warning), the
  benchmark's own convention for RGB-D work. Without ``depth.txt`` every colour frame is kept and
  ``depth`` is None.
- **Poses.** ``groundtruth.txt`` (100 Hz motion capture) is interpolated to each colour timestamp (linear
  position, slerp rotation). Frames outside its span or inside a capture gap longer than ``gt_max_gap``
  get ``pose=None`` and a NaN row in :attr:`gt_poses`. No ``groundtruth.txt`` -> no poses.
- **Camera.** ``calib.txt`` when present (one line ``fx fy cx cy`` with optional distortion, the form
  several SLAM systems ship for TUM; the image size is read from the first image). Otherwise the
  calibrated preset of the Kinect named in the folder name (``freiburg1``/``fr1`` ...), TUM's published
  values; otherwise the ROS default (525, 525, 319.5, 239.5) with a warning.
- **Undistortion.** TUM registered the depth onto the (distorted) colour image pixel for pixel, so both
  images live on the same distorted pixel grid. With ``undistort=True`` (default) both are resampled
  with the *same* map to the undistorted camera (colour bilinear, depth nearest), so they stay registered.
  (TUM suggests the undistorted ROS default intrinsics for depth work instead; pass ``camera=TUM_ROS_DEFAULT``
  or ``undistort=False`` to follow that.) ``undistort=False`` ignores the distortion coefficients: the
  frames are returned as stored and :attr:`camera` is the calibrated camera without its distortion.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import torch

from codeslam.data.association import associate
from codeslam.data.base import ImageFileSequence
from codeslam.data.imageio import image_size, read_depth_png, require_file, resolve_in_root
from codeslam.data.textfile import check_increasing, data_lines, finite_floats
from codeslam.data.trajectory import read_tum
from codeslam.errors import CodeSLAMError, DatasetError
from codeslam.geometry.camera import PinholeCamera

#: TUM depth PNGs: value 5000 = 1 m.
TUM_DEPTH_FACTOR = 5000.0
#: Largest colour-depth timestamp difference for a pair (the benchmark's associate.py default).
TUM_MAX_DIFF_S = 0.02
#: Largest spacing of the two ground-truth samples a frame's pose is interpolated between (the capture
#: runs at 100 Hz, so 0.1 s bridges up to 9 dropped samples and no real dropout).
TUM_GT_MAX_GAP_S = 0.1

# TUM's published calibration of the three Kinects' colour cameras (cvg.cit.tum.de, "intrinsic camera
# calibration of the Kinect"), 640x480, distortion (k1, k2, p1, p2, k3).
TUM_PRESETS: dict[str, PinholeCamera] = {
    "fr1": PinholeCamera(517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": PinholeCamera(520.9, 521.0, 325.1, 249.7, 640, 480, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480),
}
#: The ROS default intrinsics (no distortion) TUM recommends for the registered depth.
TUM_ROS_DEFAULT = PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480)

_PRESET_RE = re.compile(r"(?:freiburg|(?<![a-z])fr)([123])(?![0-9])")


def read_list_file(path: Path, root: Path) -> tuple[np.ndarray, list[Path]]:
    """Parse a TUM list file ``timestamp filename`` -> ((N,) float64 seconds, N paths inside ``root``).

    Comments (``#``) and blank lines are skipped. A line with other than two fields, a timestamp that is
    not a finite number, timestamps not strictly increasing, a path outside ``root`` or a missing file is
    a DatasetError naming ``file:line``.
    """
    stamps: list[float] = []
    files: list[Path] = []
    for where, line in data_lines(path):
        parts = line.split()
        if len(parts) != 2:
            raise DatasetError(f"{where}: expected 'timestamp filename', got {len(parts)} fields")
        (t,) = finite_floats(parts[:1], where, line)
        check_increasing(stamps, t, where, parts[0])
        files.append(require_file(resolve_in_root(root, parts[1], where), where))
        stamps.append(t)
    return np.array(stamps, dtype=np.float64), files


def read_calib_txt(path: Path, width: int, height: int) -> PinholeCamera:
    """``fx fy cx cy [k1 k2 p1 p2 [k3]]`` on the first non-comment line -> camera of ``width`` x ``height``."""
    where, line = next(data_lines(path), (None, None))
    if line is None:
        raise DatasetError(f"{path} is empty; expected 'fx fy cx cy [k1 k2 p1 p2 k3]'")
    parts = line.replace(",", " ").split()
    if len(parts) not in (4, 8, 9):
        raise DatasetError(f"{where}: expected 4, 8 or 9 numbers 'fx fy cx cy [k1 k2 p1 p2 [k3]]', got {len(parts)}")
    vals = finite_floats(parts, where, line)
    dist = tuple(vals[4:]) + (0.0,) * (9 - len(vals)) if len(vals) > 4 else (0.0,) * 5
    try:
        return PinholeCamera(vals[0], vals[1], vals[2], vals[3], width, height, dist)
    except CodeSLAMError as e:
        raise DatasetError(f"{path}: {e}") from None


def preset_for_folder(root: Path) -> str | None:
    """``"fr1"``/``"fr2"``/``"fr3"`` when the folder name names a TUM Kinect, else None."""
    m = _PRESET_RE.search(root.resolve().name.lower())
    return f"fr{m.group(1)}" if m else None


class TumSequence(ImageFileSequence):
    """A TUM RGB-D sequence folder (see the module docstring for every choice made)."""

    format_name = "tum"

    def __init__(
        self,
        root: str | Path,
        camera: PinholeCamera | None = None,
        undistort: bool = True,
        max_diff: float = TUM_MAX_DIFF_S,
        gt_max_gap: float = TUM_GT_MAX_GAP_S,
        depth_factor: float = TUM_DEPTH_FACTOR,
    ) -> None:
        super().__init__(root)
        root = self.root
        if not root.is_dir():
            raise DatasetError(f"dataset folder not found: {root}")
        rgb_txt = root / "rgb.txt"
        if not rgb_txt.is_file():
            raise DatasetError(f"{root} is not a TUM RGB-D folder: rgb.txt is missing")
        stamps, rgb_files = read_list_file(rgb_txt, root)
        if len(stamps) == 0:
            raise DatasetError(f"{rgb_txt} lists no images")
        self.depth_factor = depth_factor

        # Depth: pair every colour frame with its nearest depth frame; drop colour frames without one.
        self._depths: list[Path] | None = None
        self.depth_timestamps: np.ndarray | None = None
        depth_txt = root / "depth.txt"
        if depth_txt.is_file():
            d_stamps, d_files = read_list_file(depth_txt, root)
            ia, ib = associate(stamps, d_stamps, max_diff)
            if len(ia) == 0:
                raise DatasetError(
                    f"no image in {rgb_txt} has a depth map in {depth_txt} within {max_diff} s"
                )
            if len(ia) < len(stamps):
                warnings.warn(
                    f"{root}: {len(stamps) - len(ia)} of {len(stamps)} colour images have no depth map within "
                    f"{max_diff} s and are skipped",
                    stacklevel=2,
                )
            stamps = stamps[ia]
            rgb_files = [rgb_files[i] for i in ia]
            self._depths = [d_files[j] for j in ib]
            self.depth_timestamps = d_stamps[ib]  # (N,) seconds of each frame's depth map
        self._stamps = stamps
        self._images = rgb_files

        # Camera: explicit > calib.txt > preset from the folder name > ROS default.
        w, h = image_size(rgb_files[0])
        calib = root / "calib.txt"
        if camera is None and calib.is_file():
            camera = read_calib_txt(calib, w, h)
        elif camera is None:
            preset = preset_for_folder(root)
            if preset is None:
                warnings.warn(
                    f"{root}: no calib.txt and no freiburg1/2/3 in the folder name; using the ROS default "
                    "intrinsics fx=fy=525, cx=319.5, cy=239.5",
                    stacklevel=2,
                )
                camera = TUM_ROS_DEFAULT
            else:
                camera = TUM_PRESETS[preset]
        if (w, h) != (camera.width, camera.height):
            raise DatasetError(
                f"image {rgb_files[0]} is {w}x{h} but the camera is {camera.width}x{camera.height}"
            )
        self.source_camera = camera
        self.undistort = undistort and camera.has_distortion
        self._camera = camera.without_distortion()

        # Ground truth at the colour timestamps.
        self._gt = self._read_gt(root / "groundtruth.txt", read_tum, stamps, gt_max_gap, "image")

    @staticmethod
    def detect(root: Path) -> bool:
        return (Path(root) / "rgb.txt").is_file()

    @property
    def image_files(self) -> tuple[Path, ...]:
        """Each frame's colour image file, as associated (frames without a depth map left out)."""
        return tuple(self._images)

    @property
    def depth_files(self) -> tuple[Path, ...] | None:
        """Each frame's depth map file, as associated with its colour image; None without depth."""
        return None if self._depths is None else tuple(self._depths)

    def _read_depth(self, path: Path) -> torch.Tensor:
        return read_depth_png(path, self.depth_factor)
