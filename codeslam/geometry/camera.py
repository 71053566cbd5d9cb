"""The pinhole camera.

Conventions: OpenCV camera axes (x right, y down, z forward); pixel (0, 0) is the centre of the top-left
pixel; ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``. Distortion, when a dataset gives it, uses the
OpenCV/TUM ``(k1, k2, p1, p2, k3)`` radial-tangential model and is removed by the readers (undistortion),
so everything downstream sees an ideal pinhole camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from codeslam.errors import CodeSLAMError


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of an ideal pinhole camera and the image size they belong to."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    # Radial-tangential distortion (k1, k2, p1, p2, k3); all zeros means none.
    dist: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in vals):
            raise CodeSLAMError(f"camera intrinsics must be finite numbers, got fx fy cx cy = {vals}")
        if self.fx <= 0 or self.fy <= 0:
            raise CodeSLAMError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.width <= 0 or self.height <= 0:
            raise CodeSLAMError(f"image size must be positive, got {self.width}x{self.height}")
        if not (-0.5 <= self.cx <= self.width - 0.5 and -0.5 <= self.cy <= self.height - 0.5):
            raise CodeSLAMError(
                f"principal point ({self.cx}, {self.cy}) lies outside the {self.width}x{self.height} image"
            )

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    def K(self, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> torch.Tensor:
        """The 3x3 intrinsic matrix."""
        return torch.tensor(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=dtype, device=device
        )

    def params(self, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> torch.Tensor:
        """``(fx, fy, cx, cy)`` as a tensor of shape (4,), the form the pure functions take."""
        return torch.tensor([self.fx, self.fy, self.cx, self.cy], dtype=dtype, device=device)

    def without_distortion(self) -> PinholeCamera:
        return replace(self, dist=(0.0, 0.0, 0.0, 0.0, 0.0))

    def scaled(self, sx: float, sy: float | None = None) -> PinholeCamera:
        """The camera of the same image resized by ``(sx, sy)`` (pixel-centre convention:
        ``c' = (c + 0.5) s - 0.5``)."""
        sy = sx if sy is None else sy
        return PinholeCamera(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=round(self.width * sx),
            height=round(self.height * sy),
            dist=self.dist,
        )

    def resized(self, width: int, height: int) -> PinholeCamera:
        """The camera of the same image resized to ``width`` x ``height`` pixels."""
        return self.scaled(width / self.width, height / self.height)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> PinholeCamera:
        """The camera of the crop whose top-left pixel is ``(x0, y0)`` of this image."""
        return PinholeCamera(
            fx=self.fx, fy=self.fy, cx=self.cx - x0, cy=self.cy - y0, width=width, height=height, dist=self.dist
        )

    def to_dict(self) -> dict:
        return {
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "width": self.width, "height": self.height, "dist": list(self.dist),
        }


def canonical_camera(width: int = 128, height: int = 96, hfov_deg: float = 60.0) -> PinholeCamera:
    """The network's canonical camera: square pixels, centred principal point, ``hfov_deg`` horizontal
    field of view (60 degrees, like SceneNet RGB-D and close to a Kinect's 62.7). Every image is resampled
    to it before it meets the network (the paper's intrinsics correction, Sec. 5.3)."""
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return PinholeCamera(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)
