"""Parallel tracking and mapping (issue 12): the mapping thread gives the same frames tracked and an accuracy
within a stated tolerance of the sequential (inline, deterministic) mode on a generator walk, shares the map
without errors, and an error inside the mapping thread reaches the caller."""

from __future__ import annotations

import dataclasses
import time

import pytest
import torch
from slam_scene import MemorySequence, preset_frames

from codeslam.eval.slam_run import evaluate_run
from codeslam.slam.config import SLAMConfig
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.keyframes import MAPPING_BUSY
from codeslam.slam.pipeline import ground_truth, run_slam, summarise
from codeslam.slam.system import CodeSLAM


def _run(parallel: bool, frames=None, depth_model=None, config: SLAMConfig | None = None):
    seq = MemorySequence(frames or preset_frames(21, 24, "walk", 10.0))
    system = CodeSLAM(config or SLAMConfig(), depth_model or standin_depth_model(), parallel=parallel)
    run = run_slam(seq, system, seq.frames[0].camera)
    return system, run, evaluate_run(run.trajectory, ground_truth(seq, range(len(seq))))


def _slow_depth_model(seconds: float):
    """The stand-in depth model, every keyframe after the first (decoded inline) taking ``seconds`` longer: a
    mapping thread slower than the camera. Returns the model and its call counter."""
    factory = standin_depth_model()
    calls = {"n": 0}

    def slow(frame):
        calls["n"] += 1
        if calls["n"] > 1:
            time.sleep(seconds)
        return factory(frame)

    return slow, calls


def test_parallel_mapping_tracks_the_same_frames_within_tolerance():
    _, seq_run, seq_ev = _run(False)
    system, par_run, par_ev = _run(True)
    assert [r.tracking_ok for r in par_run.results] == [r.tracking_ok for r in seq_run.results]
    assert all(r.tracking_ok for r in par_run.results)
    # Tolerance. The tracker does not wait for the mapping thread, so while it is busy no keyframe is taken and
    # the keyframes are sparser (measured: 5 instead of 7 on these 24 frames, frames 0 5 12 15 22 against 0 5 9
    # 13 16 19 22), and the trajectory is less accurate: sequential 0.016 m (0.7% of the 2.3 m path); parallel,
    # whose keyframes depend on the threads' timing, 2.1-3.8% over six runs on the idle 2-core machine and 4.1%
    # once in a full CI run (a keyframe gap of 9 frames while the thread was busy). Stated tolerance: sequential
    # within 1% of the path, parallel within 6%; a run that loses the map ends far outside (tens of percent).
    path = seq_ev["path_length_gt"]
    assert seq_ev["ate_sim3_rmse"] <= 0.01 * path, seq_ev["ate_sim3_rmse"]
    assert par_ev["ate_sim3_rmse"] <= 0.06 * path, (par_ev["ate_sim3_rmse"], seq_ev["ate_sim3_rmse"])
    assert len(par_run.keyframes) >= 2 and system.mapper.updates >= 1
    # Every keyframe's frame is flagged, with its window solve, once mapping has finished.
    kf_frames = {k.frame_index for k in par_run.keyframes}
    assert {r.index for r in par_run.results if r.is_keyframe} == kf_frames
    assert all(r.window is not None for r in par_run.results if r.is_keyframe and r.index != 0)
    assert system.mapper._thread is None  # stopped by run_slam


def test_an_error_in_the_mapping_thread_reaches_the_caller():
    factory = standin_depth_model()
    calls = {"n": 0}

    def failing(frame):
        calls["n"] += 1
        if calls["n"] == 2:  # the first keyframe is decoded inline, the second on the mapping thread
            raise RuntimeError("decoder exploded")
        return factory(frame)

    with pytest.raises(RuntimeError, match="decoder exploded"):
        _run(True, depth_model=failing)
    assert bool(torch.tensor(calls["n"] >= 2))


