"""The paper's Fig. 5: one image passed through encoding and decoding.

Panel (as the paper's 3 x 2 layout): input image | ground truth; zero code (image-only prediction) | encoded depth
(the encoder's code of the ground truth); uncertainty b | optimised depth (the code fitted to the ground truth by
Gauss-Newton with the decoder Jacobian). Titles carry each depth's proximity RMSE against the ground truth.

Usage::

    python scripts/fig5_encode_decode.py DATASET --frame K [--weights FILE] [--out fig5.png]

e.g. ``python scripts/fig5_encode_decode.py ../shared/data/tum_fr1_rpy --frame 40 --out fig5_tum.png``.
The default weights are the shipped ones; the dataset needs ground-truth depth.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from codeslam.data.registry import open_dataset
from codeslam.depthmodel import DepthModel, predict_depth
from codeslam.errors import CodeSLAMError
from codeslam.recon.metrics import prox_rmse
from codeslam.recon.panels import Tile, depth_range, write_panel


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--frame", type=int, default=0, help="frame index in the dataset")
    ap.add_argument("--weights", type=Path, default=None, help="network weights (default: the shipped weights)")
    ap.add_argument("--out", type=Path, default=Path("fig5_encode_decode.png"))
    args = ap.parse_args(argv)
    try:
        seq = open_dataset(args.dataset)
        if not 0 <= args.frame < len(seq):
            raise CodeSLAMError(f"--frame {args.frame} is outside the sequence of {len(seq)} frames")
        model = DepthModel.load(args.weights)
        frame = model.canonical(seq[args.frame])
        if frame.depth is None:
            raise CodeSLAMError(f"{args.dataset} has no ground-truth depth")
        pred = predict_depth(model, [frame], ["zero", "encode", "optimise"])[0]
    except CodeSLAMError as e:
        print(f"fig5: error: {e}")
        return 2
    gt_prox = model.target_prox(frame.depth)
    a = model.avg_depth

    def depth_tile(name: str, mode: str) -> Tile:
        r = prox_rmse(pred.prox[mode], gt_prox, frame.depth)
        return Tile(f"{name} (RMSE {r:.3f})", pred.depth(mode, a), "depth")

    rows = [
        [Tile("input image", frame.image), Tile("ground truth", frame.depth, "depth")],
        [depth_tile("zero code", "zero"), depth_tile("encoded", "encode")],
        [Tile("uncertainty b", pred.uncertainty, "uncertainty"), depth_tile("optimised", "optimise")],
    ]
    write_panel(args.out, rows, depth_lim=depth_range([frame.depth]),
                title=f"{args.dataset.name} frame {args.frame}, code size {model.code_size}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
