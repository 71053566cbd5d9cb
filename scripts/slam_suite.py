"""Every sequence the SLAM issues are judged on, run with the same settings and read as one table (issues 11-13).

A change that helps one sequence and hurts another is not progress, so a change to tracking or mapping is read on
all of them at once: the two shared real sequences (the HoloLens walk at every frame and at every second frame, TUM
fr1/rpy), the generator's motion presets (walk, hand-held, corridor, two fast turns), five generator sequences that
no setting was chosen on (seeds 41-45), six added after the last setting was chosen (seeds 51-56: a 200-frame walk,
a 300-frame hand-held, a noisy corridor, a walk at 30 frames/s, a fast turn at 10 frames/s, a walk towards a blank
wall) and eight more added the same way (seeds 81-88: two walks, one of them noisy, two corridors, a noisy hand-held
camera at 30 frames/s and one at 10 frames/s, a fast turn, a walk at 30 frames/s), four runs with frames dropped
(four at the HoloLens walk's fastest turn; a tenth of the HoloLens and the TUM frames and a fifth of corridor 82's
at random, ``--frames`` lists), the HoloLens walk there and back (its frames forwards, then backwards to the
first: the camera's velocity flips at the turn), TUM fr1/rpy upside down (its rolling shutter read from the
image's bottom up), the HoloLens walk carried from frame 99 back to frame 20 and TUM fr1/rpy with its lens covered
for a second (recovery; the copies made by ``scripts/sequence_copy.py`` under ``--seqs``), TUM fr1/rpy from its
frame 15 (a recording that starts while the camera turns), with the network's depth,
four of them again with the dataset's own depth (``--depth-model standin``), which separates the tracker from the
network, and the walk towards a blank wall with
the network's code Jacobian but the dataset's depth at the zero code (``--depth-model true-prior``), which separates
the network's zero-code depth from the rest. ``--long`` adds a walk of 39 m, about three times the path of the other
walks (seed 71, 450 frames), with the network's and the dataset's depth: whether tracking, the map's scale and
memory hold over a long way.

The generator sequences are rendered on first use under ``--seqs`` (``codeslam synth``, about 55 minutes on one
core; reused after that). Runs go ``--jobs`` at a time, each ``codeslam slam DATA --out OUT/NAME -q`` plus the
``--`` arguments (``--threads 1`` by default, which makes the runs repeat to the byte and lets two share two
cores; ``--weights W`` goes to every run but the stand-in ones, whose depth is the dataset's). The table reads each
run's ``result.json``:

    python scripts/slam_suite.py OUT [--seqs DIR] [--jobs 2] [--long] [--only NAME ...] [-- --threads 1 --config C.yaml]
    python scripts/slam_suite.py --table OUT [OUT2 ...]   # the table again; several folders side by side

Frames per second are comparable only between runs that ran alone, or in pairs in the same run of this script.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass(frozen=True)
class Sequence:
    """A generator sequence: the ``codeslam synth`` arguments that render it (one scene, 320x240)."""

    name: str
    frames: int
    motion: str
    fps: int
    seed: int
    extra: tuple[str, ...] = ()

    def render(self, seqs: Path) -> Path:
        out = seqs / self.name
        scene = out / "scene_000"
        if not (scene / "groundtruth.txt").exists():
            cmd = ["codeslam", "synth", str(out), "--scenes", "1", "--frames", str(self.frames), "--motion",
                   self.motion, "--fps", str(self.fps), "--seed", str(self.seed), "--size", "320x240", *self.extra]
            print("rendering:", " ".join(cmd), flush=True)
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        return scene


SEQUENCES = {s.name: s for s in (
    Sequence("walk10", 100, "walk", 10, 11),
    Sequence("handheld30", 120, "handheld", 30, 12),
    Sequence("fastturn30", 120, "fast-turn", 30, 13),
    Sequence("ft30_s14", 120, "fast-turn", 30, 14),
    Sequence("corr10", 100, "corridor", 10, 21),
    # seeds 41-45: never used to choose a setting
    Sequence("hh41", 600, "handheld", 30, 41, ("--noise", "0.01", "--blur", "0.5")),
    Sequence("walk42", 150, "walk", 10, 42),
    Sequence("walk43", 150, "walk", 10, 43, ("--noise", "0.01")),
    Sequence("corr44", 150, "corridor", 10, 44),
    Sequence("ft45", 150, "fast-turn", 30, 45),
    # seeds 51-56: added after the last setting was chosen (2026-11-29, seventeenth session), never tuned on
    Sequence("walk51", 200, "walk", 10, 51),
    Sequence("hh52", 300, "handheld", 30, 52, ("--noise", "0.01", "--blur", "0.5")),
    Sequence("corr53", 150, "corridor", 10, 53, ("--noise", "0.01")),
    Sequence("walk54", 300, "walk", 30, 54),
    Sequence("ft55", 60, "fast-turn", 10, 55),
    Sequence("walk56", 150, "walk", 10, 56),
    # seeds 81-88: added after the last setting was chosen (2026-12-04, forty-second session), never tuned on
    Sequence("walk81", 150, "walk", 10, 81),
    Sequence("corr82", 150, "corridor", 10, 82),
    Sequence("hh83", 150, "handheld", 30, 83, ("--noise", "0.01")),
    Sequence("ft84", 120, "fast-turn", 30, 84),
    Sequence("walk85", 150, "walk", 10, 85, ("--noise", "0.01")),
    Sequence("corr86", 120, "corridor", 10, 86),
    Sequence("walk87", 200, "walk", 30, 87),
    Sequence("hh88", 150, "handheld", 10, 88),
    # seeds 91-92 (2026-12-06, forty-eighth session): a walk that faces a blank wall for 15 frames (its shading
    # 0.007-0.0095; tracker.min_intensity_std was lowered to 0.004 on it, so it is not a held-out sequence), and a
    # corridor with a dim camera's noise and blur
    Sequence("walk91", 150, "walk", 10, 91),
    Sequence("corr92", 150, "corridor", 10, 92, ("--noise", "0.03", "--blur", "0.7")),
    # seed 71: a walk of 39 m, about three times the other walks' paths (450 frames); rendered and run only with --long
    Sequence("walk71", 450, "walk", 10, 71),
)}


def dropped(frames: int, keep: float, seed: int) -> str:
    """``--frames`` for a sequence of ``frames`` frames with frames dropped at random, each kept with probability
    ``keep`` (frame 0 always): the uneven intervals of a live capture that falls behind or of a phone's video."""
    rng = np.random.default_rng(seed)
    return ",".join(str(i) for i in [0] + [i for i in range(1, frames) if rng.random() < keep])


