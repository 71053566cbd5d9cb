"""Per-frame motion of the generator's motion presets: the table in ``codeslam/synth/motion.py``'s docstring.

For every preset and frame rate, draws ``--seeds`` rooms and paths of ``--frames`` frames (no rendering) and
prints the median, 95th percentile and maximum of the translation (cm) and rotation (deg) between consecutive
frames, the mean speed (m/s) and the 95th percentile of the angular speed (deg/s) over frames.

    python scripts/motion_stats.py [--seeds 24] [--frames 300] [--fps 10,30]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from codeslam.synth.generate import scene_seed
from codeslam.synth.motion import PRESETS, preset_trajectory


def frame_motion(T: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation angle (rad) between consecutive poses T (N, 4, 4): two (N - 1,) arrays."""
    step = (T[1:, :3, 3] - T[:-1, :3, 3]).norm(dim=-1)
    R = T[:-1, :3, :3].transpose(-1, -2) @ T[1:, :3, :3]
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    return step.numpy(), torch.acos(cos).numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--fps", default="10,30")
    ap.add_argument("--presets", default=",".join(PRESETS))
    args = ap.parse_args()
    print("| preset | fps | translation cm med/95/max | rotation deg med/95/max | speed m/s | deg/s p95 | s/path |")
    print("|---|---|---|---|---|---|---|")
    for name in args.presets.split(","):
        for fps in (float(f) for f in args.fps.split(",")):
            tr, rot, t0 = [], [], time.perf_counter()
            for i in range(args.seeds):
                s = scene_seed(0, i)
                scene = PRESETS[name].scene(s)
                T = preset_trajectory(scene, args.frames, np.random.default_rng(np.random.SeedSequence([s, 0x7247])),
                                      name, fps=fps)
                a, b = frame_motion(T)
                tr.append(a)
                rot.append(b)
            tr_a, rot_a = np.concatenate(tr) * 100, np.degrees(np.concatenate(rot))
            q = lambda x: f"{np.median(x):.1f} / {np.percentile(x, 95):.1f} / {x.max():.1f}"  # noqa: E731
            sec = (time.perf_counter() - t0) / args.seeds
            print(f"| {name} | {fps:g} | {q(tr_a)} | {q(rot_a)} | {tr_a.mean() * fps / 100:.2f} | "
                  f"{np.percentile(rot_a, 95) * fps:.0f} | {sec:.2f} |", flush=True)


if __name__ == "__main__":
    main()
