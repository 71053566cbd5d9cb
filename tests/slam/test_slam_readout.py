"""The rolling-shutter readout chosen online (codeslam.slam.readout, tracker.rolling_shutter_estimate)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from slam_scene import MemorySequence, rolling_shutter_frames, small_config

from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import run_slam
from codeslam.slam.readout import CANDIDATES, ReadoutChoice, choose
from codeslam.slam.system import CodeSLAM


def at(f) -> dict[float, float]:
    """One value per candidate readout, ``f(readout)``."""
    return {c: f(c) for c in CANDIDATES}


HALF = at(lambda c: {0.25: 0.9, 0.5: 0.8, 0.75: 0.85}.get(c, 1.1))  # residuals: readout 0.5 fits best


def test_a_global_shutter_unless_a_candidate_clearly_explains_the_frames_better():
    assert choose(at(lambda c: 0.1 + 0.3 * abs(c)), 0.03) == 0.0  # every rectification fits worse (the walk's kind)
    assert choose(at(lambda c: -0.01 - 0.02 * abs(c)), 0.03) == 0.0  # better, but within the margin
    assert choose(at(lambda c: -0.4 * c), 0.03) == CANDIDATES[-1]  # the last candidate: no neighbour beyond it
    assert choose(at(lambda c: 0.4 * c), 0.03) == CANDIDATES[0]  # rows read bottom up: the first


@pytest.mark.parametrize("sign", [1, -1])  # rows read top down, or bottom up (a camera upside down)
def test_the_readout_is_the_vertex_of_the_parabola_through_the_best_candidate_and_its_neighbours(sign):
    # a quadratic in the readout s with its minimum at 0.55: the vertex is found exactly
    means = at(lambda s: (s - sign * 0.55) ** 2 - 0.55**2)
    assert math.isclose(choose(means, 0.03), sign * 0.55, abs_tol=1e-12)
    # readout 0 (ratio 0) is the neighbour of the two candidates nearest it: minimum at 0.3
    means = at(lambda s: (s - sign * 0.3) ** 2 - 0.3**2)
    assert math.isclose(choose(means, 0.03), sign * 0.3, abs_tol=1e-12)
    # never more than half a step from the best candidate
    assert 0.375 <= choose(at(lambda c: {0.25: -0.5, 0.5: -0.5001, 0.75: 10.0}.get(c, 1.0)), 0.03) < 0.5


def test_the_choice_waits_for_enough_informative_frames():
    choice = ReadoutChoice(frames=3, min_frames=3, min_turn_deg=0.5, margin=0.03)
    assert not choice.informative(torch.tensor([0.0, math.radians(0.4), 0.0], dtype=torch.float64))
    assert choice.informative(torch.tensor([0.0, math.radians(0.6), 0.0], dtype=torch.float64))
    residuals = HALF  # relative to a base of 1.0: readout 0.5 fits best
    choice.add(1.0, residuals, 4)
    choice.add(0.0, residuals, 5)  # no overlap: says nothing
    failed = {**HALF, 0.5: math.nan}
    choice.add(1.0, failed, 6)  # a failed alignment: says nothing
    choice.add(1.0, residuals, 7)
    assert choice.value is None and choice.seen == 2
    choice.add(1.0, residuals, 9)
    assert choice.final and choice.decided_at == 9 and 0.4 < choice.value < 0.6
    assert not choice.informative(torch.tensor([0.0, 0.1, 0.0], dtype=torch.float64))  # decided: no more work
    summary = choice.summary()
    assert summary["readout"] == choice.value and summary["frames"] == 3 and summary["decided_at_frame"] == 9
    assert math.isclose(summary["mean_log_residual_ratio"]["0.5"], math.log(0.8))


def test_after_min_frames_only_the_direction_that_fits_better_is_weighed():
    # rows read bottom up (a camera upside down): the negative side fits, -0.5 best
    upside_down = at(lambda c: {-0.25: 0.9, -0.5: 0.8, -0.75: 0.85}.get(c, 1.2))
    choice = ReadoutChoice(frames=6, min_frames=3, margin=0.03)
    assert choice.candidates == CANDIDATES
    for k in range(3):
        choice.add(1.0, upside_down, k)
    assert choice.side == -1 and choice.candidates == (-0.75, -0.5, -0.25) and -0.6 < choice.value < -0.4
    choice.add(1.0, {c: r for c, r in upside_down.items() if c < 0}, 3)  # the other side's are not needed now
    assert choice.seen == 4 and choice.count == [4, 4, 4, 3, 3, 3]
    summary = choice.summary()["mean_log_residual_ratio"]
    assert math.isclose(summary["-0.5"], math.log(0.8)) and math.isclose(summary["0.5"], math.log(1.2))
    # the same frames read top down: the positive side, the readout mirrored
    mirrored = ReadoutChoice(frames=6, min_frames=3, margin=0.03)
    for k in range(4):
        mirrored.add(1.0, {-c: r for c, r in upside_down.items()}, k)
    assert mirrored.side == 1 and math.isclose(mirrored.value, -choice.value)


def test_both_directions_are_weighed_until_the_frames_tell_them_apart():
    # TUM fr1/rpy started at frame 15 (fifty-eighth session): over the first ten frames the top-down candidates
    # fit better or worse frame by frame, the bottom-up ones a little worse throughout, and the two sides' best
    # means differ by little. Kept on that, the bottom-up side then settled as a global shutter.
    def early(k: int, c: float) -> float:
        return (1.2 if k % 2 else -1.0) * c if c > 0 else 0.08 * abs(c) * (1.5 if k % 2 else 0.5)

    choice = ReadoutChoice(frames=40, min_frames=10, margin=0.03)
    for k in range(10):
        choice.add(1.0, at(lambda c, k=k: math.exp(early(k, c))), k)
    means = choice.means()
    assert means[-0.25] < means[0.25]  # the bottom-up side's best leads on its mean alone (0.020 against 0.025)
    assert choice.side == 0 and choice.candidates == CANDIDATES and not choice.final
    # then frames where the camera turns fast: the top-down readouts fit clearly better, and that side is kept
    for k in range(10, 30):
        choice.add(1.0, at(lambda c: math.exp(-0.8 * c if c > 0 else 0.4 * abs(c))), k)
    assert choice.side == 1 and choice.candidates == (0.25, 0.5, 0.75) and choice.value > 0.5 and not choice.final


def test_a_provisional_choice_is_updated_until_the_choice_is_final():
    choice = ReadoutChoice(frames=4, min_frames=2, margin=0.03)
    turn = torch.tensor([0.0, 0.05, 0.0], dtype=torch.float64)
    choice.add(1.0, HALF, 3)
    assert choice.value is None
    choice.add(1.0, HALF, 4)
    assert 0.4 < choice.value < 0.6 and not choice.final and choice.informative(turn)
    choice.add(1.0, at(lambda c: 1.2 + 0.2 * abs(c)), 5)
    choice.add(1.0, at(lambda c: 1.2 + 0.2 * abs(c)), 6)  # the later frames outweigh: a global shutter after all
    assert choice.value == 0.0 and choice.final and choice.decided_at == 6 and not choice.informative(turn)
    choice.add(1.0, at(lambda c: 0.1), 7)  # final: nothing changes it
    assert choice.value == 0.0 and choice.seen == 4


def test_a_global_shutter_is_final_as_soon_as_the_frames_settle_it():
    # Every candidate fits clearly worse, frame after frame (the HoloLens walk's evidence, per-frame log ratios
    # 0.06-0.7): final at min_frames, not after all the frames, and nothing is weighed after it.
    rng = torch.Generator().manual_seed(0)
    worse = [at(lambda c: math.exp(0.1 + 0.4 * abs(c) + 0.05 * float(torch.randn(1, generator=rng))))
             for _ in range(12)]
    choice = ReadoutChoice(frames=40, min_frames=10, margin=0.03)
    for k, r in enumerate(worse[:9]):
        choice.add(1.0, r, k)
    assert choice.seen == 9 and not choice.final and choice.value is None
    choice.add(1.0, worse[9], 9)
    assert choice.final and choice.value == 0.0 and choice.decided_at == 9 and choice.seen == 10
    assert not choice.informative(torch.tensor([0.0, 0.1, 0.0], dtype=torch.float64))
    # Evidence as worse on average but spread so wide that the mean is not sure to stay above -margin: it waits.
    spread = ReadoutChoice(frames=40, min_frames=10, margin=0.03)
    for k in range(20):
        spread.add(1.0, dict.fromkeys(CANDIDATES, math.exp(0.1 + (0.6 if k % 2 else -0.6))), k)
    assert not spread.final and spread.value == 0.0
    # A rolling shutter's readout is a value every frame refines: it always takes all the frames.
    rolling = ReadoutChoice(frames=40, min_frames=10, margin=0.03)
    for k in range(39):
        rolling.add(1.0, HALF, k)
    assert not rolling.final and 0.4 < rolling.value < 0.6
    rolling.add(1.0, HALF, 39)
    assert rolling.final and rolling.decided_at == 39


def _choosing_system(parallel: bool = False, **tracker) -> CodeSLAM:
    """A small system without keypoints that chooses the readout from 4 informative frames, finally after 8."""
    cfg = small_config(size=3)
    tracker = {"rolling_shutter_estimate": True} | tracker
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, **tracker),
                              features=dataclasses.replace(cfg.features, enabled=False))
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3), parallel=parallel)
    if system.readout_choice is not None:
        system.readout_choice = ReadoutChoice(frames=8, min_frames=4)
    return system


@pytest.mark.parametrize("readout, axis", [(0.5, "rows"), (-0.5, "rows"), (0.5, "columns"), (0.0, "rows")])
def test_the_readout_is_found_from_a_turning_cameras_frames(readout, axis):
    """Frames ray-cast row by row while the camera turns (a rolling shutter reading out over half the frame
    interval, its rows top down or bottom up as in a camera upside down, or along the columns as in a portrait
    video; or a global shutter): the system finds about 0.5, -0.5, 0.5 and 0; from its provisional choice on it
    rectifies the frames and keyframes by it and weighs the later frames against such keyframes."""
    frames = rolling_shutter_frames(readout, frames=12, axis=axis)
    system = _choosing_system()
    results = [system.process(f) for f in frames]
    system.finish()
    choice = system.readout_choice
    assert all(r.tracking_ok for r in results)
    assert choice.decided_at is not None and choice.decided_at < len(frames) - 1
    if readout:
        assert 0.35 <= readout / abs(readout) * choice.value <= 0.65
        assert choice.summary()["mean_log_residual_ratio"][str(readout)] < -0.05
        assert any(kf_readout * readout > 0 for _, kf_readout in system._turn.values())  # under the provisional one
    else:
        assert choice.value == 0.0
        assert all(v > 0.05 for v in choice.summary()["mean_log_residual_ratio"].values())
    assert system.readout == choice.value
    assert system.readout_summary() == choice.summary()


def test_a_portrait_videos_readout_is_found_only_along_the_axis_its_frames_name():
    """The same column-read frames marked as row-read (what a portrait video's frames said before the reader
    named the axis): no row readout explains them, and the choice is a global shutter."""
    frames = [dataclasses.replace(f, readout_axis="rows") for f in rolling_shutter_frames(0.5, frames=12,
                                                                                             axis="columns")]
    system = _choosing_system()
    for f in frames:
        system.process(f)
    system.finish()
    assert system.readout_choice.value == 0.0


def test_a_keyframes_depth_given_later_is_rectified_along_its_frames_axis():
    """A run that reads no depth gives the keyframes the dataset's depth afterwards (``keyframe_depth``): it must
    be rectified as the keyframe's image was, along the columns for a portrait video's frames, as the depth read
    with the frame was (``depth_gt``)."""
    frames = rolling_shutter_frames(0.5, frames=12, axis="columns")
    system = _choosing_system()
    for f in frames:
        system.process(f)
    system.finish()
    rectified = [kf for kf in system.keyframes if kf.rectified_by is not None]
    assert rectified and all(kf.readout_axis == "columns" for kf in system.keyframes)
    for kf in rectified:
        assert torch.equal(system.keyframe_depth(kf, frames[kf.frame_index].depth), kf.depth_gt)


@pytest.mark.parametrize("readout", [0.5, 0.0])
def test_a_run_starts_over_with_the_readout_once_it_is_chosen(readout):
    """The frames before the choice was final were rectified by 0, then by provisional values: run_slam feeds every
    frame again to the system made anew with the chosen readout, and the run is the one that readout set by hand
    gives, pose for pose. A global shutter rectified no frame: no second pass. ``rolling_shutter_restart: 0``: none."""
    frames = rolling_shutter_frames(readout, frames=12)
    seq = MemorySequence(frames)
    system = _choosing_system()
    run = run_slam(seq, system, frames[0].camera)
    chosen = system.readout_summary()
    assert len(run.results) == len(frames) and chosen["decided_at_frame"] is not None
    if not readout:  # decided as a global shutter, every frame rectified by 0 meanwhile
        assert chosen["readout"] == 0.0 and "restarted_after_frames" not in chosen
        return
    value = chosen["readout"]
    assert 0.35 <= value <= 0.65
    assert chosen["restarted_after_frames"] == chosen["decided_at_frame"] + 1
    assert system.readout == value and system.readout_choice is None and system.readout_restart is None
    by_hand = _choosing_system(rolling_shutter_estimate=False, rolling_shutter_readout=value)
    fixed = run_slam(MemorySequence(frames), by_hand, frames[0].camera)
    assert torch.equal(run.trajectory.poses, fixed.trajectory.poses)
    assert [r.status for r in run.results] == [r.status for r in fixed.results]
    never = run_slam(MemorySequence(frames), _choosing_system(rolling_shutter_restart=0), frames[0].camera)
    assert "restarted_after_frames" not in never.readout
    assert not torch.equal(never.trajectory.poses, fixed.trajectory.poses)  # its first frames under other readouts


def test_the_parallel_mode_starts_over_too():
    """Its first frames, tracked under provisional readouts, are processed again with the chosen one, as in the
    sequential mode (TUM fr1/rpy from frame 15 in parallel: 2.05-2.19 deg without, 1.22-1.35 deg with it); the
    mapping thread of the first pass is stopped and a new one runs the second."""
    frames = rolling_shutter_frames(0.5, frames=12)
    run = run_slam(MemorySequence(frames), _choosing_system(parallel=True), frames[0].camera)
    assert run.readout["decided_at_frame"] is not None and run.readout["readout"] > 0.3
    assert run.readout["restarted_after_frames"] >= 4 and len(run.results) == len(frames)
    assert [r.index for r in run.results] == [f.index for f in frames]