# (run name, dataset: a folder under ../shared/data or a generator sequence's name, extra codeslam slam arguments)
RUNS = (
    ("holo", "hololens_dvmvs", ()),
    ("holo_every2", "hololens_dvmvs", ("--frames", "0:188:2")),
    ("tum", "tum_fr1_rpy", ()),
    ("walk", "walk10", ()),
    ("hand", "handheld30", ()),
    ("corr", "corr10", ()),
    ("ft13", "fastturn30", ()),
    ("ft14", "ft30_s14", ()),
    ("hh41", "hh41", ()),
    ("walk42", "walk42", ()),
    ("walk43", "walk43", ()),
    ("corr44", "corr44", ()),
    ("ft45", "ft45", ()),
    ("walk51", "walk51", ()),
    ("hh52", "hh52", ()),
    ("corr53", "corr53", ()),
    ("walk54", "walk54", ()),
    ("ft55", "ft55", ()),
    ("walk56", "walk56", ()),
    *((name, name, ()) for name in ("walk81", "corr82", "hh83", "ft84", "walk85", "corr86", "walk87", "hh88")),
    ("walk91", "walk91", ()),
    ("corr92", "corr92", ()),
    # frames dropped (added 2026-12-05, forty-third session): four at the HoloLens walk's fastest turn (29 deg and
    # 36 cm between the frames either side), and a tenth or a fifth at random
    ("holo_gap4", "hololens_dvmvs", ("--frames", "0:120,124:188")),
    ("holo_drop10", "hololens_dvmvs", ("--frames", dropped(188, 0.9, 11))),
    ("tum_drop10", "tum_fr1_rpy", ("--frames", dropped(190, 0.9, 12))),
    ("corr82_drop20", "corr82", ("--frames", dropped(150, 0.8, 13))),
    # the walk there and back (added 2026-12-05, forty-sixth session): at the turn the velocity flips (16 cm, 8 deg
    # off the motion model's prediction), and the way back sees the map of the way there
    ("holo_back", "hololens_dvmvs@there-and-back", ()),
    # the camera upside down (added the same session): the Kinect's rows read from the image's bottom up
    ("tum_flip", "tum_fr1_rpy@upside-down", ()),
    # recovery (added 2026-12-06, fiftieth session): the walk carried from frame 99 back to frame 20 (relocalised
    # by what it looks like, or a new segment), and TUM's lens covered for a second (30 frames lost, then placed
    # between the frames around them in the trajectory)
    ("holo_carried", "hololens_dvmvs@carried-back", ()),
    ("tum_covered", "tum_fr1_rpy@covered", ()),
    # a map segment merged (added 2026-12-06, fifty-first session): the walk there and back with the lens covered
    # for frames 60-74 (a new segment 1.8 m and 27 deg off), merged into the first map on the way back
    ("holo_back_covered", "hololens_dvmvs@back-covered", ()),
    # a recording that starts while the camera turns (added 2026-12-07, fifty-eighth session): from frame 15 TUM's
    # first informative frames did not tell the readout's two directions apart, and the one kept on a small lead
    # settled as a global shutter (3.67 deg against 1.22 with the readout the other start frames choose)
    ("tum_from15", "tum_fr1_rpy", ("--frames", "15:190")),
    ("holo_standin", "hololens_dvmvs", ("--depth-model", "standin")),
    ("tum_standin", "tum_fr1_rpy", ("--depth-model", "standin")),
    ("walk_standin", "walk10", ("--depth-model", "standin")),
    ("walk56_standin", "walk56", ("--depth-model", "standin")),
    ("walk56_trueprior", "walk56", ("--depth-model", "true-prior")),
)

