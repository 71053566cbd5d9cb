"""The runner reads one frame ahead on a thread of its own (issue 12): frames come in the order asked for, the next
one is read while the caller works on the current one, a reading error surfaces at its own frame, and no reading
thread outlives the loop."""

from __future__ import annotations

import threading

import pytest
import torch
from slam_scene import MemorySequence, preset_frames

from codeslam.errors import DatasetError
from codeslam.slam.pipeline import read_ahead


class _Recording(MemorySequence):
    """Records which thread read which frame; ``fail_at`` raises a DatasetError there."""

    def __init__(self, frames, fail_at: int | None = None) -> None:
        super().__init__(frames)
        self.reads: list[tuple[int, str]] = []
        self.fail_at = fail_at
        self.read_event = {i: threading.Event() for i in range(len(frames))}

    def __getitem__(self, i):
        if i == self.fail_at:
            raise DatasetError(f"frame {i} is unreadable")
        self.reads.append((i, threading.current_thread().name))
        self.read_event[i].set()
        return self.frames[i]


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
