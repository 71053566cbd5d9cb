"""The typed record every dataset reader returns."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from codeslam.geometry.camera import PinholeCamera


@dataclass
class Frame:
    """One RGB(-D) frame.

    Attributes:
        timestamp: seconds.
        image: (3, H, W) float32 RGB in [0, 1].
        camera: the ideal pinhole camera of ``image`` (already undistorted).
        depth: (H, W) float32 z-depth in metres, 0 where invalid; ``None`` when the dataset has no depth.
        pose: (4, 4) float64 ``T_wc`` (camera-to-world); ``None`` when the dataset has no ground truth.
        index: position of the frame in its sequence.
        valid: (H, W) bool, where ``image`` holds real pixels (False where e.g. undistortion left the image
            uncovered, filled with 0); ``None`` when every pixel is real.
        readout_axis: along which image axis a rolling-shutter sensor's rows follow one another: "rows", or
            "columns" where the reader turned the frames by a quarter turn (a phone's portrait video;
            :mod:`codeslam.geometry.rolling_shutter`).
    """

    timestamp: float
    image: torch.Tensor
    camera: PinholeCamera
    depth: torch.Tensor | None = None
    pose: torch.Tensor | None = None
    index: int = 0
    valid: torch.Tensor | None = None
    readout_axis: str = "rows"

    @property
    def gray(self) -> torch.Tensor:
        """(1, H, W) luminance in [0, 1] (ITU-R BT.601 weights)."""
        w = torch.tensor([0.299, 0.587, 0.114], dtype=self.image.dtype).view(3, 1, 1)
        return (self.image * w).sum(0, keepdim=True)


def resample_frame(frame: Frame, camera: PinholeCamera) -> Frame:
    """The frame seen by ``camera`` (same optical centre and axes, so the pose and z-depths carry over): image
    bilinear and anti-aliased, depth nearest, validity mask resampled (:mod:`codeslam.geometry.resample`)."""
    from codeslam.geometry.resample import resample_depth, resample_image, resample_validity

    if frame.camera == camera:
        return frame
    image = resample_image(frame.image[None].float(), frame.camera, camera)[0]
    depth = None
    if frame.depth is not None:
        depth = resample_depth(frame.depth[None, None].float(), frame.camera, camera)[0, 0]
    valid = resample_validity(frame.valid, frame.camera, camera)
    return dataclasses.replace(frame, image=image, camera=camera, depth=depth, valid=valid)