# Runs added by --long (or named with --only): whether tracking, the map's scale and memory hold over a path about
# three times the other walks' (about 2.5 minutes each at one thread; the session of 2026-12-02, twenty-seventh).
LONG_RUNS = (
    ("walk71", "walk71", ()),
    ("walk71_standin", "walk71", ("--depth-model", "standin")),
)


VARIANTS = {"reverse": ("--order", "reverse"), "there-and-back": ("--order", "there-and-back"),
            "upside-down": ("--upside-down",), "carried-back": ("--play", "0:100,20:70"),
            "covered": ("--cover", "60:30"), "back-covered": ("--order", "there-and-back", "--cover", "60:15")}
"""``NAME@VARIANT`` datasets: the copy's ``scripts/sequence_copy.py`` arguments."""


def dataset_path(name: str, seqs: Path) -> Path:
    """A run's dataset: a shared sequence, a generator sequence (rendered on first use), or ``NAME@VARIANT``, the
    copy of one of those that ``scripts/sequence_copy.py`` makes with :data:`VARIANTS` (on first use)."""
    base, _, variant = name.partition("@")
    if variant:
        out = seqs / f"{base}@{variant}"
        if not (out / "rgb.txt").exists():
            cmd = [sys.executable, str(Path(__file__).with_name("sequence_copy.py")), str(dataset_path(base, seqs)),
                   str(out), *VARIANTS[variant]]
            print("copying:", " ".join(cmd[1:]), flush=True)
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        return out
    if name in SEQUENCES:
        return SEQUENCES[name].render(seqs)
    return SHARED / name


def run_arguments(extra: tuple[str, ...], passthrough: list[str]) -> list[str]:
    """A run's own arguments and the suite's ``--`` ones, less ``--weights W`` where the run takes its depth from
    the dataset (``--depth-model standin`` refuses weights): ``-- --weights W`` compares networks on the network
    runs and leaves the stand-in runs as they are."""
    args = list(passthrough)
    if "standin" in extra:
        while "--weights" in args:
            i = args.index("--weights")
            del args[i:i + 2]
        args = [a for a in args if not a.startswith("--weights=")]
    return [*extra, *args]


def run_one(name: str, data: Path, extra: tuple[str, ...], out: Path, passthrough: list[str]) -> str:
    folder = out / name
    cmd = ["codeslam", "slam", str(data), "--out", str(folder), "-q", *run_arguments(extra, passthrough)]
    start = time.perf_counter()
    with open(out / f"{name}.log", "w") as log:
        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    return f"{name}: rc {rc}, {time.perf_counter() - start:.0f} s"


