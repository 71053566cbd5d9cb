"""Keyframe selection (paper Sec. 4.3: "once a certain baseline is achieved we add a keyframe"), PTAM-like: a
tracked frame becomes a keyframe when it has moved far enough from the last keyframe, relative to the scene's
depth (parallax), when it has turned far enough, when too little of the keyframe is still in view, or when too few
of the keyframe's keypoints are still matched (ORB-SLAM's criterion)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from codeslam.geometry.lie import so3_angle_host
from codeslam.slam.config import KeyframeConfig

#: The reason of a keyframe the tracker wanted and did not take because the mapping thread was still busy with the
#: last one (parallel mode; the run's summary counts these frames).
MAPPING_BUSY = "mapping busy"


@dataclass(frozen=True)
class KeyframeDecision:
    """Whether to add a keyframe and why. reason: 'baseline', 'rotation', 'overlap', 'features' or '' (no keyframe), or
    'tracking failed' / 'too soon' when a criterion held but the frame is not eligible (the system adds
    :data:`MAPPING_BUSY` and others when it overrides a decision). urgent: the keyframe is
    leaving the view; starving: fewer of its keypoints matched than ``min_feature_inliers``."""

    add: bool
    reason: str
    baseline_ratio: float
    rotation_deg: float
    overlap: float
    urgent: bool = False
    starving: bool = False


def motion_since_keyframe(T_kf: torch.Tensor, median_depth: float) -> tuple[float, float]:
    """(4, 4) pose of the frame in the keyframe -> (translation / median scene depth, rotation angle in degrees).

    The baseline-to-depth ratio measures parallax independently of the map's (monocular) scale."""
    t = float(T_kf[:3, 3].norm())
    angle = so3_angle_host(T_kf[:3, :3])
    return t / median_depth, math.degrees(angle)


def decide_keyframe(
    T_kf: torch.Tensor,
    median_depth: float,
    overlap: float,
    frames_since_keyframe: int,
    tracking_ok: bool,
    cfg: KeyframeConfig,
    feature_inliers: int | None = None,
) -> KeyframeDecision:
    """The keyframe decision for a tracked frame.

    T_kf (4, 4): the frame's pose in the last keyframe; median_depth: that keyframe's median decoded depth;
    overlap: fraction of the keyframe's pixels visible in the frame (from the tracker); frames_since_keyframe:
    1 for the frame right after the keyframe; feature_inliers: ORB + PnP inliers of the frame against the
    keyframe (None: no feature tracking ran, the criterion does not apply).
    """
    ratio, rot = motion_since_keyframe(T_kf, median_depth)
    # Urgent: the keyframe is leaving the view (twice a threshold, or little overlap). Such a frame becomes a
    # keyframe even right after the last one, and parallel mapping waits for it: measured on the HoloLens walk
    # at every second frame, the frame after a keyframe had turned 23 deg from it and the next one 25 deg more;
    # tracked against the old keyframe that frame had nothing left in view.
    starving = feature_inliers is not None and feature_inliers < cfg.min_feature_inliers
    urgent = (ratio >= 2 * cfg.min_baseline_ratio or rot >= 2 * cfg.max_rotation_deg or overlap < cfg.urgent_overlap
              or starving)
    if ratio >= cfg.min_baseline_ratio:
        reason = "baseline"
    elif rot >= cfg.max_rotation_deg:
        reason = "rotation"
    elif overlap < cfg.min_overlap:
        reason = "overlap"
    elif starving:
        reason = "features"
    else:
        return KeyframeDecision(False, "", ratio, rot, overlap)
    if not tracking_ok:
        return KeyframeDecision(False, "tracking failed", ratio, rot, overlap, urgent, starving)
    if frames_since_keyframe < cfg.min_frames_between and not urgent:
        return KeyframeDecision(False, "too soon", ratio, rot, overlap, urgent, starving)
    return KeyframeDecision(True, reason, ratio, rot, overlap, urgent, starving)
