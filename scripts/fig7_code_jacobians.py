"""The paper's Fig. 7: the influence of single code entries on the decoded depth.

For each of two images (rows) and three code entries (columns), the Jacobian of the decoded proximity with respect to
that entry, ``dD/dc_k`` (one column of the code Jacobian, computed by one batched forward pass), colours the grey
input image: red where increasing the entry brings the surface closer (positive proximity change), blue where it
pushes it away. Each entry's colour scale is shared by both images so that its regions of influence compare.

Usage::

    python scripts/fig7_code_jacobians.py DATASET --frames K1,K2 [--entries 0,1,2] [--weights FILE] [--out fig7.png]

e.g. ``python scripts/fig7_code_jacobians.py ../shared/data/tum_fr1_rpy --frames 20,30 --out fig7_tum.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from codeslam.data.registry import open_dataset
from codeslam.depthmodel import DepthModel
from codeslam.errors import CodeSLAMError
from codeslam.geometry.image import rgb_to_gray
from codeslam.recon.panels import Tile, signed_overlay, write_panel


def _ints(text: str) -> list[int]:
    return [int(t) for t in text.split(",") if t.strip()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--frames", type=_ints, default=[0, 1], help="two frame indices, e.g. 20,30")
    ap.add_argument("--entries", type=_ints, default=[0, 1, 2], help="code entries (columns), e.g. 0,1,2")
    ap.add_argument("--weights", type=Path, default=None, help="network weights (default: the shipped weights)")
    ap.add_argument("--out", type=Path, default=Path("fig7_code_jacobians.png"))
    args = ap.parse_args(argv)
    try:
        seq = open_dataset(args.dataset)
        bad = [i for i in args.frames if not 0 <= i < len(seq)]
        if bad:
            raise CodeSLAMError(f"frame {bad[0]} is outside the sequence of {len(seq)} frames")
        model = DepthModel.load(args.weights)
        bad = [k for k in args.entries if not 0 <= k < model.code_size]
        if bad:
            raise CodeSLAMError(f"code entry {bad[0]} is outside the code of size {model.code_size}")
        frames = [model.canonical(seq[i]) for i in args.frames]
        images = torch.stack([f.image for f in frames])
        jac = torch.stack([d.levels[0].jac.cpu() for d in model.linear_decoders(model.features(images))])
    except CodeSLAMError as e:
        print(f"fig7: error: {e}")
        return 2
    gray = rgb_to_gray(images)[:, 0]  # (F, H, W)
    rows = [[] for _ in frames]
    for k in args.entries:
        scale = float(np.percentile(jac[:, k].abs().numpy(), 99.0)) or 1.0  # shared by the images
        for r, f in enumerate(frames):
            rows[r].append(Tile(f"frame {f.index}, entry {k + 1}", signed_overlay(gray[r], jac[r, k], scale)))
    write_panel(args.out, rows, title="dD/dc_k: red = closer, blue = farther")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
