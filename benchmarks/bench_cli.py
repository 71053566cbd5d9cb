"""Whole ``codeslam slam`` processes timed from outside, as issue 12 checks them, in one run.

``benchmarks/bench_slam.py`` times the loop inside one process; a user waits for the whole command: the
interpreter and torch's import, the network's loading, the loop, the mapping thread's last solve and the outputs
(trajectory, report). Issue 12 reads both: "frames per second from its own summary and the whole process timed
from outside; the median over several runs". For each round, every (dataset, mode, configuration) is run once
as ``codeslam slam DATA --out TMP -q --threads T [--parallel] [--config C]``, in the same order each round, so that
the machine's slower and faster minutes fall on every cell alike; then per cell the medians over the rounds of:

* wall s of the whole process, and frames / wall s ("whole process frames/s");
* the frames/s the run's own summary reports (``result.json``: ``fps_with_io``, the loop with reading);
* CPU s of the process (user + system, its threads and children included) and its peak memory (MB);
* failed frames, ATE Sim(3) and the orientation error after the best rotation alignment (a speed-up is read
  beside what it costs);

and the ratios of the medians: parallel / sequential, and each configuration / the first. Nothing is asserted.

    python benchmarks/bench_cli.py DATA [DATA ...] [--rounds 3] [--threads 2] [--modes sequential parallel]
                                   [--config default B.yaml ...] [--frames A:B] [--weights W] [--json F]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _fail(msg: str) -> None:
    print(f"bench_cli: {msg}", file=sys.stderr)
    sys.exit(1)


def run_once(data: str, mode: str, config: str, args: argparse.Namespace, out: Path) -> dict:
    """One whole process: its wall time from outside, its own rusage (``os.wait4``: CPU and peak memory of
    this child alone), and what its ``result.json`` says."""
    cmd = [sys.executable, "-m", "codeslam", "slam", data, "--out", str(out), "-q", "--threads", str(args.threads)]
    if mode == "parallel":
        cmd.append("--parallel")
    if config != "default":
        cmd += ["--config", config]
    if args.frames:
        cmd += ["--frames", args.frames]
    if args.weights:
        cmd += ["--weights", args.weights]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    stderr = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped by wait4 (for its rusage): Popen must not wait again
    if proc.returncode != 0:
        last = [line for line in stderr.splitlines() if line.strip()]
        _fail(f"{Path(data).name} {mode} {Path(config).stem}: codeslam slam exited with {proc.returncode}: "
              f"{last[-1] if last else 'no message'}")
    s = json.loads((out / "result.json").read_text())
    return {"wall_s": wall, "fps_process": s["frames"] / wall, "fps_summary": s["fps_with_io"],
            "cpu_s": usage.ru_utime + usage.ru_stime, "peak_mb": usage.ru_maxrss / 1024.0, "frames": s["frames"],
            "failed": s["tracking_failures"], "ate_sim3": s.get("ate_sim3_rmse"),
            "rot_deg": s.get("rot_aligned_rmse_deg")}


def _median(runs: list[dict], key: str) -> float | None:
    vals = [r[key] for r in runs if r[key] is not None]
    return statistics.median(vals) if vals else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="+", help="dataset folders (or videos) that codeslam slam reads")
    ap.add_argument("--rounds", type=int, default=3, help="runs of every cell; medians are printed")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--modes", nargs="+", default=["sequential", "parallel"], choices=("sequential", "parallel"))
    ap.add_argument("--config", nargs="+", default=["default"],
                    help="SLAM configuration overlays to compare ('default': the defaults)")
    ap.add_argument("--frames", default=None, help="codeslam slam's --frames (e.g. 0:60)")
    ap.add_argument("--weights", default=None, help="network weights (default: the shipped ones)")
    ap.add_argument("--json", default=None, help="also write every run's measurements here")
    a = ap.parse_args()
    if a.rounds < 1:
        _fail(f"--rounds must be at least 1, got {a.rounds}")
    for d in a.data:  # before any run: a wrong path stops the bench at once
        if not Path(d).exists():
            _fail(f"dataset not found: {d}")
    for c in a.config:
        if c != "default" and not Path(c).is_file():
            _fail(f"configuration file not found: {c}")
    cells = [(d, m, c) for d in a.data for m in a.modes for c in a.config]
    runs: dict[tuple[str, str, str], list[dict]] = {cell: [] for cell in cells}
    with tempfile.TemporaryDirectory(prefix="bench_cli_") as tmp:
        for r in range(a.rounds):
            for i, cell in enumerate(cells):
                runs[cell].append(run_once(*cell, a, Path(tmp) / f"r{r}_{i}"))
    label = {cell: f"{Path(cell[0]).name} {cell[1]}" + (f" {Path(cell[2]).stem}" if len(a.config) > 1 else "")
             for cell in cells}
    w = max(26, 2 + max(len(v) for v in label.values()))
    print(f"codeslam slam, whole processes timed from outside, {a.threads} torch thread(s), median of {a.rounds}")
    print(f"{'':30s}" + "".join(f"{label[c]:>{w}s}" for c in cells))
    rows = [("wall s", "wall_s", "{:.1f}"), ("frames/s, whole process", "fps_process", "{:.2f}"),
            ("frames/s, its summary", "fps_summary", "{:.2f}"), ("CPU s", "cpu_s", "{:.1f}"),
            ("peak memory MB", "peak_mb", "{:.0f}"), ("failed frames", "failed", "{:.0f}"),
            ("ATE Sim(3) m", "ate_sim3", "{:.4f}"), ("orientation deg", "rot_deg", "{:.2f}")]
    for name, key, fmt in rows:
        vals = [_median(runs[c], key) for c in cells]
        print(f"{name:30s}" + "".join(f"{(fmt.format(v) if v is not None else 'n/a'):>{w}s}" for v in vals))
    walls = [" ".join(f"{x['wall_s']:.1f}" for x in runs[c]) for c in cells]
    print(f"{'each wall s':30s}" + "".join(f"{v:>{w}s}" for v in walls))
    for d in a.data:
        for c in a.config:
            tag = f" {Path(c).stem}" if len(a.config) > 1 else ""
            if "sequential" in a.modes and "parallel" in a.modes:
                p, s = (_median(runs[(d, m, c)], "fps_process") for m in ("parallel", "sequential"))
                print(f"{Path(d).name}{tag}: parallel / sequential whole-process frames/s = {p / s:.2f}")
        for m in a.modes:
            for c in a.config[1:]:
                x, ref = (_median(runs[(d, m, k)], "fps_process") for k in (c, a.config[0]))
                print(f"{Path(d).name} {m}: {Path(c).stem} / {Path(a.config[0]).stem} whole-process frames/s = "
                      f"{x / ref:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps({" ".join(k): v for k, v in runs.items()}, indent=1))


if __name__ == "__main__":
    main()
