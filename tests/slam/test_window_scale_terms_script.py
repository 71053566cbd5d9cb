"""``scripts/window_scale_terms.py``: which terms of a window solve hold the map's scale."""

from __future__ import annotations

import pytest
import torch
from slam_scene import MemorySequence, small_config, synth_frames

from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import run_slam
from codeslam.slam.system import CodeSLAM


def _windows(free_scale: bool, monkeypatch) -> list:
    """Copies of the window after each of a short run's solves (float64, so that the data terms' derivatives are
    zero to rounding rather than to float32's cancellation in their large gradients)."""
    import copy
    from dataclasses import replace

    import codeslam.slam.window as window_module

    solve, seen = window_module.SlidingWindow.optimise, []

    def optimise(self, *a, **k):
        report = solve(self, *a, **k)
        seen.append(copy.deepcopy(self))
        return report

    monkeypatch.setattr(window_module.SlidingWindow, "optimise", optimise)
    frames = synth_frames(3, 16, 7.5)
    config = small_config(size=3, code_directions=8, free_scale=free_scale, map_prior_weight=0.0,
                          sfm={"geometric_pose_min_std": 0.0})
    system = CodeSLAM(replace(config, dtype="float64"), standin_depth_model(num_levels=3))
    run_slam(MemorySequence(frames), system, frames[0].camera)
    return seen


def test_the_data_terms_are_scale_free_and_the_priors_hold_the_scale(script, monkeypatch):
    wst = script("window_scale_terms")
    windows = [w for w in _windows(True, monkeypatch) if w.prior is not None and len(w) == 3]
    assert windows  # solves after a marginalisation, with a full window
    terms = wst.scale_terms(windows[-1], level=0)
    priors = [terms[n] for n in ("marginal prior", "depth scale priors", "code prior")]
    size = max(abs(g) for g, _ in priors)
    assert size > 1e-3 and min(h for _, h in priors) > 0  # the priors see the scale direction
    for name in ("photometric", "geometric", "keypoints"):  # exactly scale-free
        assert abs(terms[name][0]) < 1e-9 * size, (name, terms[name])
    torch.testing.assert_close(terms["depth scale priors"][1], 3 / small_config().window.depth_scale_sigma ** 2,
                               rtol=1e-4, atol=0)  # three keyframes, d(m_k)/d(s_k) = 1 each


def test_a_window_without_scale_entries_is_refused(script, monkeypatch):
    wst = script("window_scale_terms")
    window = _windows(False, monkeypatch)[-1]
    with pytest.raises(SystemExit, match="no scale entry"):
        wst.scale_terms(window)
