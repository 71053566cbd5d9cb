"""The runner reads one frame ahead on a thread of its own (issue 12): frames come in the order asked for, the next
one is read while the caller works on the current one, a reading error surfaces at its own frame, and no reading
thread outlives the loop. With a depth model that never reads depth (the network's) the frames are read without it
and the keyframes get the dataset's depth after the run, the same maps as a run on frames with depth."""

from __future__ import annotations

import dataclasses
import threading

import pytest
import torch
from slam_scene import MemorySequence, preset_frames, rolling_shutter_frames, small_config

from codeslam.errors import DatasetError
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.proximity import depth_to_prox
from codeslam.sfm.decoder import standin_decoder
from codeslam.slam.pipeline import read_ahead, run_slam
from codeslam.slam.system import CodeSLAM


class _Recording(MemorySequence):
    """Records which thread read which frame; ``fail_at`` raises a DatasetError there."""

    def __init__(self, frames, fail_at: int | None = None) -> None:
        super().__init__(frames)
        self.reads: list[tuple[int, str]] = []
        self.depth_asked: list[bool] = []
        self.depth_reads: list[int] = []
        self.fail_at = fail_at
        self.read_event = {i: threading.Event() for i in range(len(frames))}

    def frame(self, i, depth=True):
        if i == self.fail_at:
            raise DatasetError(f"frame {i} is unreadable")
        self.reads.append((i, threading.current_thread().name))
        self.depth_asked.append(depth)
        self.read_event[i].set()
        return super().frame(i, depth)

    def depth(self, i):  # a depth read alone, as the readers with depth do it
        self.depth_reads.append(i)
        return self.frames[i].depth


def _reading_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("codeslam-read")]


def test_frames_come_in_order_and_the_next_is_read_while_the_caller_works():
    seq = _Recording(preset_frames(3, 5, "walk", 10.0, width=32, height=24))
    order = [4, 0, 3, 1]
    got = []
    for k, (frame, waited) in enumerate(read_ahead(seq, order)):
        got.append(frame.index)
        assert waited >= 0.0
        if k + 1 < len(order):  # the caller holds frame k: frame k + 1 is read meanwhile, without being asked
            assert seq.read_event[order[k + 1]].wait(timeout=10.0)
    assert got == [seq.frames[i].index for i in order]
    assert [i for i, _ in seq.reads] == order  # each frame read once, none beyond the last
    assert all(name.startswith("codeslam-read") for _, name in seq.reads)
    assert _reading_threads() == []


def test_a_reading_error_surfaces_at_its_frame_and_the_thread_ends():
    seq = _Recording(preset_frames(3, 4, "walk", 10.0, width=32, height=24), fail_at=2)
    got = []
    with pytest.raises(DatasetError, match="frame 2 is unreadable"):
        for frame, _ in read_ahead(seq, range(4)):
            got.append(frame.index)
    assert got == [seq.frames[0].index, seq.frames[1].index]
    assert _reading_threads() == []


def test_a_loop_left_early_leaves_no_reading_thread():
    seq = _Recording(preset_frames(3, 5, "walk", 10.0, width=32, height=24))
    it = read_ahead(seq, range(5))
    next(it)
    it.close()  # the caller stops (an error in the system, Ctrl-C): the frame read ahead is dropped
    assert _reading_threads() == []
    assert [i for i, _ in seq.reads] in ([0], [0, 1])  # frame 1 read or cancelled before it started, no more
    assert list(read_ahead(seq, [])) == []


def test_the_reading_thread_leaves_the_callers_torch_threads():
    seq = _Recording(preset_frames(3, 3, "walk", 10.0, width=32, height=24))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        counts = [torch.get_num_threads() for _ in read_ahead(seq, range(3))]
        assert counts == [2, 2, 2]  # the reader runs one thread of its own; the caller keeps its two
    finally:
        torch.set_num_threads(before)


def _wall_model(reads_depth: bool | None):
    """A depth model that decodes every frame to a plane 3 m away without looking at its depth (as the network
    reads only the image); ``reads_depth`` False says so, None leaves the attribute off (a model that may)."""

    def decode(frame):
        h, w = frame.image.shape[-2:]
        prox = depth_to_prox(torch.full((h, w), 3.0, dtype=torch.float64), 1.5)
        return standin_decoder(prox, 8, 3, 1.5)

    if reads_depth is not None:
        decode.reads_depth = reads_depth
    return decode


def test_frames_come_without_depth_to_a_model_that_never_reads_it_and_keyframes_get_theirs_after_the_run():
    # A turning camera's frames at 128x96, the system in 64x48 with a rolling shutter: each keyframe's depth is
    # resampled and rectified by the readout its image was.
    frames = rolling_shutter_frames(0.5, frames=10, width=128, height=96)
    cfg = small_config(size=3)
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, rolling_shutter_estimate=False,
                                                               rolling_shutter_readout=0.5))
    runs = {}
    for reads_depth in (False, None):
        seq = _Recording(frames)
        system = CodeSLAM(cfg, _wall_model(reads_depth))
        assert system.reads_frame_depth == (reads_depth is None)
        runs[reads_depth] = (run_slam(seq, system, canonical_camera(64, 48)), seq)
    (bare, bare_seq), (whole, whole_seq) = runs[False], runs[None]
    assert bare_seq.depth_asked == [False] * 10 and whole_seq.depth_asked == [True] * 10
    assert whole_seq.depth_reads == [] and sorted(bare_seq.depth_reads) == [k.frame_index for k in bare.keyframes]
    assert len(bare.keyframes) >= 2 and [k.frame_index for k in bare.keyframes] == [k.frame_index for k in
                                                                                    whole.keyframes]
    assert any(k.rectified_by is not None for k in bare.keyframes)
    for a, b in zip(bare.keyframes, whole.keyframes):
        assert a.depth_gt is not None and a.depth_gt.shape == (48, 64)
        assert torch.equal(a.depth_gt, b.depth_gt)  # the same map as from frames read with their depth
        assert torch.equal(a.T_wc, b.T_wc)


def test_an_error_in_the_system_leaves_no_reading_thread_while_its_traceback_is_held():
    # the frame read ahead is cancelled and its thread joined when the run fails, not when the failed run's frames
    # (which a held traceback keeps) are collected
    class Boom(Exception):
        pass

    def failing_model(frame):
        raise Boom("the depth model failed")

    seq = _Recording(preset_frames(3, 6, "walk", 10.0, width=32, height=24))
    with pytest.raises(Boom) as held:
        run_slam(seq, CodeSLAM(small_config(size=3), failing_model), canonical_camera(32, 24))
    assert held.value is not None and _reading_threads() == []
