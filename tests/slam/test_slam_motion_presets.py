"""Tracking that holds motion as people move a camera: the generator's walk (about 9 cm and up to 6 deg between
frames at 10 frames/s), corridor (the same speeds straight ahead) and fast-turn (pans of 6-9 deg per frame at 10
frames/s) presets, rendered at 160x120, are
tracked on every frame with an accuracy of a fraction of the path (issue 11's check on the generator presets, here
with the stand-in depth so the back-end is tested without the network; scripts/slam_table.py runs the full
sequences with the network)."""

from __future__ import annotations

import pytest
import torch
from slam_scene import MemorySequence, preset_frames

from codeslam.eval.metrics import accumulated_distances
from codeslam.eval.slam_run import evaluate_run
from codeslam.slam.config import SLAMConfig
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import ground_truth, run_slam
from codeslam.slam.system import CodeSLAM
from codeslam.synth.generate import scene_seed


def _run(motion: str, frames: int, seed: int = 21):
    seq = MemorySequence(preset_frames(seed, frames, motion, 10.0))
    system = CodeSLAM(SLAMConfig(), standin_depth_model())
    run = run_slam(seq, system, seq.frames[0].camera)
    gt = ground_truth(seq, range(frames))
    return run, evaluate_run(run.trajectory, gt), float(accumulated_distances(gt.positions_xyz.numpy())[-1])


@pytest.mark.parametrize("motion", ["walk", "fast-turn", "corridor"])
def test_a_preset_path_is_tracked_on_every_frame(motion):
    # the corridor of `codeslam synth --seed 21`: its far end lies beyond the 10 m depth range (6% of the first
    # frame without depth), which the stand-in must fill from the walls around it
    run, ev, path = _run(motion, 24, scene_seed(21, 0) if motion == "corridor" else 21)
    assert [r.index for r in run.results if not r.tracking_ok] == []
    assert all(r.status in ("initialising", "tracked") for r in run.results)
    assert len(run.keyframes) < 24 // 2  # keyframes by parallax and overlap, not every second frame
    assert bool(torch.isfinite(run.trajectory.poses).all())
    if motion == "walk":  # 2.3 m walked: within 1% of the path (measured 0.6% on 30 frames)
        assert path > 1.5 and ev["ate_sim3_rmse"] <= 0.01 * path, (ev["ate_sim3_rmse"], path)
    elif motion == "corridor":  # 2.2 m along the corridor (measured 0.23%; 3.0% with the median-filled depth)
        assert path > 1.5 and ev["ate_sim3_rmse"] <= 0.01 * path, (ev["ate_sim3_rmse"], path)
    else:  # turning on the spot: the orientation is what matters (measured 0.04 deg)
        assert ev["rot_aligned_rmse_deg"] < 0.5 and ev["ate_se3_rmse"] < 0.01, ev


@pytest.mark.parametrize("promote", [True, False])
def test_a_frame_lost_against_its_keyframe_is_tracked_against_the_previous_frame(promote):
    """With keyframes asked for by no criterion, the fast turn leaves the first keyframe's view; the first frame
    that cannot be tracked against it makes the frame before it a keyframe ('next frame lost') and is tracked
    against that instead (recovery.promote_previous). Without that, the same frames are lost."""
    from dataclasses import replace

    from codeslam.slam.config import KeyframeConfig, RecoveryConfig

    frames = 16
    seq = MemorySequence(preset_frames(21, frames, "fast-turn", 10.0))
    never = KeyframeConfig(min_baseline_ratio=1e3, max_rotation_deg=1e3, min_overlap=0.0, urgent_overlap=0.0,
                           min_feature_inliers=0)
    cfg = replace(SLAMConfig(), keyframes=never, recovery=replace(RecoveryConfig(), promote_previous=promote,
                                                                  relocalise=False))
    run = run_slam(seq, CodeSLAM(cfg, standin_depth_model()), seq.frames[0].camera)
    failed = [r.index for r in run.results if not r.tracking_ok]
    promoted = [r.index for r in run.results if r.is_keyframe and r.reason == "next frame lost"]
    if promote:
        assert failed == [] and len(promoted) >= 1, (failed, promoted)
        ev = evaluate_run(run.trajectory, ground_truth(seq, range(frames)))
        assert ev["rot_aligned_rmse_deg"] < 0.5, ev
    else:
        assert failed and promoted == [], (failed, promoted)
