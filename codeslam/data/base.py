"""The interface every dataset reader implements."""

from __future__ import annotations

import abc
import warnings
from pathlib import Path

import numpy as np
import torch

from codeslam.data.frame import Frame
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
