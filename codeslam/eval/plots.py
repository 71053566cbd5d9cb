"""Evaluation plots (tools layer): trajectories seen from above and error against travelled distance.

matplotlib is imported inside the functions with the non-interactive Agg backend, so importing this module
is cheap and never opens a window; every PNG is written atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from codeslam.io import atomic_path


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path, dpi: int) -> None:
    plt = _pyplot()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    finally:
        plt.close(fig)


def plot_trajectories(
    path: str | Path,
    est_xyz: np.ndarray,
    ref_xyz: np.ndarray,
    title: str = "",
    est_label: str = "estimate",
    ref_label: str = "reference",
    dpi: int = 120,
) -> None:
    """Write a PNG with two top views, x-y and x-z, of the (aligned) estimate against the reference.

    Args:
        est_xyz: (N, 3) estimated positions already in the reference's frame (e.g. ``ATEResult.est_xyz``).
        ref_xyz: (M, 3) reference positions.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, (a, b) in zip(axes, [(0, 1), (0, 2)], strict=True):
        ax.plot(ref_xyz[:, a], ref_xyz[:, b], "-", color="0.3", lw=1.5, label=ref_label)
        ax.plot(est_xyz[:, a], est_xyz[:, b], "-", color="tab:blue", lw=1.0, label=est_label)
        ax.plot(ref_xyz[:1, a], ref_xyz[:1, b], "o", color="0.3", ms=5)
        ax.plot(est_xyz[:1, a], est_xyz[:1, b], "o", color="tab:blue", ms=4)
        ax.set_xlabel(f"{'xyz'[a]} [m]")
        ax.set_ylabel(f"{'xyz'[b]} [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best")
    if title:
        fig.suptitle(title)
    _save(fig, path, dpi)


def plot_error_vs_distance(
    path: str | Path,
    distances: np.ndarray,
    errors: np.ndarray,
    title: str = "Translation error versus travelled distance",
    label: str = "",
    dpi: int = 120,
) -> None:
    """Write a PNG of translation error (m) against travelled ground-truth distance (m), as the paper's
    Fig. 9 (EuRoC MH02). ``distances`` and ``errors`` are (N,) arrays, e.g. from
    :func:`codeslam.eval.metrics.drift_vs_distance`."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(distances, errors, "-", color="tab:red", lw=1.2, label=label or None)
    ax.set_xlabel("travelled distance [m]")
    ax.set_ylabel("translation error [m]")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    if label:
        ax.legend(loc="best")
    if title:
        ax.set_title(title)
    _save(fig, path, dpi)
