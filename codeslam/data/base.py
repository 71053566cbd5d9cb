"""The interface every dataset reader implements."""

from __future__ import annotations

import abc
import warnings
from pathlib import Path

import numpy as np
import torch

from codeslam.data.frame import Frame
from codeslam.data.imageio import (
    check_depth_shape,
    check_frame_shapes,
    frame_index,
    read_rgb,
    undistort_depth_map,
    undistort_frame,
)
from codeslam.geometry.camera import PinholeCamera


class Sequence(abc.ABC):
    """A random-access sequence of :class:`Frame`, read lazily from disk.

    Subclasses parse their list files in ``__init__`` (so a malformed folder fails at once with a
    :class:`~codeslam.errors.DatasetError`) and read images only in :meth:`frame` (``sequence[i]``).
    """

    #: short format name used by ``--format`` and the registry
    format_name: str = ""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @staticmethod
    @abc.abstractmethod
    def detect(root: Path) -> bool:
        """Whether ``root`` looks like a folder of this format (cheap: file names only)."""

    # Readers set these three attributes in __init__; the accessors below are shared by every format.
    _camera: PinholeCamera  # the (undistorted) camera of every frame
    _stamps: np.ndarray  # (N,) float64 seconds
    _gt: torch.Tensor | None  # (N, 4, 4) float64 T_wc at the frame timestamps (NaN rows: no pose), or None

    @property
    def camera(self) -> PinholeCamera:
        """The (undistorted) pinhole camera of every frame."""
        return self._camera

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) float64 seconds of the frames."""
        return self._stamps

    @property
    @abc.abstractmethod
    def has_depth(self) -> bool: ...

    @property
    def gt_poses(self) -> torch.Tensor | None:
        """(N, 4, 4) float64 ground-truth ``T_wc`` at the frame timestamps, or None."""
        return self._gt

    def _pose(self, i: int) -> torch.Tensor | None:
        """Frame ``i``'s ground-truth ``T_wc`` (a copy), or None: no ground truth, or none near its timestamp (a
        NaN row)."""
        if self._gt is None or bool(torch.isnan(self._gt[i]).any()):
            return None
        return self._gt[i].clone()

    def _read_gt(
        self, path: Path, read, stamps: np.ndarray, max_gap: float, what: str = "frame"
    ) -> torch.Tensor | None:
        """Ground truth from the trajectory file ``path`` (parsed by ``read``: path -> Trajectory) interpolated at
        ``stamps``: (N, 4, 4) float64 with NaN rows where no pose is within ``max_gap`` seconds; sets ``gt_path``.
        None when the file does not exist, or (with a warning) when it covers none of the timestamps."""
        from codeslam.data.association import interpolate_poses

        self.gt_path: Path | None = None
        if not path.is_file():
            return None
        poses, valid = interpolate_poses(read(path), stamps, max_gap)
        if not bool(valid.any()):
            warnings.warn(f"{path} covers none of the {what} timestamps; no poses", stacklevel=3)
            return None
        self.gt_path = path
        return poses

    def __len__(self) -> int:
        return len(self._stamps)

    def __getitem__(self, i: int) -> Frame:
        return self.frame(i)

    @abc.abstractmethod
    def frame(self, i: int, depth: bool = True) -> Frame:
        """Frame ``i`` (Python indexing); with ``depth=False`` its depth is left unread (None) for a consumer
        that never looks at it: monocular SLAM with the network's depth reads only its keyframes' depth, for the
        report, with :meth:`depth` (on TUM fr1/rpy a depth PNG's decoding and undistortion are about a third of a
        frame's 35 ms read)."""

    def depth(self, i: int) -> torch.Tensor | None:
        """Frame ``i``'s depth alone, as ``self[i].depth`` (None when the dataset has none); readers with
        depth read it without the image."""
        return self.frame(i).depth

    @property
    def has_pose(self) -> bool:
        return self.gt_poses is not None

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]


class ImageFileSequence(Sequence):
    """A reader of listed image files, optional depth files beside them and a lens that may be undistorted (TUM,
    image folders, EuRoC, TartanAir): each reads, checks and undistorts a frame the same way. A subclass lists the
    files in ``__init__`` and, with depth files, says how one is read (:meth:`_read_depth`)."""

    _images: list[Path]  # each frame's image file
    _depths: list[Path] | None = None  # each frame's depth file, or None without depth
    source_camera: PinholeCamera  # the camera as recorded, with its lens distortion
    undistort: bool = False  # whether frames are resampled to ``_camera`` (the distortion removed)

    @property
    def has_depth(self) -> bool:
        return self._depths is not None

    def _read_depth(self, path: Path) -> torch.Tensor:
        """(H, W) metres of the depth file ``path`` (readers with depth files say how)."""
        raise NotImplementedError(f"{type(self).__name__} reads no depth files")

    def frame(self, i: int, depth: bool = True) -> Frame:
        i = frame_index(i, len(self))
        image = read_rgb(self._images[i])
        depth_map, depth_path = None, None
        if depth and self._depths is not None:
            depth_path = self._depths[i]
            depth_map = self._read_depth(depth_path)
        check_frame_shapes(self.source_camera, image, depth_map, self._images[i], depth_path)
        valid = None
        if self.undistort:
            image, depth_map, valid = undistort_frame(self.source_camera, image, depth_map)
        return Frame(float(self._stamps[i]), image, self._camera, depth_map, self._pose(i), i, valid)

    def depth(self, i: int) -> torch.Tensor | None:
        i = frame_index(i, len(self))
        if self._depths is None:
            return None
        depth = self._read_depth(self._depths[i])
        check_depth_shape(self.source_camera, depth, self._depths[i])
        return undistort_depth_map(self.source_camera, depth) if self.undistort else depth
