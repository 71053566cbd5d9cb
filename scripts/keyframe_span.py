"""Does a SLAM map's scale follow where the network's code span holds each view? (issues 11 and 13)

For every keyframe of a ``codeslam slam`` run (its ``keyframes.npz``) the frame is decoded again with the run's
weights and its span scale is read (``depth_prior_eval.span_fit``, on a grid of 0.05): the scale, relative to the
zero code's, at which the linear decoder ``prox0 + J c`` fits the frame's true depth best after its own median.
Beside it, what the run made of that keyframe: its final depth over its zero-code depth, and both over the truth
(medians over the valid pixels), and the span scale times the zero code's: the depth, over the truth, at which the
span holds that view. The window fits codes to images, which fix a view's shape and not its scale; if the map's
scale keyframe by keyframe follows where the span holds each view, the map's scale drift (``result.json``:
``scale_drift``) is the network's span moving from view to view, not the tracker.

Measured (docs/results/slam_table.md, twenty-third session; medians over the keyframes of map / truth and
span / truth, and the rank correlation of the two over the keyframes): walk 42 0.50 / 0.51, 0.53; walk 51
0.38 / 0.46, 0.51; walk 54 0.50 / 0.50, 0.18; walk 43 0.52 / 0.52, 0.56; walk 56 0.46 / 0.45, 0.86; the corridor
preset 0.50 / 0.65, 0.35. (Map / zero code against span scale is not compared: both are divided by the zero code's
depth and share its swings.)

    python scripts/keyframe_span.py RUN DATA [--blocks 8] [--threads 2]

RUN: a ``codeslam slam`` output folder (keyframes.npz, result.json: its weights are used); DATA: the dataset it
ran on, with ground-truth depth.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

#: The span scales tried per keyframe: finer than depth_prior_eval's set grid, to follow a run keyframe by keyframe.
SCALES = tuple(float(s) for s in np.round(np.arange(0.25, 3.001, 0.05), 2))


def ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 0..n-1 of x, ties sharing their mean rank (what Spearman's rho correlates)."""
    x = np.asarray(x, dtype=np.float64)
    order = np.argsort(x, kind="stable")
    r = np.empty(len(x))
    r[order] = np.arange(len(x))
    for v in np.unique(x):  # ties: the mean of their ranks
        same = x == v
        r[same] = r[same].mean()
    return r


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation of x and y (NaN with fewer than 3 pairs or a constant one)."""
    if len(x) < 3:
        return float("nan")
    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def correlation(rows: list[dict], a: str, b: str) -> float:
    """Spearman's rho of two columns over the rows where both are finite."""
    x, y = np.array([r[a] for r in rows]), np.array([r[b] for r in rows])
    ok = np.isfinite(x) & np.isfinite(y)
    return spearman(x[ok], y[ok])


def keyframe_scales(depth: np.ndarray, depth_zero: np.ndarray, depth_gt: np.ndarray) -> dict[str, float]:
    """One keyframe's (H, W) final, zero-code and true depth (0 or non-finite = invalid) -> medians of
    ``map_zero`` (final / zero code), ``map_true`` and ``zero_true`` over the pixels valid in all three."""
    ok = np.isfinite(depth) & np.isfinite(depth_zero) & np.isfinite(depth_gt) & (depth > 0) & (depth_zero > 0) & (
        depth_gt > 0)
    if not ok.any():
        return {"map_zero": float("nan"), "map_true": float("nan"), "zero_true": float("nan")}
    d, z, t = depth[ok], depth_zero[ok], depth_gt[ok]
    return {"map_zero": float(np.median(d / z)), "map_true": float(np.median(d / t)),
            "zero_true": float(np.median(z / t))}


def block_table(rows: list[dict], blocks: int) -> list[str]:
    """Markdown lines: the keyframes in ``blocks`` groups in run order, medians of each column per group."""
    n = len(rows)
    size = max(1, -(-n // blocks))
    out = ["| keyframes (frames) | map / zero code | span scale | map / truth | span / truth | zero code / truth |",
           "|---" * 6 + "|"]
    for a in range(0, n, size):
        g = rows[a:a + size]

        def med(key, g=g):
            return float(np.nanmedian([r[key] for r in g]))

        out.append(f"| {a}-{a + len(g) - 1} ({g[0]['frame']}-{g[-1]['frame']}) | {med('map_zero'):.2f} | "
                   f"{med('span_scale'):.2f} | {med('map_true'):.2f} | {med('span_true'):.2f} | "
                   f"{med('zero_true'):.2f} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path, help="a codeslam slam output folder")
    ap.add_argument("data", type=Path, help="the dataset it ran on (with ground-truth depth)")
    ap.add_argument("--blocks", type=int, default=8, help="groups of keyframes in the table")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from depth_prior_eval import span_fit  # this folder's script: on sys.path when run as a script

    from codeslam.cli.common import open_frames
    from codeslam.depthmodel import DepthModel

    kf = np.load(args.run / "keyframes.npz")
    weights = json.loads((args.run / "result.json").read_text()).get("weights", "default")
    model = DepthModel.load(None if weights in (None, "default") else weights)
    seq, _ = open_frames(args.data, None, None)
    rows = []
    for k, index in enumerate(kf["frame_index"]):
        frame = model.canonical(seq[int(index)])
        if frame.depth is None:
            raise SystemExit(f"{args.data}: frame {int(index)} has no ground-truth depth")
        level = model.linear_decoders(model.features(frame.image[None]))[0].levels[0]
        fit = span_fit(level.prox0.cpu(), level.jac.cpu(), frame.depth.cpu(), model.avg_depth, scales=SCALES)
        row = {"frame": int(index), "span_scale": min(fit, key=fit.get),
               **keyframe_scales(kf["depth"][k], kf["depth_zero"][k], kf["depth_gt"][k])}
        row["span_true"] = row["span_scale"] * row["zero_true"]  # where the span holds the view, over the truth
        rows.append(row)
    print("\n".join(block_table(rows, args.blocks)))
    print(f"\n{len(rows)} keyframes; rank correlation over them of map / truth with span / truth "
          f"{correlation(rows, 'map_true', 'span_true'):.2f}, with zero code / truth "
          f"{correlation(rows, 'map_true', 'zero_true'):.2f}; medians of map / truth and span / truth "
          f"{np.nanmedian([r['map_true'] for r in rows]):.2f} and {np.nanmedian([r['span_true'] for r in rows]):.2f}")


if __name__ == "__main__":
    main()
