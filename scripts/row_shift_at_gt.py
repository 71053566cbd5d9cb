"""How well do two frames align at their ground-truth poses and depth? The residual image shift per band of rows.

For each pair (A, B), every pixel of A with ground-truth depth is warped into B with the ground-truth relative
pose (the same warp as SfM, Eq. 5, at the network's canonical camera), and for each horizontal band of rows the
2-D shift of B's image that best aligns the band (mean absolute grey difference, bias removed, grid search) is
reported. A perfect global-shutter camera with exact poses gives zero everywhere. A shift that is the same in every
band points to a pose or time-stamp error; a shift that changes linearly from the top band to the bottom one is
the signature of a rolling shutter (each row exposed at a different time while the camera turns).

Usage::

    python scripts/row_shift_at_gt.py ../shared/data/tum_fr1_rpy --pairs 18:22,72:76,150:154,162:166
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from codeslam.data.registry import open_dataset
from codeslam.depthmodel import DepthModel
from codeslam.errors import CodeSLAMError
from codeslam.geometry.image import bilinear_sample, rgb_to_gray
from codeslam.sfm.warp import relative_pose, warp


def _pairs(text: str) -> list[tuple[int, int]]:
    try:
        return [tuple(int(v) for v in p.split(":")) for p in text.split(",") if p.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B,A:B,..., got {text!r}") from None


def band_shifts(model: DepthModel, seq, a: int, b: int, bands: int, max_shift: float, step: float) -> dict:
    """-> {"mean_flow_px", "shifts": [(dx, dy) per band, top first]} at the canonical resolution."""
    fa, fb = model.canonical(seq[a]), model.canonical(seq[b])
    if fa.depth is None or fa.pose is None or fb.pose is None:
        raise CodeSLAMError(f"frames {a} and {b} need ground-truth depth and poses")
    H, W = fa.depth.shape
    cam = model.camera
    params = torch.tensor([[cam.fx, cam.fy, cam.cx, cam.cy]], dtype=torch.float64)[:, None]
    gray_a = rgb_to_gray(fa.image[None].double())[0, 0].reshape(1, -1)
    gray_b = rgb_to_gray(fb.image[None].double())[:, :1]
    rows, cols = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64),
                                indexing="ij")
    uv = torch.stack([cols, rows], -1).reshape(1, -1, 2)
    depth = fa.depth.double().reshape(1, -1)
    v, _, _ = warp(uv, depth, relative_pose(fa.pose.double()[None], fb.pose.double()[None]), params, params)
    margin = max_shift + 1
    ok = (depth > 0) & (v[..., 0] > margin) & (v[..., 0] < W - 1 - margin) & (v[..., 1] > margin) & (
        v[..., 1] < H - 1 - margin)
    grid = np.arange(-max_shift, max_shift + 1e-9, step)
    band_masks = [ok & (uv[..., 1] >= k * H / bands) & (uv[..., 1] < (k + 1) * H / bands) for k in range(bands)]
    band_masks = [m if int(m.sum()) >= 20 else None for m in band_masks]  # too few pixels to align: stays NaN
    best = [(float("inf"), float("nan"), float("nan"))] * bands
    for dx in grid:
        for dy in grid:
            sampled, _ = bilinear_sample(gray_b, v + v.new_tensor([dx, dy]))  # one lookup serves every band
            r_all = gray_a - sampled[:, 0]
            for k, in_band in enumerate(band_masks):
                if in_band is None:
                    continue
                r = r_all[in_band]
                cost = float((r - r.mean()).abs().mean())
                if cost < best[k][0]:
                    best[k] = (cost, float(dx), float(dy))
    shifts = [b[1:] for b in best]
    return {"mean_flow_px": float((v - uv).norm(dim=-1)[ok].mean()), "shifts": shifts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--pairs", type=_pairs, required=True, help="A:B frame index pairs, comma separated")
    ap.add_argument("--bands", type=int, default=6, help="horizontal bands of rows")
    ap.add_argument("--max-shift", type=float, default=3.0, help="search range in pixels")
    ap.add_argument("--step", type=float, default=0.25, help="search step in pixels")
    ap.add_argument("--weights", type=Path, default=None, help="network weights (only its canonical camera is used)")
    args = ap.parse_args(argv)
    try:
        model = DepthModel.load(args.weights)
        seq = open_dataset(args.dataset)
        print(f"canonical camera {model.camera.width}x{model.camera.height}; shifts (dx, dy) in pixels, top band first")
        for a, b in args.pairs:
            r = band_shifts(model, seq, a, b, args.bands, args.max_shift, args.step)
            print(f"{a}->{b}: mean flow {r['mean_flow_px']:.1f} px; "
                  + " ".join(f"({dx:+.2f}, {dy:+.2f})" for dx, dy in r["shifts"]), flush=True)
    except CodeSLAMError as e:
        print(f"row_shift_at_gt: error: {e}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
