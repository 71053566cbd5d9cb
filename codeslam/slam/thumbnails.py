"""Which stored keyframes a lost frame looks like: PTAM's small blurry images (the relocaliser of Klein and Murray,
"Improving the Agility of Keyframe-Based SLAM", ECCV 2008), beside the keyframes nearest the predicted pose.

A lost frame is relocalised by ORB matching and PnP against stored keyframes (:mod:`codeslam.slam.frontend`), tried
nearest to the motion model's prediction first. After a long loss (a lens covered while the camera moved, a camera
carried back to a place it saw earlier) the prediction says nothing about where the camera is: a HoloLens walk
carried back from frame 99 to frame 20 tried only keyframes near its prediction, past frame 99, and started a new
map segment, 1.4 m off (docs/results/slam_table.md, fiftieth session). PTAM finds its candidates by appearance: each
keyframe's image shrunk to 40x30 pixels, blurred and made zero-mean, compared with the lost frame's by the sum of
squared differences. Here the thumbnail is also scaled to unit norm, so that the comparison is the normalised
cross-correlation and a change of exposure does not move it.
"""

from __future__ import annotations

import kornia
import torch
import torch.nn.functional as F

from codeslam.geometry.image import rgb_to_gray

THUMBNAIL_SIZE = (24, 32)
"""(height, width) of a thumbnail: the network's 128x96 image shrunk four times (PTAM: 40x30 from 640x480)."""
THUMBNAIL_BLUR = 1.5
"""Gaussian blur of a thumbnail (its pixels; PTAM: 2.5 at 40x30), so that a few pixels of motion keep it alike."""


def thumbnail(image: torch.Tensor) -> torch.Tensor:
    """(H, W) or (1, H, W) grey or (3, H, W) RGB image in [0, 1] -> (h * w,) float32 CPU thumbnail of its grey
    levels: area-shrunk to :data:`THUMBNAIL_SIZE`, blurred, zero-mean, unit norm (zero where the image is flat)."""
    img = image.detach().to(device="cpu", dtype=torch.float32)
    img = img.reshape(1, -1, *img.shape[-2:])  # (1, 1 or 3, H, W)
    if img.shape[1] == 3:
        img = rgb_to_gray(img)  # (1, 1, H, W)
    small = F.interpolate(img, size=THUMBNAIL_SIZE, mode="area")  # (1, 1, h, w)
    k = 2 * round(3 * THUMBNAIL_BLUR) + 1
    small = kornia.filters.gaussian_blur2d(small, (k, k), (THUMBNAIL_BLUR, THUMBNAIL_BLUR), border_type="replicate")
    v = small.flatten()
    v = v - v.mean()
    norm = v.norm()
    return v / norm if norm > 0 else v


def most_alike(query: torch.Tensor, thumbnails: torch.Tensor, count: int) -> list[int]:
    """Indices of the ``count`` rows of ``thumbnails`` (N, h * w) most like ``query`` (h * w,), best first, by
    normalised cross-correlation (both from :func:`thumbnail`)."""
    if count <= 0 or thumbnails.shape[0] == 0:
        return []
    score = thumbnails @ query  # (N,)
    return torch.topk(score, min(count, score.shape[0])).indices.tolist()
