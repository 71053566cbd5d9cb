"""A live run (``codeslam slam --realtime``, :class:`codeslam.slam.pipeline.Live`): the frames arrive at the
recording's times, the system takes the newest one that has arrived when it is ready, the frames skipped meanwhile
are never read, the system is told the recording's frame period, and nothing is processed twice. Time is a fake
clock here, so every schedule is exact."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from slam_scene import MemorySequence, preset_frames, small_config

from codeslam.cli import main
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import canonical_camera
from codeslam.slam.pipeline import Live, live_frames, live_schedule, run_slam
from codeslam.slam.system import CodeSLAM, FrameResult


class FakeClock:
    """A stopwatch that moves only when told to (``advance``) or when someone sleeps on it."""

    def __init__(self) -> None:
        self.now = 100.0
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.now

    def advance(self, dt: float) -> None:
        self.now += dt

    def sleep(self, dt: float) -> None:
        self.slept.append(dt)
        self.now += dt


class _Reads(MemorySequence):
    def __init__(self, frames) -> None:
        super().__init__(frames)
        self.reads: list[int] = []

    def frame(self, i, depth=True):
        self.reads.append(i)
        return super().frame(i, depth)


def _ten_hertz(n: int) -> list:
    frames = preset_frames(3, n, "walk", 10.0, width=32, height=24)
    assert np.allclose(np.diff([f.timestamp for f in frames]), 0.1)
    return frames


def test_the_schedule_takes_the_newest_frame_that_has_arrived_or_waits_for_the_next():
    stamps = 5.0 + 0.1 * np.arange(10)  # 10 frames/s
    assert live_schedule(stamps, -1, 0.0, 1.0) == (0, 0.0)
    assert live_schedule(stamps, 0, 0.25, 1.0) == (2, 0.0)  # frames 1 and 2 came while frame 0 was processed
    k, wait = live_schedule(stamps, 2, 0.21, 1.0)  # the system is early: frame 3 comes at 0.3
    assert k == 3 and wait == pytest.approx(0.09)
    assert live_schedule(stamps, 0, 0.25, 2.0) == (5, 0.0)  # twice the rate: frame k at 0.05 k
    assert live_schedule(stamps, 9, 5.0, 1.0)[0] == 10  # every frame offered
    assert live_schedule(stamps, 3, 100.0, 1.0) == (9, 0.0)  # long after the end: the last frame


def test_a_slow_system_gets_the_newest_frames_and_the_skipped_ones_are_never_read():
    seq = _Reads(_ten_hertz(20))
    clock = FakeClock()
    got = []
    for frame, waited in live_frames(seq, range(20), Live(1.0, clock, clock.sleep)):
        got.append(frame.index)
        assert waited == 0.0  # the reading takes no time on this clock, and no frame was waited for
        clock.advance(0.25)  # each frame takes the system 2.5 frame periods
    assert got == [0, 2, 5, 7, 10, 12, 15, 17, 19]
    assert seq.reads == got and clock.slept == []


def test_a_fast_system_gets_every_frame_and_waits_for_each():
    seq = _Reads(_ten_hertz(6))
    clock = FakeClock()
    got = [f.index for f, _ in live_frames(seq, [1, 2, 3, 4, 5], Live(2.0, clock, clock.sleep))
           if clock.advance(0.01) is None]
    assert got == [1, 2, 3, 4, 5]
    assert clock.slept == pytest.approx([0.04] * 4)  # frames 0.05 s apart at twice the rate, 0.01 s of work each
    assert clock.now == pytest.approx(100.0 + 0.2 + 0.01)


def test_frames_out_of_time_order_cannot_come_live():
    seq = _Reads(_ten_hertz(4))
    clock = FakeClock()
    with pytest.raises(CodeSLAMError, match="time order"):
        next(live_frames(seq, [2, 1, 3], Live(1.0, clock, clock.sleep)))
    assert seq.reads == []


def test_a_live_speed_must_be_positive():
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(CodeSLAMError, match="speed"):
            Live(bad)


def test_a_live_run_processes_the_frames_that_arrive_and_tells_the_system_their_period():
    frames = _ten_hertz(12)
    clock = FakeClock()
    system = CodeSLAM(small_config(size=3), _plane_model)
    process = system.process

    def slow(frame):  # each frame takes the system 0.25 s
        clock.advance(0.25)
        return process(frame)

    system.process = slow
    run = run_slam(MemorySequence(frames), system, canonical_camera(32, 24), live=Live(1.0, clock, clock.sleep))
    assert [r.index for r in run.results] == [0, 2, 5, 7, 10, 11]
    assert system.frame_period == pytest.approx(0.1)
    assert run.live == {"speed": 1.0, "frames_offered": 12, "frames_processed": 6, "frames_skipped": 6,
                        "duration_s": pytest.approx(1.1), "offered_fps": pytest.approx(10.0)}
    assert len(run.trajectory.timestamps) == 6


def test_the_system_counts_periods_in_the_period_it_is_told():
    system = CodeSLAM(small_config(size=3), _plane_model)
    system.process(_ten_hertz(1)[0])
    assert np.isnan(system._periods(0.3))  # one frame: no interval to take the period from
    system.frame_period = 0.1
    assert system._periods(0.3) == 3.0 and system._periods(0.04) == 1.0


class _RestartingSystem:
    """What :func:`run_slam` asks of a system, with a readout restart wanted at every frame."""

    camera = canonical_camera(32, 24)
    reads_frame_depth = True
    keyframes: list = []
    merges: list = []
    frame_period = None
    readout_restart = 0.5

    def __init__(self) -> None:
        self.restarts = 0
        self.config = small_config(size=3)

    def tracking_threads(self):
        import contextlib

        return contextlib.nullcontext()

    def process(self, frame):
        self.readout_restart = 0.5 if self.restarts == 0 else None
        return FrameResult(index=frame.index, timestamp=frame.timestamp, T_wc=torch.eye(4), tracking_ok=True,
                           status="tracked", keyframe_id=0, is_keyframe=False)

    def restart_with_readout(self, readout):
        self.restarts += 1

    def finish(self):
        pass

    def close(self):
        pass

    def trajectory(self):
        return None

    keyframe_trajectory = trajectory

    def readout_summary(self):
        return None

    def keyframe_tracking(self):
        return []


def test_a_live_run_never_starts_over():
    frames = _ten_hertz(4)
    offline = _RestartingSystem()
    run_slam(MemorySequence(frames), offline, offline.camera)
    assert offline.restarts == 1  # offline, the frames are fed again with the chosen readout
    clock = FakeClock()
    live = _RestartingSystem()
    run = run_slam(MemorySequence(frames), live, live.camera, live=Live(1.0, clock, clock.sleep))
    assert live.restarts == 0 and [r.index for r in run.results] == [0, 1, 2, 3]


def _plane_model(frame):
    from codeslam.geometry.proximity import depth_to_prox
    from codeslam.sfm.decoder import standin_decoder

    h, w = frame.image.shape[-2:]
    return standin_decoder(depth_to_prox(torch.full((h, w), 3.0, dtype=torch.float64), 1.5), 8, 3, 1.5)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("slam_live")
    assert main(["synth", str(root / "seq"), "--scenes", "1", "--frames", "8", "--seed", "3", "--size", "64x48"]) == 0
    return root / "seq" / "scene_000"


def test_the_realtime_option_runs_live_and_says_so(dataset, tmp_path, capsys):
    out = tmp_path / "out"
    # a thousand times the recording's rate: every frame has come once the first is processed, so the system
    # takes the first and then the last
    rc = main(["slam", str(dataset), "--depth-model", "standin", "--size", "64x48", "--realtime", "--speed",
               "1000", "--out", str(out), "-q", "--threads", "1"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    summary = json.loads((out / "result.json").read_text())
    assert summary["live"]["frames_offered"] == 8 and summary["live"]["frames_processed"] == 2
    assert summary["live"]["frames_skipped"] == 6 and summary["live"]["speed"] == 1000
    assert summary["frames"] == 2 and summary["first_frame"] == 0 and summary["last_frame"] == 7
    assert "2 of 8 frames processed, 6 skipped" in " ".join(captured.out.split())


def test_bad_live_options_fail_with_one_line(dataset, tmp_path, capsys):
    standin = ["--depth-model", "standin", "--size", "64x48", "--out", str(tmp_path / "out"), "-q"]
    for args, words in ((["--speed", "2"], "--realtime"), (["--realtime", "--speed", "0"], "positive"),
                        (["--realtime", "--speed", "nan"], "positive")):
        assert main(["slam", str(dataset), *args, *standin]) != 0
        err = capsys.readouterr().err.strip()
        assert err.startswith("codeslam: error:") and "\n" not in err and words in err, err
    assert not (tmp_path / "out" / "result.json").exists()
