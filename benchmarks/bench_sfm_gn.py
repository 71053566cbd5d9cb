"""Time of one Gauss-Newton iteration of N-frame SfM: analytic compact Jacobians vs autograd Jacobians.

One iteration = residuals + Jacobians + normal equations + damped Cholesky solve, at the full resolution of the
canonical camera (128x96), for 2 and 4 frames (master pairs, both directions) and code sizes 32, 64 (the SLAM
window's, ``window.code_directions``) and 128 (the shipped network's). The autograd baseline differentiates the
same residual function with forward-mode autograd over all free variables (``codeslam.sfm.autodiff``), then forms
J^T W J. Both are timed in the same run; the "GEMM" columns are the time of the J^T W J products alone (measured
inside the same iterations) as a share of the iteration.

    python benchmarks/bench_sfm_gn.py [--repeats 5] [--device cpu] [--dtype float32] [--chunk 64] [--threads N]
                                      [--geometric-stride S]

With ``--geometric-stride S`` the analytic iteration is also timed with the geometric residuals on every S-th
pixel (``SfMConfig.geometric_stride``), and its time printed beside the full one with their ratio.

Prints a table; asserts nothing about time.
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace

import torch

from codeslam.cli.common import keep_freed_memory
from codeslam.clock import NO_CLOCK, StageClock
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.lie import se3_exp
from codeslam.sfm.autodiff import autodiff_normal_equations
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.decoder import standin_decoder
from codeslam.sfm.keyframes import Keyframe, build_levels
from codeslam.sfm.pairs import master_pairs
from codeslam.sfm.solver import PairProblem, solve_damped
from codeslam.sfm.variables import BlockId, SfMState, VariableLayout


def _smooth_noise(gen: torch.Generator, h: int, w: int, cells: int) -> torch.Tensor:
    """(h, w) bicubic upsampling of a (cells x cells) random grid: a smooth random field in about [-1, 1]."""
    grid = torch.rand(1, 1, cells, cells, generator=gen) * 2 - 1
    return torch.nn.functional.interpolate(grid, size=(h, w), mode="bicubic", align_corners=True)[0, 0]


def synthetic_problem(num_frames: int, code_size: int, width: int, height: int, seed: int = 0):
    """Frames with smooth random images and depths (2-3 m) and stand-in decoders, poses a few cm apart, codes
    and affine parameters slightly off zero: a state where most pixels warp inside the other views."""
    gen = torch.Generator().manual_seed(seed)
    cam = canonical_camera(width, height)
    kfs = []
    for _ in range(num_frames):
        gray = 0.5 + 0.2 * _smooth_noise(gen, height, width, 24) + 0.1 * _smooth_noise(gen, height, width, 48)
        depth = 2.5 + 0.5 * _smooth_noise(gen, height, width, 6)
        prox = 2.0 / (depth + 2.0)
        dec = standin_decoder(prox, code_size, 1, 2.0, code_offset=torch.randn(code_size, generator=gen),
                              image=gray)
        kfs.append(Keyframe(gray, cam, dec))
    poses = se3_exp(torch.cat([0.05 * torch.randn(num_frames, 3, generator=gen),
                               0.01 * torch.randn(num_frames, 3, generator=gen)], dim=1))
    pairs = torch.tensor(master_pairs(num_frames, 0))
    state = SfMState(poses, 0.1 * torch.randn(num_frames, code_size, generator=gen),
                     0.01 * torch.randn(pairs.shape[0], 2, generator=gen))
    return kfs, pairs, state


def time_iteration(step, device: torch.device, repeats: int) -> tuple[float, float]:
    """Median wall time (s) of ``step(clock)`` and median GEMM share of it (the 'gemm' stage the normal
    equations time on ``clock``), after one warm-up call."""
    step(NO_CLOCK)
    times, shares = [], []
    clock = StageClock(device)
    for _ in range(repeats):
        with clock("iteration"):
            step(clock)
        ms = clock.split()
        times.append(1e-3 * ms["iteration"])
        shares.append(ms.get("gemm", 0.0) / ms["iteration"])
    return statistics.median(times), statistics.median(shares)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--autograd-repeats", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--chunk", type=int, default=64, help="JVPs per vmap batch of the autograd Jacobian")
    ap.add_argument("--frames", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--codes", type=int, nargs="+", default=[32, 64, 128])
    ap.add_argument("--skip-autograd", action="store_true")
    ap.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch's default)")
    ap.add_argument("--geometric-stride", type=int, default=1,
                    help="also time the analytic iteration with this SfMConfig.geometric_stride (1: not)")
    args = ap.parse_args()
    if args.repeats < 1 or args.autograd_repeats < 0:
        ap.error("--repeats must be >= 1 and --autograd-repeats >= 0 (0 skips autograd, as --skip-autograd)")
    if args.geometric_stride < 1:
        ap.error("--geometric-stride must be >= 1")
    args.skip_autograd = args.skip_autograd or args.autograd_repeats == 0
    keep_freed_memory()  # as the codeslam command does at its start (the window's iterations run under it)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    dtype = getattr(torch, args.dtype)
    cfg = SfMConfig(gradient_mode="interpolant")  # the Jacobians autograd computes, so both do the same maths

    print(f"device={device} dtype={args.dtype} threads={torch.get_num_threads()} size={args.width}x{args.height} "
          f"torch={torch.__version__}")
    header = (f"{'frames':>6} {'pairs':>5} {'code':>4} {'vars':>5} {'analytic ms':>11} {'GEMM %':>6} "
              f"{'autograd ms':>11} {'GEMM %':>6} {'ratio':>7}")
    strided = args.geometric_stride > 1
    if strided:
        header += f" {f'stride {args.geometric_stride} ms':>12} {'ratio':>6}"
    print(header)
    print("-" * len(header))
    for F_ in args.frames:
        for C in args.codes:
            kfs, pairs, state = synthetic_problem(F_, C, args.width, args.height)
            kfs = [Keyframe(k.image.to(dtype), k.camera, k.decoder.to(dtype, device)) for k in kfs]
            level = build_levels(kfs, [0], dtype, device)[0]
            pairs = pairs.to(device)
            state = SfMState(state.poses.to(device, dtype), state.codes.to(device, dtype),
                             state.affine.to(device, dtype))
            layout = VariableLayout.for_sfm(F_, C, pairs.shape[0], True, fixed=[BlockId("pose", 0)])
            problem = PairProblem(level, pairs, cfg)

            def analytic(clock, problem=problem, state=state, layout=layout):
                _, ev = problem.evaluate(state)
                H, g = problem.linearize(state, ev, layout, clock)
                return solve_damped(H, g, cfg.initial_damping, cfg.min_diagonal)

            def autograd(clock, problem=problem, state=state, layout=layout, level=level, pairs=pairs):
                problem.evaluate(state)  # the cost, as an LM iteration needs it
                H, g = autodiff_normal_equations(level, pairs, state, layout, cfg, clock, args.chunk)
                return solve_damped(H, g, cfg.initial_damping, cfg.min_diagonal)

            t_an, share_an = time_iteration(analytic, device, args.repeats)
            if args.skip_autograd:
                t_ad, share_ad, ratio = float("nan"), float("nan"), float("nan")
            else:
                t_ad, share_ad = time_iteration(autograd, device, args.autograd_repeats)
                ratio = t_ad / t_an
            row = (f"{F_:>6} {pairs.shape[0]:>5} {C:>4} {layout.dim:>5} {1e3 * t_an:>11.1f} {100 * share_an:>6.1f} "
                   f"{1e3 * t_ad:>11.1f} {100 * share_ad:>6.1f} {ratio:>7.1f}")
            if strided:  # the same iteration with the geometric residuals on the stride's grid
                sparse = PairProblem(level, pairs, replace(cfg, geometric_stride=args.geometric_stride))
                t_st, _ = time_iteration(lambda clock, sparse=sparse: analytic(clock, sparse), device, args.repeats)
                row += f" {1e3 * t_st:>12.1f} {t_an / t_st:>6.2f}"
            print(row)


if __name__ == "__main__":
    main()
