"""The rolling-shutter readout chosen online (codeslam.slam.readout, tracker.rolling_shutter_estimate)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from slam_scene import rolling_shutter_frames, small_config

from codeslam.slam.depth import standin_depth_model
from codeslam.slam.readout import CANDIDATES, ReadoutChoice, choose
from codeslam.slam.system import CodeSLAM


def test_a_global_shutter_unless_a_candidate_clearly_explains_the_frames_better():
    assert choose([0.10, 0.23, 0.31], 0.03) == 0.0  # every rectification fits worse (the HoloLens walk's kind)
    assert choose([-0.01, -0.02, -0.025], 0.03) == 0.0  # better, but within the margin
    assert choose([-0.1, -0.2, -0.3], 0.03) == CANDIDATES[-1]  # the last candidate: no neighbour beyond it


def test_the_readout_is_the_vertex_of_the_parabola_through_the_best_candidate_and_its_neighbours():
    # a quadratic in the readout s with its minimum at 0.55: the vertex is found exactly
    means = [(s - 0.55) ** 2 - 0.55**2 for s in CANDIDATES]
    assert math.isclose(choose(means, 0.03), 0.55, abs_tol=1e-12)
    # readout 0 (ratio 0) is the first candidate's left neighbour: minimum at 0.3
    means = [(s - 0.3) ** 2 - 0.3**2 for s in CANDIDATES]
    assert math.isclose(choose(means, 0.03), 0.3, abs_tol=1e-12)
    # never more than half a step from the best candidate
    assert choose([-0.5, -0.5001, 10.0], 0.03) >= CANDIDATES[1] - 0.125


def test_the_choice_waits_for_enough_informative_frames():
    choice = ReadoutChoice(frames=3, min_frames=3, min_turn_deg=0.5, margin=0.03)
    assert not choice.informative(torch.tensor([0.0, math.radians(0.4), 0.0], dtype=torch.float64))
    assert choice.informative(torch.tensor([0.0, math.radians(0.6), 0.0], dtype=torch.float64))
    residuals = [0.9, 0.8, 0.85]  # relative to a base of 1.0: readout 0.5 fits best
    choice.add(1.0, residuals, 4)
    choice.add(0.0, residuals, 5)  # no overlap: says nothing
    choice.add(1.0, [0.9, math.nan, 0.85], 6)  # a failed alignment: says nothing
    choice.add(1.0, residuals, 7)
    assert choice.value is None and choice.seen == 2
    choice.add(1.0, residuals, 9)
    assert choice.final and choice.decided_at == 9 and 0.4 < choice.value < 0.6
    assert not choice.informative(torch.tensor([0.0, 0.1, 0.0], dtype=torch.float64))  # decided: no more work
    summary = choice.summary()
    assert summary["readout"] == choice.value and summary["frames"] == 3 and summary["decided_at_frame"] == 9
    assert math.isclose(summary["mean_log_residual_ratio"]["0.5"], math.log(0.8))


def test_a_provisional_choice_is_updated_until_the_choice_is_final():
    choice = ReadoutChoice(frames=4, min_frames=2, margin=0.03)
    turn = torch.tensor([0.0, 0.05, 0.0], dtype=torch.float64)
    choice.add(1.0, [0.9, 0.8, 0.85], 3)
    assert choice.value is None
    choice.add(1.0, [0.9, 0.8, 0.85], 4)
    assert 0.4 < choice.value < 0.6 and not choice.final and choice.informative(turn)
    choice.add(1.0, [1.2, 1.3, 1.4], 5)
    choice.add(1.0, [1.2, 1.3, 1.4], 6)  # the later frames outweigh: a global shutter after all
    assert choice.value == 0.0 and choice.final and choice.decided_at == 6 and not choice.informative(turn)
    choice.add(1.0, [0.1, 0.1, 0.1], 7)  # final: nothing changes it
    assert choice.value == 0.0 and choice.seen == 4


def test_a_global_shutter_is_final_as_soon_as_the_frames_settle_it():
    # Every candidate fits clearly worse, frame after frame (the HoloLens walk's evidence, per-frame log ratios
    # 0.06-0.7): final at min_frames, not after all the frames, and nothing is weighed after it.
    rng = torch.Generator().manual_seed(0)
    worse = [[math.exp(0.1 * (i + 1) + 0.05 * float(torch.randn(1, generator=rng))) for i in range(3)]
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
        spread.add(1.0, [math.exp(0.1 + (0.6 if k % 2 else -0.6))] * 3, k)
    assert not spread.final and spread.value == 0.0
    # A rolling shutter's readout is a value every frame refines: it always takes all the frames.
    rolling = ReadoutChoice(frames=40, min_frames=10, margin=0.03)
    for k in range(39):
        rolling.add(1.0, [0.9, 0.8, 0.85], k)
    assert not rolling.final and 0.4 < rolling.value < 0.6
    rolling.add(1.0, [0.9, 0.8, 0.85], 39)
    assert rolling.final and rolling.decided_at == 39


@pytest.mark.parametrize("readout", [0.5, 0.0])
def test_the_readout_is_found_from_a_turning_cameras_frames(readout):
    """Frames ray-cast row by row while the camera turns (a rolling shutter reading out over half the frame
    interval, or a global shutter): the system finds about 0.5 in the first and 0 in the second; from its
    provisional choice on it rectifies the frames and keyframes by it and weighs the later frames against such
    keyframes."""
    frames = rolling_shutter_frames(readout, frames=12)
    cfg = small_config(size=3)
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, rolling_shutter_estimate=True),
                              features=dataclasses.replace(cfg.features, enabled=False))
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3))
    system.readout_choice = ReadoutChoice(frames=8, min_frames=4)
    results = [system.process(f) for f in frames]
    system.finish()
    choice = system.readout_choice
    assert all(r.tracking_ok for r in results)
    assert choice.decided_at is not None and choice.decided_at < len(frames) - 1
    if readout > 0:
        assert 0.35 <= choice.value <= 0.65
        assert choice.summary()["mean_log_residual_ratio"]["0.5"] < -0.05
        assert any(kf_readout > 0 for _, kf_readout in system._turn.values())  # made under the provisional one
    else:
        assert choice.value == 0.0
        assert all(v > 0.05 for v in choice.summary()["mean_log_residual_ratio"].values())
    assert system.readout == choice.value
    assert system.readout_summary() == choice.summary()
