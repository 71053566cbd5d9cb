"""Keyframe selection (paper Sec. 4.3: "once a certain baseline is achieved we add a keyframe"), PTAM-like: a
tracked frame becomes a keyframe when it has moved far enough from the last keyframe, relative to the scene's
depth (parallax), when it has turned far enough, or when too little of the keyframe is still in view."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from codeslam.geometry.lie import so3_log
from codeslam.slam.config import KeyframeConfig


@dataclass(frozen=True)
class KeyframeDecision:
    """Whether to add a keyframe and why. reason: 'baseline', 'rotation', 'overlap' or '' (no keyframe), or
    'tracking failed' / 'too soon' when a criterion held but the frame is not eligible."""

    add: bool
    reason: str
    baseline_ratio: float
    rotation_deg: float
    overlap: float


def motion_since_keyframe(T_kf: torch.Tensor, median_depth: float) -> tuple[float, float]:
    """(4, 4) pose of the frame in the keyframe -> (translation / median scene depth, rotation angle in degrees).

    The baseline-to-depth ratio measures parallax independently of the map's (monocular) scale."""
    t = float(T_kf[:3, 3].norm())
    angle = float(so3_log(T_kf[:3, :3]).norm())
    return t / median_depth, math.degrees(angle)


def decide_keyframe(
    T_kf: torch.Tensor,
    median_depth: float,
    overlap: float,
    frames_since_keyframe: int,
    tracking_ok: bool,
    cfg: KeyframeConfig,
) -> KeyframeDecision:
    """The keyframe decision for a tracked frame.

    T_kf (4, 4): the frame's pose in the last keyframe; median_depth: that keyframe's median decoded depth;
    overlap: fraction of the keyframe's pixels visible in the frame (from the tracker); frames_since_keyframe:
    1 for the frame right after the keyframe.
    """
    ratio, rot = motion_since_keyframe(T_kf, median_depth)
    if ratio >= cfg.min_baseline_ratio:
        reason = "baseline"
    elif rot >= cfg.max_rotation_deg:
        reason = "rotation"
    elif overlap < cfg.min_overlap:
        reason = "overlap"
    else:
        return KeyframeDecision(False, "", ratio, rot, overlap)
    if not tracking_ok:
        return KeyframeDecision(False, "tracking failed", ratio, rot, overlap)
    if frames_since_keyframe < cfg.min_frames_between:
        return KeyframeDecision(False, "too soon", ratio, rot, overlap)
    return KeyframeDecision(True, reason, ratio, rot, overlap)
