"""Map segments joined again when the camera comes back to a place an older segment mapped (ORB-SLAM3's map
merging, Campos et al., "ORB-SLAM3", T-RO 2021, Sec. VI-B, without its welding bundle adjustment).

After tracking was lost long enough, a new map segment starts at the motion model's prediction
(:class:`~codeslam.slam.config.RecoveryConfig`): its poses are right relative to each other and wrong by however far
the prediction was off. While such a segment is mapped, each frame that becomes a keyframe is matched against the
older segments' keyframes it looks like (ORB + PnP on their depth, :mod:`codeslam.slam.thumbnails`); where it
matches, the frame's pose in the older map and in its own give the rigid motion between the two. Two such
motions from successive keyframes that agree (a single match can be a repeated texture) move the whole segment into
the older map, and tracking goes on in one map. The scale is not changed: both segments take theirs from the same
network's prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from codeslam.geometry.lie import se3_inverse
from codeslam.slam.keyframes import motion_since_keyframe


@dataclass(frozen=True)
class SegmentMerge:
    """One segment moved into an older map.

    Attributes:
        segment: the segment moved (with every segment merged into it before).
        into: the segment that roots the map it joined.
        frame_index: the frame whose match confirmed it; keyframe_id: the older keyframe it matched.
        inliers: PnP inliers of that match.
        G: (4, 4) float64 rigid motion applied to the segment's poses (``T_wc <- G T_wc``).
    """

    segment: int
    into: int
    frame_index: int
    keyframe_id: int
    inliers: int
    G: torch.Tensor


class SegmentMaps:
    """Which map each segment belongs to: a segment is its own map until it is merged into an older one."""

    def __init__(self) -> None:
        self._into: dict[int, int] = {}

    def root(self, segment: int) -> int:
        """The segment that roots ``segment``'s map (itself when never merged)."""
        while segment in self._into:
            segment = self._into[segment]
        return segment

    def join(self, segment: int, into: int) -> None:
        """``segment``'s map becomes part of ``into``'s."""
        a, b = self.root(segment), self.root(into)
        if a == b:
            raise ValueError(f"segments {segment} and {into} are one map already")
        self._into[a] = b


def segment_motion(T_here: torch.Tensor, T_there: torch.Tensor) -> torch.Tensor:
    """The rigid motion ``G`` that takes a frame's pose in its own segment, ``T_here``, to its pose in an older
    map, ``T_there`` (both (4, 4) ``T_wc``): ``G T_here = T_there``."""
    return T_there.to(torch.float64) @ se3_inverse(T_here.to(torch.float64))


def motions_agree(G1: torch.Tensor, G2: torch.Tensor, T_wc: torch.Tensor, depth: float, max_ratio: float,
                  max_deg: float) -> bool:
    """Whether two segment motions put the camera at ``T_wc`` (in the segment) at the same place in the older map:
    positions apart by at most ``max_ratio`` times the scene ``depth`` (a map's translations are in its depth
    units) and rotations by at most ``max_deg`` (:func:`~codeslam.slam.keyframes.motion_since_keyframe` of the one
    pose in the other, as the tracker's deviation from its prediction is read)."""
    A, B = G1.to(torch.float64) @ T_wc.to(torch.float64), G2.to(torch.float64) @ T_wc.to(torch.float64)
    ratio, turn = motion_since_keyframe(se3_inverse(A) @ B, depth)
    return ratio <= max_ratio and turn <= max_deg
