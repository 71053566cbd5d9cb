"""``scripts/keyframe_span.py``: a SLAM run's keyframe scales beside where the network's code span holds each view."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def test_rank_correlation_matches_scipy_with_ties(script):
    stats = pytest.importorskip("scipy.stats")
    ks = script("keyframe_span")
    rng = np.random.default_rng(0)
    x = rng.integers(0, 6, 40).astype(float)  # ties
    y = x + rng.normal(scale=2.0, size=40)
    assert ks.spearman(x, y) == pytest.approx(stats.spearmanr(x, y).correlation, rel=1e-12)
    assert np.isnan(ks.spearman(x[:2], y[:2])) and np.isnan(ks.spearman(np.ones(5), y[:5]))


def test_keyframe_scales_are_medians_over_the_pixels_valid_in_all_three(script):
    ks = script("keyframe_span")
    gt = np.array([[1.0, 2.0], [4.0, 0.0]])
    zero = np.array([[2.0, 4.0], [np.nan, 3.0]])
    final = np.array([[0.5, 1.0], [2.0, 1.0]])
    s = ks.keyframe_scales(final, zero, gt)  # pixels (0, 0) and (0, 1) only
    assert s == {"map_zero": 0.25, "map_true": 0.5, "zero_true": 2.0}
    assert np.isnan(ks.keyframe_scales(final, zero, np.zeros_like(gt))["map_true"])


def test_a_run_is_read_against_the_shipped_networks_span(script, tmp_path, capsys, monkeypatch):
    from codeslam.cli import main as cli
    from codeslam.cli.common import open_frames
    from codeslam.depthmodel import DepthModel

    assert cli(["synth", str(tmp_path / "seq"), "--scenes", "1", "--frames", "4", "--seed", "3",
                "--size", "128x96"]) == 0
    data = tmp_path / "seq" / "scene_000"
    model = DepthModel.load(None)
    seq, _ = open_frames(data, None, None)
    gt = np.stack([model.canonical(seq[i]).depth.numpy() for i in (0, 2, 3)])
    run = tmp_path / "run"  # a run whose map sits at half the truth and whose zero code at 1.2 times it
    run.mkdir()
    np.savez(run / "keyframes.npz", frame_index=np.array([0, 2, 3]), depth=0.5 * gt, depth_zero=1.2 * gt,
             depth_gt=gt)
    (run / "result.json").write_text('{"weights": "default"}')
    ks = script("keyframe_span")
    monkeypatch.syspath_prepend(str(SCRIPTS))  # as when run as a script: depth_prior_eval beside it
    monkeypatch.setattr(sys, "argv", ["keyframe_span.py", str(run), str(data), "--blocks", "2", "--threads", "1"])
    ks.main()
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| 0-") or line.startswith("| 2-")]
    assert len(rows) == 2 and rows[0].startswith("| 0-1 (0-2) | 0.42 |") and rows[1].startswith("| 2-2 (3-3) | 0.42 |")
    assert all(r.split("|")[4].strip() == "0.50" and r.split("|")[6].strip() == "1.20" for r in rows)
    span = [float(r.split("|")[3]) for r in rows]
    assert all(min(ks.SCALES) <= s <= max(ks.SCALES) for s in span)
    assert "3 keyframes" in out and "medians of map / truth and span / truth 0.50" in out
