"""Speed of the SLAM system, sequential against parallel mapping, in one run (issue 12).

For each sequence (a real one, by default ``../shared/data/tum_fr1_rpy``, and a generator preset rendered in
memory, by default the walk at 10 frames/s) and each mapping mode it runs the whole system in a fresh process
(so peak memory is that run's) and prints:

* frames per second of the whole loop, reading included (and of the system alone);
* per-frame stages (read, resample, features, track, relocalise, wait) and per-keyframe stages (decode,
  marginalise, window): median and 90th percentile in ms ("read" is the time the loop waited for a frame: frames
  are read one ahead on a thread of their own, :func:`codeslam.slam.pipeline.read_ahead`; "wait" the time the
  tracker waited for the mapping thread, parallel mode);
* each frame's time in ``CodeSLAM.process`` on the tracking thread, wall and that thread's CPU time (median and
  90th percentile ms; in parallel mode the difference is waiting: for an urgent keyframe, the GIL or a core), and
  the mapping steps' wall and CPU time in all (s; their stages decode, marginalise and window, as the mapping
  thread's clock timed them; with ``window.solve_process`` the window solves run in a child process, whose CPU
  time is printed on its own line, :mod:`codeslam.slam.solve_process`);
* map updates (window solves) per second of wall time, keyframes, failed frames, and the window solves cut short
  by the tracker (parallel mode; in brackets those cut before their first iteration);
* peak resident memory (MB; with the window's solver process, its peak added to the run's: an upper bound);
* ATE Sim(3) and the orientation error after the best rotation alignment, so a speed-up is read beside what it
  costs;

and the ratios parallel / sequential of the whole-loop rate. With ``--config A.yaml B.yaml`` every run is made
once per configuration (YAML overlays of the defaults; ``default`` names the defaults themselves), and the
ratios of each to the first are printed too: an A/B comparison measured in one run. Nothing is asserted.

    python benchmarks/bench_slam.py [--dataset DIR] [--frames N] [--preset walk --preset-fps 10
                                    --preset-frames 60 --size 320x240] [--depth-model network|standin]
                                    [--threads 2] [--modes sequential parallel] [--weights W]
                                    [--config default B.yaml ...]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import queue
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PER_FRAME = ("read", "resample", "features", "track", "relocalise", "wait")
PER_KEYFRAME = ("decode", "marginalise", "window")


def _sequence(spec: dict):
    """The sequence to run: a dataset folder, or a generator preset rendered in memory (cached in the parent)."""
    from codeslam.data.registry import open_dataset

    if spec["kind"] == "dataset":
        return open_dataset(spec["path"])
    sys.path.insert(0, str(REPO / "tests" / "slam"))
    from slam_scene import MemorySequence, preset_frames  # the test helper renders presets in memory

    w, h = (int(v) for v in spec["size"].split("x"))
    return MemorySequence(preset_frames(spec["seed"], spec["frames"], spec["preset"], spec["fps"], w, h))


def _run(spec: dict, mode: str, args: dict, out: mp.Queue) -> None:
    import torch

    from codeslam.cli.common import keep_freed_memory
    from codeslam.eval.slam_run import evaluate_run_if_possible
    from codeslam.slam.config import load_config
    from codeslam.slam.pipeline import ground_truth, mapping_statistics, run_slam
    from codeslam.slam.system import CodeSLAM

    keep_freed_memory()  # as the codeslam command does at its start
    torch.set_num_threads(args["threads"])
    seq = _sequence(spec)
    n = min(len(seq), spec.get("limit") or len(seq))
    config = load_config(None if args["config"] == "default" else args["config"])
    if args["depth_model"] == "network":
        from codeslam.depthmodel import DepthModel
        from codeslam.network.jacobian import jacobian_dtype
        from codeslam.slam.depth import network_depth_model

        model = DepthModel.load(args["weights"])
        factory, camera = network_depth_model(
            model, jacobian_dtype(config.jacobian_dtype, config.device, config.torch_dtype)), model.camera
    else:
        from codeslam.geometry.camera import canonical_camera
        from codeslam.slam.depth import standin_depth_model

        factory, camera = standin_depth_model(), canonical_camera()
    clock = _bench_clock(config.device)
    system = CodeSLAM(config, factory, parallel=(mode == "parallel"), clock=clock)
    tracker = _thread_clock(system)
    t0 = time.perf_counter()
    run = run_slam(seq, system, camera, list(range(n)))
    wall = time.perf_counter() - t0
    stages = {}
    for k in PER_FRAME:
        v = [r.timings_ms.get(k, 0.0) for r in run.results]
        stages[k] = (float(np.median(v)), float(np.percentile(v, 90)))
    kf_results = [r for r in run.results if r.is_keyframe and r.window is not None]
    for k in PER_KEYFRAME:
        v = [r.timings_ms.get(k, 0.0) for r in kf_results] or [0.0]
        stages[k] = (float(np.median(v)), float(np.percentile(v, 90)))
    ev = evaluate_run_if_possible(run.trajectory, ground_truth(seq, list(range(n))))
    child = resource.getrusage(resource.RUSAGE_CHILDREN)  # the solver process (parallel mode), ended by run_slam
    out.put({
        "frames": n, "fps": n / wall, "fps_system": run.fps, "keyframes": len(run.keyframes),
        "updates_per_s": system.mapper.updates / wall, "failed": sum(not r.tracking_ok for r in run.results),
        "peak_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss + child.ru_maxrss) / 1024.0,
        "solver_cpu_s": child.ru_utime + child.ru_stime, "stages": stages,
        "ate_sim3": ev.get("ate_sim3_rmse"), "rot_deg": ev.get("rot_aligned_rmse_deg"),
        "frame_wall": (float(np.median(tracker["wall"])), float(np.percentile(tracker["wall"], 90))),
        "frame_cpu": (float(np.median(tracker["cpu"])), float(np.percentile(tracker["cpu"], 90))),
        "mapping_wall_s": sum(f.wall_s for f in clock.forks), "mapping_cpu_s": sum(f.cpu_s for f in clock.forks),
        "solves": mapping_statistics(run.results),
    })


def _thread_clock(system) -> dict:
    """Wall and calling-thread CPU time (ms) of every ``system.process`` (the tracking thread's frame), by wrapping
    it on this instance: in parallel mode a frame's wall time beyond its CPU time is waiting, for an urgent
    keyframe, the GIL or a core. The CPU time counts the calling thread only (not the extra OpenMP workers of a
    step on more than one thread)."""
    tracker = {"wall": [], "cpu": []}
    process = system.process

    def clocked(*args, **kwargs):
        w0, c0 = time.perf_counter(), time.thread_time()
        try:
            return process(*args, **kwargs)
        finally:
            tracker["wall"].append(1e3 * (time.perf_counter() - w0))
            tracker["cpu"].append(1e3 * (time.thread_time() - c0))

    system.process = clocked
    return tracker


def _bench_clock(device):
    """The system's clock (:class:`codeslam.clock.StageClock`, whose stages the per-stage rows read), which also
    sums the wall and CPU time of every stage it timed on its thread, never reset by a split; its forks (the
    mapping steps' clock) are kept in ``forks``: their sums are the mapping's wall and CPU time."""
    from contextlib import contextmanager

    from codeslam.clock import StageClock

    class BenchClock(StageClock):
        def __init__(self, device) -> None:
            super().__init__(device)
            self.wall_s, self.cpu_s, self.forks = 0.0, 0.0, []

        @contextmanager
        def __call__(self, stage: str):
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                with super().__call__(stage):
                    yield
            finally:
                self.wall_s += time.perf_counter() - w0
                self.cpu_s += time.thread_time() - c0

        def fork(self) -> BenchClock:
            self.forks.append(BenchClock(self.device))
            return self.forks[-1]

    return BenchClock(device)


def _run_or_report(spec: dict, mode: str, args: dict, out: mp.Queue) -> None:
    """:func:`_run`, with any error handed to the parent as one line (the parent stops the bench with it)."""
    try:
        _run(spec, mode, args, out)
    except BaseException as e:  # noqa: BLE001 - whatever ended the run, the parent must hear of it
        out.put({"error": f"{type(e).__name__}: {e}"})


def measure(spec: dict, mode: str, args: dict) -> dict:
    ctx = mp.get_context("spawn")  # a fresh process per run: its own peak memory, no state shared
    q = ctx.Queue()
    p = ctx.Process(target=_run_or_report, args=(spec, mode, args, q))
    p.start()
    while True:  # a run that dies without a word (killed, out of memory) must not leave the bench waiting
        try:
            result = q.get(timeout=1.0)
            break
        except queue.Empty:
            if not p.is_alive():
                sys.exit(f"bench_slam: the {mode} run ended without a result (exit code {p.exitcode})")
    p.join()
    if "error" in result:
        sys.exit(f"bench_slam: the {mode} run failed: {result['error']}")
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default=str(REPO.parent / "shared" / "data" / "tum_fr1_rpy"))
    ap.add_argument("--frames", type=int, default=None, help="at most this many frames of the dataset")
    ap.add_argument("--preset", default="walk", help="generator preset ('' to skip)")
    ap.add_argument("--preset-fps", type=float, default=10.0)
    ap.add_argument("--preset-frames", type=int, default=60)
    ap.add_argument("--size", default="320x240", help="the preset's rendered image size")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--depth-model", default="network", choices=("network", "standin"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--weights", default=None, help="network weights (default: the shipped ones)")
    ap.add_argument("--modes", nargs="+", default=["sequential", "parallel"])
    ap.add_argument("--config", nargs="+", default=["default"],
                    help="SLAM configuration overlays to compare ('default': the defaults)")
    ap.add_argument("--json", default=None, help="also write the measurements here")
    a = ap.parse_args()
    from codeslam.errors import CodeSLAMError
    from codeslam.slam.config import load_config

    if a.dataset:  # opened once here too, so that a wrong path stops the bench before any run
        from codeslam.data.registry import open_dataset

        try:
            open_dataset(a.dataset)
        except CodeSLAMError as e:
            sys.exit(f"bench_slam: {e}")
    for c in a.config:  # each overlay read once here, so that a bad one stops the bench before any run
        try:
            load_config(None if c == "default" else c)
        except CodeSLAMError as e:
            sys.exit(f"bench_slam: {e}")
    specs = []
    if a.dataset:
        specs.append(({"kind": "dataset", "path": a.dataset, "limit": a.frames}, Path(a.dataset).name))
    if a.preset:
        specs.append(({"kind": "preset", "preset": a.preset, "fps": a.preset_fps, "frames": a.preset_frames,
                       "size": a.size, "seed": a.seed}, f"{a.preset}@{a.preset_fps:g}fps"))
    table = {}
    for spec, name in specs:
        for mode in a.modes:
            for c in a.config:
                args = {"threads": a.threads, "depth_model": a.depth_model, "weights": a.weights, "config": c}
                label = mode if len(a.config) == 1 else f"{mode} {Path(c).stem}"
                table[(name, label)] = measure(spec, mode, args)
    print(f"depth model {a.depth_model}, weights {a.weights or 'shipped'}, {a.threads} torch thread(s)")
    cols = [f"{name} {mode}" for name, mode in table]
    w = max(28, 2 + max(len(c) for c in cols))  # column width: the longest heading and two spaces
    print(f"{'':24s}" + "".join(f"{c:>{w}s}" for c in cols))
    rows = [("frames", "frames", "{:d}"), ("frames/s (whole loop)", "fps", "{:.2f}"),
            ("frames/s (system)", "fps_system", "{:.2f}"), ("keyframes", "keyframes", "{:d}"),
            ("map updates/s", "updates_per_s", "{:.2f}"), ("failed frames", "failed", "{:d}"),
            ("peak memory MB", "peak_mb", "{:.0f}"), ("ATE Sim(3) m", "ate_sim3", "{:.4f}"),
            ("orientation deg", "rot_deg", "{:.2f}")]
    for label, key, fmt in rows:
        vals = [r.get(key) for r in table.values()]
        print(f"{label:24s}" + "".join(f"{(fmt.format(v) if v is not None else 'n/a'):>{w}s}" for v in vals))
    for st in PER_FRAME + PER_KEYFRAME:
        vals = [r["stages"][st] for r in table.values()]
        print(f"{st + ' ms med/p90':24s}" + "".join(f"{f'{m:.1f} / {p:.1f}':>{w}s}" for m, p in vals))
    for label, key in (("frame wall ms med/p90", "frame_wall"), ("frame CPU ms med/p90", "frame_cpu")):
        print(f"{label:24s}" + "".join(f"{f'{m:.1f} / {p:.1f}':>{w}s}" for m, p in (r[key] for r in table.values())))
    mapping = ["{:.1f} / {:.1f}".format(r["mapping_wall_s"], r["mapping_cpu_s"]) for r in table.values()]
    print(f"{'mapping wall / CPU s':24s}" + "".join(f"{v:>{w}s}" for v in mapping))
    solver = ["{:.1f}".format(r["solver_cpu_s"]) for r in table.values()]
    print(f"{'solver process CPU s':24s}" + "".join(f"{v:>{w}s}" for v in solver))
    solves = ["{} / {} ({})".format(r["solves"]["cut_short"], r["solves"]["window_solves"],
                                    r["solves"]["cut_before_first_iteration"]) for r in table.values()]
    print(f"{'solves cut / all (at 0)':24s}" + "".join(f"{v:>{w}s}" for v in solves))
    tags = [""] if len(a.config) == 1 else [f" {Path(c).stem}" for c in a.config]
    for _, name in specs:
        for tag in tags:
            if (name, "sequential" + tag) in table and (name, "parallel" + tag) in table:
                r = table[(name, "parallel" + tag)]["fps"] / table[(name, "sequential" + tag)]["fps"]
                print(f"{name}{tag}: parallel / sequential frames per second = {r:.2f}")
        for mode in a.modes:
            for tag in tags[1:]:
                r = table[(name, mode + tag)]["fps"] / table[(name, mode + tags[0])]["fps"]
                print(f"{name} {mode}: {tag.strip()} / {tags[0].strip()} frames per second = {r:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps({f"{k[0]} {k[1]}": v for k, v in table.items()}, indent=1))


if __name__ == "__main__":
    main()
