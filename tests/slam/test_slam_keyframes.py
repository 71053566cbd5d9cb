"""Keyframe selection: baseline relative to the scene depth, rotation, overlap; never on failed tracking or too
soon after the last keyframe."""

from __future__ import annotations

import math

import pytest
import torch

from codeslam.geometry.lie import se3_exp
from codeslam.slam.config import KeyframeConfig
from codeslam.slam.keyframes import decide_keyframe, motion_since_keyframe

D = torch.float64
CFG = KeyframeConfig(min_baseline_ratio=0.1, max_rotation_deg=10.0, min_overlap=0.6, min_frames_between=2,
                     min_feature_inliers=50)


def _pose(t=(0.0, 0.0, 0.0), rot_deg=(0.0, 0.0, 0.0)):
    return se3_exp(torch.tensor([*t, *(math.radians(a) for a in rot_deg)], dtype=D))


def test_motion_since_keyframe_is_baseline_over_depth_and_rotation_angle():
    T = _pose((0.3, 0.0, 0.4), (0.0, 0.0, 0.0))
    ratio, rot = motion_since_keyframe(T, median_depth=2.0)
    assert ratio == pytest.approx(0.25) and rot == pytest.approx(0.0, abs=1e-9)
    T = _pose(rot_deg=(3.0, 0.0, 4.0))
    assert motion_since_keyframe(T, 2.0)[1] == pytest.approx(5.0, rel=1e-9)


@pytest.mark.parametrize("depth", [0.5, 2.0, 8.0])
def test_translation_threshold_scales_with_the_scene_depth(depth):
    below = decide_keyframe(_pose((0.09 * depth, 0.0, 0.0)), depth, 0.9, 5, True, CFG)
    above = decide_keyframe(_pose((0.0, 0.11 * depth, 0.0)), depth, 0.9, 5, True, CFG)
    assert not below.add and below.reason == ""
    assert above.add and above.reason == "baseline"


def test_rotation_threshold():
    assert not decide_keyframe(_pose(rot_deg=(0.0, 9.0, 0.0)), 2.0, 0.9, 5, True, CFG).add
    d = decide_keyframe(_pose(rot_deg=(0.0, 11.0, 0.0)), 2.0, 0.9, 5, True, CFG)
    assert d.add and d.reason == "rotation" and d.rotation_deg == pytest.approx(11.0)


def test_overlap_threshold():
    assert not decide_keyframe(_pose(), 2.0, 0.61, 5, True, CFG).add
    d = decide_keyframe(_pose(), 2.0, 0.59, 5, True, CFG)
    assert d.add and d.reason == "overlap"


def test_no_keyframe_on_failed_tracking_or_too_soon():
    far = _pose((0.3, 0.0, 0.0))  # baseline ratio 0.15: above 0.1, below twice that
    d = decide_keyframe(far, 2.0, 0.9, 5, False, CFG)
    assert not d.add and d.reason == "tracking failed"
    d = decide_keyframe(far, 2.0, 0.9, 1, True, CFG)
    assert not d.add and d.reason == "too soon" and not d.urgent
    assert decide_keyframe(far, 2.0, 0.9, 2, True, CFG).add


@pytest.mark.parametrize("case", ["baseline", "rotation", "overlap", "features"])
def test_an_urgent_keyframe_is_made_even_right_after_the_last(case):
    T, overlap, inliers = {
        "baseline": (_pose((0.5, 0.0, 0.0)), 0.9, None),  # twice the baseline ratio
        "rotation": (_pose(rot_deg=(0.0, 21.0, 0.0)), 0.9, None),  # twice the rotation
        "overlap": (_pose(), 0.3, None),  # below urgent_overlap (0.45)
        "features": (_pose(), 0.9, 10),  # matches thinning out
    }[case]
    d = decide_keyframe(T, 2.0, overlap, 1, True, CFG, inliers)
    assert d.add and d.urgent and d.reason == case
    assert not decide_keyframe(T, 2.0, overlap, 1, False, CFG, inliers).add  # never on failed tracking


def test_feature_threshold_applies_only_where_features_were_matched():
    cfg = KeyframeConfig(min_baseline_ratio=0.1, max_rotation_deg=10.0, min_overlap=0.6, min_frames_between=2,
                         min_feature_inliers=50)
    assert not decide_keyframe(_pose(), 2.0, 0.9, 5, True, cfg, 50).add
    d = decide_keyframe(_pose(), 2.0, 0.9, 5, True, cfg, 49)
    assert d.add and d.reason == "features"
    assert decide_keyframe(_pose(), 2.0, 0.9, 5, True, cfg, 0).add  # features found, none matched
    assert not decide_keyframe(_pose(), 2.0, 0.9, 5, True, cfg, None).add  # no feature tracking ran
    off = KeyframeConfig(min_feature_inliers=0)
    assert not decide_keyframe(_pose(), 2.0, 0.9, 5, True, off, 0).add