def row(folder: Path) -> list[str]:
    """One run's cells: failed, ATE Sim(3) (the never-moving camera's), % of the path, rotation error after the best
    rotation alignment, translation RPE per frame (and after the Sim(3) scale), Sim(3) scale, scale drift (the map's
    scale over the last fifth of the path over its scale over the first; '-' where the camera turns on the spot or
    the run predates it), frames/s."""
    f = folder / "result.json"
    if not f.exists():
        return ["(no result)"] + [""] * 7
    s = json.loads(f.read_text())
    if "ate_sim3_rmse" not in s:
        return [f"{s['tracking_failures']}/{s['frames']}", "(no ground truth)"] + [""] * 6
    path = s.get("path_length_gt") or float("nan")
    drift = s.get("scale_drift")
    return [
        f"{s['tracking_failures']}/{s['frames']}",
        f"{s['ate_sim3_rmse']:.4f} ({s['no_motion_ate_rmse_aligned']:.3f})",
        f"{100 * s['ate_sim3_rmse'] / path:.2f}%",
        f"{s['rot_aligned_rmse_deg']:.2f}",
        f"{1000 * s['rpe_trans_rmse']:.1f} ({1000 * s['rpe_trans_sim3_rmse']:.1f})",
        f"{s['sim3_scale']:.2f}",
        "-" if drift is None else f"{drift:.2f}",
        f"{s['fps']:.2f}",
    ]


def table(outs: list[Path]) -> str:
    """The runs any of ``outs`` holds (a run folder or its log), in the suite's order, one row each."""
    names = [name for name, _, _ in RUNS + LONG_RUNS
             if any((o / name).exists() or (o / f"{name}.log").exists() for o in outs)]
    head = ["failed", "ATE Sim(3) m (never moving)", "of path", "rotation °", "RPE mm (after the scale)", "scale",
            "scale drift", "frames/s"]
    if len(outs) == 1:
        lines = ["| run | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
        lines += [f"| {name} | " + " | ".join(row(outs[0] / name)) + " |" for name in names]
        return "\n".join(lines)
    # side by side: failed, ATE, rotation, scale drift per folder
    cols = [f"{o.name}: {c}" for o in outs for c in ("failed", "ATE Sim(3) m", "rotation °", "scale drift")]
    lines = ["| run | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name in names:
        cells = []
        for o in outs:
            r = row(o / name)
            cells += [r[0], r[1].split(" ")[0], r[3], r[6]]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def selected_runs(only: list[str] | None, long: bool = False) -> list[tuple[str, str, tuple[str, ...]]]:
    """The runs to make, in the suite's order: every one of RUNS (or those ``only`` names), and LONG_RUNS with
    ``long`` (all of them, or those ``only`` names whatever ``long`` says)."""
    runs = [r for r in RUNS if only is None or r[0] in only]
    return runs + [r for r in LONG_RUNS if (long and only is None) or (only is not None and r[0] in only)]


def main() -> None:
    argv = sys.argv[1:]
    passthrough = ["--threads", "1"]
    if "--" in argv:
        i = argv.index("--")
        argv, passthrough = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path, nargs="+", help="Output folder (with --table: one or more to compare).")
    ap.add_argument("--seqs", type=Path, default=Path(os.environ.get("CODESLAM_SEQS", "suite_seqs")),
                    help="Where the generator sequences are rendered (default suite_seqs or $CODESLAM_SEQS).")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", nargs="+", default=None, help="Run only these (names as in the table).")
    ap.add_argument("--long", action="store_true", help="Also the long runs (LONG_RUNS: a 450-frame walk).")
    ap.add_argument("--table", action="store_true", help="Only print the table of existing run folders.")
    args = ap.parse_args(argv)
    if args.table:
        print(table(args.out))
        return
    out = args.out[0]
    out.mkdir(parents=True, exist_ok=True)
    unknown = sorted(set(args.only or ()) - {r[0] for r in RUNS + LONG_RUNS})
    if unknown:
        ap.error(f"--only: no run named {', '.join(unknown)}")
    runs = selected_runs(args.only, args.long)
    datasets = {name: dataset_path(data, args.seqs) for name, data, _ in runs}  # render before timing anything
    (out / "suite.json").write_text(json.dumps({"passthrough": passthrough, "runs": [r[0] for r in runs]}))
    # the longest first, so that two jobs end together
    order = sorted(runs, key=lambda r: r[1].partition("@")[0] in ("hololens_dvmvs", "hh41", "walk71"), reverse=True)
    with ThreadPoolExecutor(args.jobs) as pool:
        for msg in pool.map(lambda r: run_one(r[0], datasets[r[0]], r[2], out, passthrough), order):
            print(msg, flush=True)
    print(table([out]))


if __name__ == "__main__":
    main()