def test_the_mapping_thread_and_the_tracker_split_torch_threads(monkeypatch):
    """The mapping thread runs its window solves with its own torch thread count (half by default) and decodes
    keyframes with all of them (the tracker mostly waits for that), the tracker runs with the rest while it
    processes a frame, and the caller's setting is back afterwards."""
    import threading

    from codeslam.slam.window import SlidingWindow

    decoded, solved = {}, {}
    factory = standin_depth_model()

    def recording(frame):  # keyframes after the first are decoded on the mapping thread
        decoded.setdefault(threading.current_thread().name, set()).add(torch.get_num_threads())
        return factory(frame)

    optimise = SlidingWindow.optimise

    def recording_optimise(self, *args, **kwargs):
        solved.setdefault(threading.current_thread().name, set()).add(torch.get_num_threads())
        return optimise(self, *args, **kwargs)

    monkeypatch.setattr(SlidingWindow, "optimise", recording_optimise)
    before = torch.get_num_threads()
    torch.set_num_threads(4)
    try:
        for decode_threads, expected in ((None, {4}), (2, {2})):
            decoded.clear()
            solved.clear()
            seq = MemorySequence(preset_frames(21, 12, "walk", 10.0))
            system = CodeSLAM(SLAMConfig(), recording, parallel=True, mapping_threads=1,
                              decode_threads=decode_threads)
            assert system._tracking_threads == 3
            run_slam(seq, system, seq.frames[0].camera)
            assert torch.get_num_threads() == 4  # the caller's count, restored after every frame
            assert decoded.get("codeslam-mapping") == expected, decoded
            assert solved.get("codeslam-mapping") == {1}, solved
            assert decoded.get("MainThread") == {3}, decoded  # the first keyframe, decoded inline by the tracker
    finally:
        torch.set_num_threads(before)
    with pytest.raises(Exception, match="mapping_threads"):
        CodeSLAM(SLAMConfig(), factory, parallel=True, mapping_threads=0)
    with pytest.raises(Exception, match="decode_threads"):
        CodeSLAM(SLAMConfig(), factory, parallel=True, decode_threads=0)


def test_each_frames_own_work_runs_on_the_alignment_thread_count_and_the_mapping_on_the_callers():
    """Sequential mode: each frame's resampling, keypoints and photometric alignment with ``alignment_threads``
    (1 by default), the keyframes' decoding (mapping) with the caller's count; None leaves the frame's work at
    the caller's."""
    factory = standin_depth_model()
    seq = MemorySequence(preset_frames(21, 8, "walk", 10.0))
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for alignment_threads, expected in ((1, {1}), (None, {2})):
            decoded, aligned, prepared = set(), set(), set()

            def recording(frame, decoded=decoded):
                decoded.add(torch.get_num_threads())
                return factory(frame)

            system = CodeSLAM(SLAMConfig(), recording, alignment_threads=alignment_threads)
            track = system.tracker.track

            def counting(*args, track=track, aligned=aligned, **kwargs):
                aligned.add(torch.get_num_threads())
                return track(*args, **kwargs)

            views = system._views

            def preparing(frame, views=views, prepared=prepared, **kwargs):
                prepared.add(torch.get_num_threads())
                return views(frame, **kwargs)

            system.tracker.track = counting
            system._views = preparing
            run_slam(seq, system, seq.frames[0].camera)
            assert aligned == expected and prepared == expected and decoded == {2}, \
                (alignment_threads, aligned, prepared, decoded)
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    with pytest.raises(Exception, match="alignment_threads"):
        CodeSLAM(SLAMConfig(), factory, alignment_threads=0)


def test_a_frame_lost_against_the_old_keyframe_waits_for_the_one_being_decoded():
    # A mapping thread much slower than the camera (each keyframe's decode takes 1.5 s here): frames after a
    # keyframe was asked for are tracked against the older one until they leave it. Then the tracker waits for
    # the new keyframe instead of giving the frame up (a parallel HoloLens run lost frames 78-80 and 148-150 so).
    slow, calls = _slow_depth_model(1.5)
    # The generator's walk at 5 frames/s (about 18 cm between frames). Measured (1.5 s decodes): without the wait
    # frames 12-14 or 12-15 were lost, ATE 0.31-0.39 m of a 3.5 m path; with it none, 0.18 m (5%).
    system, run, ev = _run(True, frames=preset_frames(21, 20, "walk", 5.0), depth_model=slow)
    assert [r.index for r in run.results if not r.tracking_ok] == []
    assert calls["n"] >= 3 and ev["ate_sim3_rmse"] <= 0.1 * ev["path_length_gt"], ev["ate_sim3_rmse"]


@pytest.mark.parametrize("take", [False, True])
def test_a_keyframe_wanted_while_the_mapping_thread_is_busy_is_refused_or_taken(take):
    # A mapping thread slower than the camera (0.4 s per decode): refused, some wanted keyframes wait for an idle
    # thread ("mapping busy"); with keyframes.take_when_busy the tracker waits for the thread and none is refused.
    slow, _ = _slow_depth_model(0.4)
    cfg = SLAMConfig()
    cfg = dataclasses.replace(cfg, keyframes=dataclasses.replace(cfg.keyframes, take_when_busy=take))
    _, run, _ = _run(True, frames=preset_frames(21, 16, "walk", 10.0), depth_model=slow, config=cfg)
    busy = [r.index for r in run.results if r.keyframe is not None and r.keyframe.reason == MAPPING_BUSY]
    assert all(r.tracking_ok for r in run.results)
    assert (busy == []) if take else (busy != []), busy
    # The run's summary counts them, and every keyframe after the first had its window solve.
    stats = summarise(run)["mapping_statistics"]
    assert stats["refused_busy"] == len(busy)
    assert stats["window_solves"] == len(run.keyframes) - 1 >= 1
    assert 0 <= stats["cut_before_first_iteration"] <= stats["cut_short"] <= stats["window_solves"]
