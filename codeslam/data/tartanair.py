"""TartanAir sequences (Wang et al., IROS 2020), left camera.

Layout of one sequence (``root``, e.g. ``abandonedfactory/Easy/P000``)::

    image_left/000000_left.png            colour, 640x480
    depth_left/000000_left_depth.npy      float32 z-depth in metres (optional)
    pose_left.txt                         one line per image: tx ty tz qx qy qz qw (optional)

- **Poses.** ``pose_left.txt`` gives camera-to-world poses in NED axes: the camera body frame has x
  forward, y right, z down, and so does the world frame. Our camera frame is OpenCV's optical frame
  (x right, y down, z forward). With ``M`` the axis permutation taking NED coordinates to optical ones,
  ``p_opt = M p_ned``, ``M = [[0, 1, 0], [0, 0, 1], [1, 0, 0]]`` (optical x = NED y, optical y = NED z,
  optical z = NED x), a camera-frame point goes to NED by ``M^-1``, to the NED world by ``T_ned`` and to
  an optical-axes world by ``M``: ``T_wc = M T_ned M^-1`` (:func:`ned_to_optical`). The world frame is
  thus the NED world with relabelled axes (x east, y down, z north) -- any fixed world frame is fine for
  SLAM and its evaluation. Moving forward in NED moves the camera along its own +z.
- **Camera.** TartanAir's published pinhole camera fx = fy = 320, cx = 320, cy = 240, 640x480 (a 90 deg
  field of view; the images are rendered without distortion). ``camera=`` overrides it.
- **Timestamps.** TartanAir stores none; frame ``i`` is given ``i / fps`` seconds with a nominal
  ``fps`` = 10 (an assumption, used only for reporting durations and in trajectory files).
- Frames are the images of ``image_left`` sorted by name; depth files are matched by name
  (``<stem>_depth.npy``) and must exist for every image when ``depth_left/`` exists.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from codeslam.data.base import ImageFileSequence
from codeslam.data.imageio import read_depth_npy
from codeslam.data.textfile import check_quaternion, data_lines, finite_floats
from codeslam.data.trajectory import poses_from_tum_rows
from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera

TARTANAIR_CAMERA = PinholeCamera(fx=320.0, fy=320.0, cx=320.0, cy=240.0, width=640, height=480)
#: Nominal frame rate used to make timestamps (TartanAir has none).
TARTANAIR_FPS = 10.0
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

#: p_optical = NED_TO_OPTICAL p_ned.
NED_TO_OPTICAL = torch.tensor(
    [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]], dtype=torch.float64
)


def ned_to_optical(T_ned: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) camera-to-world poses in NED axes -> the same poses in OpenCV optical axes,
    ``M T_ned M^-1`` (see the module docstring)."""
    M = NED_TO_OPTICAL.to(T_ned.dtype)
    return M @ T_ned @ M.T  # M is a permutation: M^-1 = M^T


def read_pose_file(path: Path) -> torch.Tensor:
    """``tx ty tz qx qy qz qw`` per line -> (N, 4, 4) float64 NED camera-to-world poses."""
    rows = []
    for where, line in data_lines(path):
        parts = line.split()
        if len(parts) != 7:
            raise DatasetError(f"{where}: expected 'tx ty tz qx qy qz qw', got {len(parts)} fields")
        vals = finite_floats(parts, where, line)
        check_quaternion(vals[3:], where)
        rows.append(vals)
    if not rows:
        return torch.zeros(0, 4, 4, dtype=torch.float64)
    return poses_from_tum_rows(np.array(rows))


class TartanAirSequence(ImageFileSequence):
    """One TartanAir sequence, left camera (see the module docstring)."""

    format_name = "tartanair"

    def __init__(self, root: str | Path, camera: PinholeCamera | None = None, fps: float = TARTANAIR_FPS) -> None:
        super().__init__(root)
        if not self.root.is_dir():
            raise DatasetError(f"dataset folder not found: {self.root}")
        img_dir = self.root / "image_left"
        if not img_dir.is_dir():
            raise DatasetError(f"{self.root} is not a TartanAir folder: image_left/ is missing")
        if not fps > 0:
            raise DatasetError(f"fps must be positive, got {fps}")
        self._images = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES)
        if not self._images:
            raise DatasetError(f"{img_dir} holds no images")
        n = len(self._images)
        self._camera = TARTANAIR_CAMERA if camera is None else camera
        self.source_camera = self._camera
        self._stamps = np.arange(n, dtype=np.float64) / fps

        depth_dir = self.root / "depth_left"
        self._depths: list[Path] | None = None
        if depth_dir.is_dir():
            self._depths = [depth_dir / f"{p.stem}_depth.npy" for p in self._images]
            missing = [p for p in self._depths if not p.is_file()]
            if missing:
                raise DatasetError(f"{len(missing)} images have no depth file, e.g. {missing[0]}")

        self._gt: torch.Tensor | None = None
        self.gt_path: Path | None = None
        pose_txt = self.root / "pose_left.txt"
        if pose_txt.is_file():
            T_ned = read_pose_file(pose_txt)
            if len(T_ned) != n:
                raise DatasetError(f"{pose_txt} has {len(T_ned)} poses but {img_dir} has {n} images")
            self._gt = ned_to_optical(T_ned)
            self.gt_path = pose_txt

    @staticmethod
    def detect(root: Path) -> bool:
        return (Path(root) / "image_left").is_dir()

    def _read_depth(self, path: Path) -> torch.Tensor:
        return read_depth_npy(path)
