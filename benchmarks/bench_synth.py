"""Throughput of the synthetic RGB-D generator (frames per second), single-threaded and with worker processes.

Measures, for each image size and anti-aliasing setting:

- ``views``: training views (random poses, ``codeslam.synth.shards.render_shard`` with 16 views per room,
  room building included) in one process with one torch thread;
- ``sequence``: trajectory frames (one room, frames rendered 8 at a time, PNG writing excluded);
- ``shards x W``: end to end ``write_shards`` with W worker processes (process start-up and file writing
  included), the number that matters for "50,000 training views in under an hour" (issue 3: >= 20 views/s
  at 128x96 on a 2-core CPU).

    python benchmarks/bench_synth.py [--sizes 128x96,256x192] [--views 64] [--workers 2] [--supersample 1,2]

Each cell gives frames per wall-clock second and per CPU second (for the workers, per CPU second times the
number of workers): on a machine shared with other jobs the wall-clock rate varies run to run, the CPU rate
much less. Prints a table, asserts nothing.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time

import numpy as np
import torch

from codeslam.geometry.camera import canonical_camera
from codeslam.synth.render import RenderConfig, render
from codeslam.synth.scene import build_scene
from codeslam.synth.shards import ShardSpec, render_shard, write_shards
from codeslam.synth.trajectory import random_trajectory


def _rate(n: int, fn) -> tuple[float, float]:
    """(n / wall seconds, n / CPU seconds of this process) of running fn()."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def bench_views(size: tuple[int, int], views: int, supersample: int) -> tuple[float, float]:
    spec = ShardSpec(views=views, camera=canonical_camera(*size), seed=123, views_per_scene=16, shard_size=views,
                     render=RenderConfig(supersample=supersample))
    return _rate(views, lambda: render_shard(spec, 0))


def bench_sequence(size: tuple[int, int], frames: int, supersample: int, seed: int = 7) -> tuple[float, float]:
    scene = build_scene(seed)
    poses = random_trajectory(scene, frames, np.random.default_rng(seed))
    cam, cfg = canonical_camera(*size), RenderConfig(supersample=supersample)

    def run() -> None:
        for a in range(0, frames, 8):
            render(scene, cam, poses[a:a + 8], cfg)

    return _rate(frames, run)


def bench_shards(size: tuple[int, int], views: int, workers: int, supersample: int) -> tuple[float, float]:
    """(views / wall second, views per second of the workers' summed CPU time times ``workers``): the
    second is what W otherwise idle cores would give."""
    spec = ShardSpec(views=views, camera=canonical_camera(*size), seed=321, views_per_scene=16,
                     shard_size=max(16, views // (2 * workers)), render=RenderConfig(supersample=supersample))
    with tempfile.TemporaryDirectory() as tmp:
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        write_shards(spec, tmp, workers=workers)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return views / wall, views / (cpu / workers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128x96,256x192")
    ap.add_argument("--views", type=int, default=64, help="views (and sequence frames) per measurement")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--supersample", default="1,2")
    args = ap.parse_args()
    torch.set_num_threads(1)  # as the synth CLI and its workers do
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    print("frames per second: wall clock / per CPU second (x workers for the shards: what idle cores give)")
    print(f"{'size':>9} {'aa':>3} {'views (1 thread)':>17} {'sequence (1 thread)':>20} "
          f"{f'shards x{args.workers} workers':>19}")
    for size in sizes:
        for ss in (int(s) for s in args.supersample.split(",")):
            v = bench_views(size, args.views, ss)
            q = bench_sequence(size, args.views, ss)
            w = bench_shards(size, args.views * args.workers, args.workers, ss)
            print(f"{size[0]:>4}x{size[1]:<4} {ss:>3} {v[0]:>8.1f} / {v[1]:>6.1f} {q[0]:>10.1f} / {q[1]:>6.1f} "
                  f"{w[0]:>9.1f} / {w[1]:>6.1f}", flush=True)


if __name__ == "__main__":
    main()
