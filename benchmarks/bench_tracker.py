"""Speed of per-frame photometric tracking (issue 12): the dedicated 8-variable solver against the generic two-frame
SfM problem it replaces, in one run on the same frames.

Frames ``first + 1 .. first + frames`` of a sequence (by default TUM fr1/rpy, frames 1..60) are each tracked against
the keyframe ``every`` frames before or less (frames 1-10 against frame 0, 11-20 against frame 10, ...), with the
shipped network's depth at the zero code, at the network's 128x96 camera. Each frame starts from the previous
frame's pose (the generic path's, so that both paths start from the same pose; the identity after a keyframe)
and the two paths alternate frame by frame, so that both see the same load. The dedicated path's time includes
building the keyframe's cached data on the first frame after each keyframe.

Prints the median and mean ms per frame of each path and their ratio, and the largest differences between the
two: rotation (radians), translation relative to the keyframe's median depth, cost (relative), and how many
frames differ in iterations or in the ok flag. Nothing is asserted.

    python benchmarks/bench_tracker.py [--dataset DIR] [--frames 60] [--every 10] [--first 0] [--threads 1]
                                       [--weights W] [--repeats 1]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch

from codeslam.cli.common import keep_freed_memory
from codeslam.geometry.image import rgb_to_gray
from codeslam.geometry.lie import se3_inverse, se3_log
from codeslam.slam.config import SLAMConfig
from codeslam.slam.tracker import SOLVERS, PhotometricTracker

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default=str(REPO.parent / "shared" / "data" / "tum_fr1_rpy"))
    ap.add_argument("--first", type=int, default=0, help="the first keyframe")
    ap.add_argument("--frames", type=int, default=60, help="frames tracked after the first keyframe")
    ap.add_argument("--every", type=int, default=10, help="a keyframe every this many frames")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--weights", default=None, help="network weights (default: the shipped ones)")
    ap.add_argument("--repeats", type=int, default=1, help="track every frame this many times per path")
    a = ap.parse_args()
    keep_freed_memory()  # as the codeslam command does at its start
    torch.set_num_threads(a.threads)

    from codeslam.data.registry import open_dataset
    from codeslam.depthmodel import DepthModel

    seq = open_dataset(a.dataset)
    model = DepthModel.load(a.weights)
    cfg = SLAMConfig()
    trackers = {s: PhotometricTracker(cfg.tracker, cfg.window.sfm, solver=s) for s in SOLVERS}
    ms: dict[str, list[float]] = {s: [] for s in SOLVERS}
    diff = {"rot": 0.0, "trans": 0.0, "cost": 0.0, "iterations": 0, "ok": 0, "failed": 0}
    kf = code = depth = kf_index = None
    T_prev = torch.eye(4, dtype=torch.float64)
    last = min(len(seq) - 1, a.first + a.frames)
    for i in range(a.first + 1, last + 1):
        k = a.first + (i - 1 - a.first) // a.every * a.every  # the keyframe of frame i
        if k != kf_index:
            kf_index = k
            kf = model.keyframe(model.canonical(seq[k]))
            code = torch.zeros(kf.decoder.code_size, dtype=kf.decoder.levels[0].jac.dtype)
            depth = float(kf.decoder.depth(code).median())
            T_prev = torch.eye(4, dtype=torch.float64)
        frame = model.canonical(seq[i])
        gray = rgb_to_gray(frame.image[None])[0]
        res = {}
        for s in SOLVERS:
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                res[s] = trackers[s].track(kf, code, gray, model.camera, T_prev, valid=frame.valid)
                ms[s].append(1e3 * (time.perf_counter() - t0))
        g, d = res["generic"], res["dedicated"]
        e = se3_log(se3_inverse(g.T_kf) @ d.T_kf)
        diff["rot"] = max(diff["rot"], float(e[3:].norm()))
        diff["trans"] = max(diff["trans"], float(e[:3].norm()) / depth)
        diff["cost"] = max(diff["cost"], abs(g.cost - d.cost) / max(abs(g.cost), 1e-30))
        diff["iterations"] += g.iterations != d.iterations
        diff["ok"] += g.ok != d.ok
        diff["failed"] += not g.ok
        T_prev = g.T_kf if g.ok and math.isfinite(g.cost) else T_prev
    n = last - a.first
    print(f"{Path(a.dataset).name}: {n} frames {a.first + 1}..{last}, a keyframe every {a.every}, "
          f"{a.threads} torch thread(s), levels {cfg.tracker.pyramid_levels}, iterations {cfg.tracker.max_iterations}")
    for s in SOLVERS:
        print(f"{s:10s} median {np.median(ms[s]):7.1f} ms/frame, mean {np.mean(ms[s]):7.1f}, "
              f"p90 {np.percentile(ms[s], 90):7.1f}")
    print(f"generic / dedicated: median {np.median(ms['generic']) / np.median(ms['dedicated']):.2f}x, "
          f"mean {np.mean(ms['generic']) / np.mean(ms['dedicated']):.2f}x")
    print(f"max difference: rotation {diff['rot']:.1e} rad, translation {diff['trans']:.1e} of the median depth, "
          f"cost {diff['cost']:.1e} relative; frames with other iterations {diff['iterations']}, other ok flag "
          f"{diff['ok']}; failed (generic) {diff['failed']}")


if __name__ == "__main__":
    main()
