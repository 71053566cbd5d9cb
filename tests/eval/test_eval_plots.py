"""Evaluation plots: PNGs written atomically."""

from __future__ import annotations

import numpy as np
import pytest

from codeslam.eval.plots import plot_error_vs_distance, plot_trajectories

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_plots_write_png(tmp_path):
    s = np.linspace(0, 6, 50)
    ref = np.stack([np.cos(s), np.sin(s), 0.1 * s], 1)
    est = ref + 0.02
    plot_trajectories(tmp_path / "sub" / "t.png", est, ref, title="test")
    plot_error_vs_distance(tmp_path / "d.png", s, 0.1 * s, label="est")
    for p in (tmp_path / "sub" / "t.png", tmp_path / "d.png"):
        assert p.read_bytes()[:8] == PNG_MAGIC
    assert sorted(x.name for x in tmp_path.rglob("*") if x.is_file()) == ["d.png", "t.png"]


def test_failed_plot_leaves_previous_file(tmp_path, monkeypatch):
    target = tmp_path / "d.png"
    target.write_bytes(b"old")
    import matplotlib.figure

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", boom)
    with pytest.raises(OSError, match="disk full"):
        plot_error_vs_distance(target, np.arange(3.0), np.arange(3.0))
    assert target.read_bytes() == b"old"
    assert [x.name for x in tmp_path.iterdir()] == ["d.png"]
