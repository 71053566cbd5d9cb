"""Side-by-side panels of images, depth maps and uncertainties as PNG (matplotlib, Agg backend), and the
Jacobian colouring of the paper's Fig. 7.

A panel is a grid of :class:`Tile`\\ s. All depth tiles of one panel share one colour range (by default the 2-98
percentiles of their valid depths, so ground truth and predictions compare by colour) and one colour bar; so do
the uncertainty tiles. Invalid depth (0) is drawn black. Every PNG is written atomically.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from codeslam.io import atomic_path

TILE_KINDS = ("rgb", "depth", "uncertainty")
#: percentiles of the valid depths that set a panel's default depth colour range
DEPTH_PERCENTILES = (2.0, 98.0)
#: percentile of the uncertainties that sets a panel's default uncertainty colour maximum
UNCERTAINTY_PERCENTILE = 99.0
DEPTH_CMAP = "viridis"
UNCERTAINTY_CMAP = "magma"


@dataclass(frozen=True)
class Tile:
    """One panel cell.

    Attributes:
        title: text above the tile.
        data: "rgb": (3, H, W) or (H, W, 3) in [0, 1] (a grey (H, W) image is shown in grey);
            "depth": (H, W) metres, 0 = invalid; "uncertainty": (H, W) >= 0.
        kind: one of :data:`TILE_KINDS`.
    """

    title: str
    data: np.ndarray | torch.Tensor
    kind: str = "rgb"

    def __post_init__(self) -> None:
        if self.kind not in TILE_KINDS:
            raise ValueError(f"tile kind must be one of {TILE_KINDS}, got {self.kind!r}")

    def array(self) -> np.ndarray:
        a = self.data.detach().cpu().double().numpy() if isinstance(self.data, torch.Tensor) else np.asarray(
            self.data, dtype=np.float64)
        if self.kind == "rgb" and a.ndim == 3 and a.shape[0] == 3 and a.shape[-1] != 3:
            a = a.transpose(1, 2, 0)  # (3, H, W) -> (H, W, 3)
        return a


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def depth_range(depths: Sequence[np.ndarray | torch.Tensor], percentiles=DEPTH_PERCENTILES) -> tuple[float, float]:
    """The (lo, hi) percentiles of the valid (finite, > 0) values of all ``depths``; (0, 1) when there are none."""
    vals = [np.asarray(torch.as_tensor(d).detach().cpu().double()).ravel() for d in depths]
    v = np.concatenate(vals) if vals else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(v, percentiles)
    return float(lo), float(max(hi, lo + 1e-6))


def signed_overlay(gray: np.ndarray | torch.Tensor, values: np.ndarray | torch.Tensor,
                   scale: float | None = None) -> np.ndarray:
    """Colour a grey image (H, W) in [0, 1] by signed values (H, W) (the paper's Fig. 7): blue where negative,
    red where positive, blended over the image in proportion to ``|value| / scale`` (default: the 99th
    percentile of ``|value|``). -> (H, W, 3) RGB in [0, 1]."""
    g = np.asarray(torch.as_tensor(gray).detach().cpu().double())
    v = np.asarray(torch.as_tensor(values).detach().cpu().double())
    if scale is None:
        scale = float(np.percentile(np.abs(v), 99.0)) or 1.0
    alpha = np.clip(np.abs(v) / scale, 0.0, 1.0)[..., None]  # (H, W, 1)
    red, blue = np.array([0.85, 0.1, 0.1]), np.array([0.1, 0.25, 0.9])
    colour = np.where(v[..., None] >= 0, red, blue)  # (H, W, 3)
    return (1.0 - alpha) * g[..., None] + alpha * colour


def write_panel(
    path: str | os.PathLike,
    rows: Sequence[Sequence[Tile | None]],
    depth_lim: tuple[float, float] | None = None,
    uncertainty_max: float | None = None,
    title: str = "",
    tile_inches: float = 2.6,
    dpi: int = 100,
) -> None:
    """Write a grid of tiles (``None`` leaves a cell empty) as a PNG, with one colour bar for all depth tiles
    (range ``depth_lim``, default from :func:`depth_range`) and one for all uncertainty tiles."""
    plt = _pyplot()
    n_rows = len(rows)
    n_cols = max((len(r) for r in rows), default=0)
    if n_rows == 0 or n_cols == 0:
        raise ValueError("a panel needs at least one tile")
    tiles = [t for r in rows for t in r if t is not None]
    if depth_lim is None:
        depth_lim = depth_range([t.array() for t in tiles if t.kind == "depth"])
    if uncertainty_max is None:
        unc = [t.array().ravel() for t in tiles if t.kind == "uncertainty"]
        u = np.concatenate(unc) if unc else np.zeros(0)
        u = u[np.isfinite(u)]
        uncertainty_max = float(np.percentile(u, UNCERTAINTY_PERCENTILE)) if u.size else 1.0
        uncertainty_max = max(uncertainty_max, 1e-6)
    first = tiles[0].array()
    aspect = first.shape[0] / first.shape[1]
    kinds = {t.kind for t in tiles}
    bars = len(kinds & {"depth", "uncertainty"})
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(tile_inches * n_cols, (tile_inches * aspect + 0.35) * n_rows
                                                      + 0.5 * bars + (0.3 if title else 0.0)),
                             squeeze=False, layout="constrained")
    cmap_depth = plt.get_cmap(DEPTH_CMAP).with_extremes(bad="black")
    try:
        mappables: dict[str, object] = {}
        for r in range(n_rows):
            for c in range(n_cols):
                ax = axes[r][c]
                ax.set_axis_off()
                tile = rows[r][c] if c < len(rows[r]) else None
                if tile is None:
                    continue
                a = tile.array()
                if tile.kind == "rgb":
                    ax.imshow(np.clip(a, 0, 1), cmap="gray" if a.ndim == 2 else None, vmin=0, vmax=1,
                              interpolation="nearest")
                elif tile.kind == "depth":
                    m = np.ma.masked_where(~(np.isfinite(a) & (a > 0)), a)
                    im = ax.imshow(m, cmap=cmap_depth, vmin=depth_lim[0], vmax=depth_lim[1], interpolation="nearest")
                    mappables["depth"] = im
                else:
                    im = ax.imshow(a, cmap=UNCERTAINTY_CMAP, vmin=0.0, vmax=uncertainty_max, interpolation="nearest")
                    mappables["uncertainty"] = im
                ax.set_title(tile.title, fontsize=9)
        labels = {"depth": "depth [m]", "uncertainty": "uncertainty b (proximity)"}
        for kind, mappable in mappables.items():
            # below the whole grid (so every tile keeps its size), one bar per kind
            bar = fig.colorbar(mappable, ax=axes.ravel().tolist(), location="bottom", fraction=0.05 / n_rows,
                               shrink=0.5, aspect=40)
            bar.set_label(labels[kind], fontsize=8)
            bar.ax.tick_params(labelsize=7)
        if title:
            fig.suptitle(title, fontsize=10)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    finally:
        plt.close(fig)
