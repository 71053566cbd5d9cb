"""Speed and accuracy of the SLAM system (paper Sec. 4.3) on a synthetic sequence or a dataset folder.

For each variant (the default system, and with ``--compare`` the same without marginalisation, where the oldest
keyframe's terms are dropped instead of becoming a prior) it reports frames per wall-clock and per CPU second,
the mean time per frame of every stage (tracking, decoding, marginalisation, window optimisation), the window
optimisation time per keyframe, and against ground truth ATE (SE(3) and Sim(3) alignment), the orientation
error relative to the first frame and the no-motion baselines.

    python benchmarks/bench_slam.py [--dataset DIR] [--seed 3 --frames 60 --fps 30] [--size 128x96]
                                    [--depth-model standin|network] [--weights FILE] [--device cpu]
                                    [--threads 1] [--compare]

Without ``--dataset`` the sequence is rendered in memory by the generator (the room and trajectory of
``codeslam synth OUT --scenes 1 --seed S``, rendered as that command renders, without the PNG quantisation).
The stand-in depth model is an oracle built from the true depth (see :mod:`codeslam.slam.depth`); with trained
weights use ``--depth-model network``.
Prints a table, asserts nothing. On a machine shared with other jobs the wall-clock rate varies run to run, the
CPU rate much less.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from codeslam.data.frame import Frame, resample_frame
from codeslam.eval.slam_run import evaluate_run
from codeslam.geometry.camera import canonical_camera
from codeslam.slam.config import SLAMConfig, load_config
from codeslam.slam.pipeline import ground_truth, run_slam
from codeslam.slam.system import CodeSLAM


class _Frames:
    """A minimal in-memory sequence (what :func:`run_slam` needs)."""

    def __init__(self, frames: list[Frame]) -> None:
        self.frames = frames
        self.timestamps = np.array([f.timestamp for f in frames])
        has_pose = all(f.pose is not None for f in frames)
        self.gt_poses = torch.stack([f.pose for f in frames]) if has_pose else None

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]


def synthetic_sequence(seed: int, frames: int, fps: float, width: int, height: int) -> _Frames:
    from codeslam.synth.generate import scene_seed
    from codeslam.synth.render import RenderConfig, render
    from codeslam.synth.scene import build_scene
    from codeslam.synth.trajectory import random_trajectory

    s = scene_seed(seed, 0)  # the room of `codeslam synth OUT --scenes 1 --seed SEED`
    scene = build_scene(s)
    poses = random_trajectory(scene, frames, np.random.default_rng(np.random.SeedSequence([s, 0x7247])), fps=fps)
    cam = canonical_camera(width, height)
    images, depths = [], []
    for a in range(0, frames, 8):
        img, dep = render(scene, cam, poses[a:a + 8], RenderConfig(supersample=2))  # as the CLI
        images.append(img)
        depths.append(dep)
    image, depth = torch.cat(images), torch.cat(depths)
    return _Frames([Frame(1000.0 + i / fps, image[i], cam, depth[i], poses[i], i) for i in range(frames)])


def run_variant(name: str, seq, cfg: SLAMConfig, factory, camera) -> dict:
    system = CodeSLAM(cfg, factory)
    c0 = time.process_time()
    run = run_slam(seq, system, camera)
    cpu = time.process_time() - c0
    n = len(run.results)
    out = {"variant": name, "frames": n, "keyframes": len(run.keyframes),
           "failures": sum(not r.tracking_ok for r in run.results), "fps": run.fps, "fps_cpu": n / cpu,
           **{f"ms_{k}": v / n for k, v in run.timings_ms.items() if k in ("track", "decode", "marginalise", "window")},
           "ms_window_per_kf": run.timings_ms["window"] / max(len(run.keyframes) - 1, 1)}
    gt = ground_truth(seq, range(n))
    if gt is not None:
        out.update(evaluate_run(run.trajectory, gt))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default=None, help="a dataset folder instead of the rendered sequence")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--fps", type=float, default=30.0, help="frame rate of the rendered trajectory")
    ap.add_argument("--size", default="128x96")
    ap.add_argument("--depth-model", default="standin", choices=("standin", "network"))
    ap.add_argument("--weights", default=None)
    ap.add_argument("--config", default=None, help="YAML overlay of the SLAM configuration")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--compare", action="store_true", help="also run without marginalisation")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    w, h = (int(v) for v in args.size.split("x"))
    cfg = replace(load_config(args.config), device=args.device)
    if args.depth_model == "network":
        from codeslam.depthmodel import DepthModel
        from codeslam.slam.depth import network_depth_model

        model = DepthModel.load(args.weights, device=args.device)
        factory, camera = network_depth_model(model), model.camera
    else:
        from codeslam.slam.depth import standin_depth_model

        factory, camera = standin_depth_model(num_levels=cfg.decoder_levels), canonical_camera(w, h)
    if args.dataset:
        from codeslam.data.registry import open_dataset

        ds = open_dataset(args.dataset)
        frames = [resample_frame(ds[i], camera) for i in range(min(args.frames, len(ds)))]
        seq = _Frames(frames)
    else:
        seq = synthetic_sequence(args.seed, args.frames, args.fps, camera.width, camera.height)
    variants = [("default", cfg)]
    if args.compare:
        variants.append(("no marginalisation", replace(cfg, window=replace(cfg.window, marginalise=False))))
    rows = [run_variant(name, seq, c, factory, camera) for name, c in variants]
    print(f"{len(seq)} frames at {camera.width}x{camera.height}, depth model {args.depth_model}, "
          f"device {args.device}, {args.threads} thread(s)")
    keys = ["frames", "keyframes", "failures", "fps", "fps_cpu", "ms_track", "ms_decode", "ms_marginalise",
            "ms_window", "ms_window_per_kf", "ate_se3_rmse", "ate_sim3_rmse", "sim3_scale", "rot_err_rmse_deg",
            "rpe_rot_rmse_deg", "drift_end_error", "no_motion_ate_rmse", "no_motion_ate_rmse_aligned",
            "path_length_gt"]
    print(f"{'':28s}" + "".join(f"{r['variant']:>22s}" for r in rows))
    for k in keys:
        vals = [r.get(k) for r in rows]
        print(f"{k:28s}" + "".join(f"{v:>22.4f}" if isinstance(v, float) else f"{v!s:>22s}" for v in vals))


if __name__ == "__main__":
    main()
