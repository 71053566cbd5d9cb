"""Reading a SLAM run's folder: everything the report needs comes from these files alone, so ``codeslam report
RUN_DIR`` can rebuild a report long after the run.

Files (written by :mod:`codeslam.slam.pipeline` and, for ``groundtruth.txt``, by :func:`write_groundtruth`):

* ``result.json`` (required): the run's summary (counts, timings, metrics with ground truth);
* ``trajectory.txt`` (required): every processed frame's pose, TUM format;
* ``groundtruth.txt``: the ground-truth poses of the processed frames that have one, TUM format;
* ``keyframes.npz``: keyframe poses, images and depth maps (``depth_zero``, ``uncertainty``, ``depth_gt`` when the
  run stored them);
* ``map.ply``: the fused point cloud;
* ``frames.csv``: one row per processed frame (status, reason, keyframe flag, tracking statistics).

A missing optional file leaves its field None; the report then says what is not available.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from codeslam.data.trajectory import Trajectory, read_tum, write_tum
from codeslam.errors import DatasetError
from codeslam.recon.fusion import PointCloud

RESULT_FILE = "result.json"
TRAJECTORY_FILE = "trajectory.txt"
GROUNDTRUTH_FILE = "groundtruth.txt"
KEYFRAMES_FILE = "keyframes.npz"
MAP_FILE = "map.ply"
FRAMES_FILE = "frames.csv"
REPORT_FILE = "report.html"

#: frames.csv columns read as numbers (an empty cell is NaN); the others stay text.
FRAME_NUMERIC_COLUMNS = (
    "frame", "timestamp", "is_keyframe", "ref_keyframe", "segment", "overlap", "inlier_ratio", "explained",
    "feature_inliers", "feature_matches", "residual", "texture", "iterations", "window_ms", "track_ms", "total_ms",
)


@dataclass
class RunFiles:
    """The contents of a run folder.

    Attributes:
        root: the folder.
        summary: ``result.json``.
        trajectory: every processed frame's estimated ``T_wc`` (map frame: the first camera).
        groundtruth: the processed frames' ground-truth ``T_wc`` (world frame of the dataset), or None.
        keyframes: the arrays of ``keyframes.npz`` by name, or None.
        cloud: the fused map, or None.
        frames: ``frames.csv`` by column (numeric columns as float arrays, the others as lists of str), or None.
    """

    root: Path
    summary: dict
    trajectory: Trajectory
    groundtruth: Trajectory | None = None
    keyframes: dict[str, np.ndarray] | None = None
    cloud: PointCloud | None = None
    frames: dict[str, np.ndarray | list[str]] | None = None

    @property
    def has_metrics(self) -> bool:
        """Whether the run was evaluated against ground truth."""
        return "ate_se3_rmse" in self.summary


def write_groundtruth(run_dir: str | Path, gt: Trajectory | None) -> Path | None:
    """Store the ground truth of the processed frames in the run folder (nothing without one), so the report can
    be rebuilt from the folder alone."""
    if gt is None or len(gt) == 0:
        return None
    path = Path(run_dir) / GROUNDTRUTH_FILE
    write_tum(path, gt)
    return path


def read_summary(path: Path) -> dict:
    """``result.json`` as a dict; DatasetError when missing or not a JSON object."""
    if not path.is_file():
        raise DatasetError(f"{path.parent} is not a codeslam run folder: {path.name} is missing")
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DatasetError(f"cannot read {path}: {' '.join(str(e).split())}") from None
    if not isinstance(summary, dict):
        raise DatasetError(f"{path} does not hold a JSON object")
    return summary


def read_keyframes(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays of ``keyframes.npz`` (None when absent); DatasetError when unreadable."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as e:
        raise DatasetError(f"cannot read {path}: {' '.join(str(e).split())}") from None


def read_frames_csv(path: Path) -> dict[str, np.ndarray | list[str]] | None:
    """``frames.csv`` by column (None when absent); DatasetError when it has no ``frame`` and ``status`` columns
    or a numeric cell is not a number."""
    if not path.is_file():
        return None
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DatasetError(f"cannot read {path}: {' '.join(str(e).split())}") from None
    if not rows or not {"frame", "status"} <= set(rows[0]):
        raise DatasetError(f"{path} needs a header with at least 'frame' and 'status' and one row per frame")
    out: dict[str, np.ndarray | list[str]] = {}
    for col in rows[0]:
        cells = [(r.get(col) or "").strip() for r in rows]
        if col in FRAME_NUMERIC_COLUMNS:
            try:
                out[col] = np.array([float(c) if c else math.nan for c in cells], dtype=np.float64)
            except ValueError:
                raise DatasetError(f"{path}: column {col!r} holds a value that is not a number") from None
        else:
            out[col] = cells
    return out


def load_run(run_dir: str | Path) -> RunFiles:
    """Read a run folder (see the module docstring); DatasetError when it is not one or a file is unreadable."""
    from codeslam.recon.ply import read_ply

    root = Path(run_dir)
    if not root.is_dir():
        raise DatasetError(f"run folder not found: {root}")
    summary = read_summary(root / RESULT_FILE)
    if not (root / TRAJECTORY_FILE).is_file():
        raise DatasetError(f"{root} is not a complete codeslam run folder: {TRAJECTORY_FILE} is missing")
    trajectory = read_tum(root / TRAJECTORY_FILE)
    gt_path = root / GROUNDTRUTH_FILE
    groundtruth = read_tum(gt_path) if gt_path.is_file() else None
    cloud = read_ply(root / MAP_FILE) if (root / MAP_FILE).is_file() else None
    return RunFiles(root, summary, trajectory, groundtruth, read_keyframes(root / KEYFRAMES_FILE), cloud,
                    read_frames_csv(root / FRAMES_FILE))


def frame_statuses(run: RunFiles) -> tuple[np.ndarray, list[str], list[str]]:
    """(frame indices (N,), status per frame, reason per frame): from ``frames.csv`` when the run has one;
    otherwise derived from the summary (a frame in ``failed_frames`` is 'failed', the others 'tracked', the first
    'initialising'), with the frame indices spread evenly from ``first_frame`` to ``last_frame``."""
    if run.frames is not None:
        reasons = run.frames.get("reason") or [""] * len(run.frames["status"])
        return np.asarray(run.frames["frame"]).astype(np.int64), list(run.frames["status"]), list(reasons)
    s = run.summary
    n = int(s.get("frames", len(run.trajectory)))
    first, last = int(s.get("first_frame", 0)), int(s.get("last_frame", n - 1))
    idx = np.rint(np.linspace(first, last, n)).astype(np.int64) if n > 1 else np.array([first], dtype=np.int64)
    failed = {int(i) for i in s.get("failed_frames", [])}
    status = ["failed" if int(i) in failed else "tracked" for i in idx]
    if n and status[0] == "tracked":
        status[0] = "initialising"
    return idx, status, ["" for _ in idx]


def mapping_text(summary: dict) -> str | None:
    """The summary's line on the window solves (``result.json``'s ``mapping`` mode and ``mapping_statistics``),
    how many were undone (``window_rollbacks``: a solve the window's checks rejected, or one after which the next
    frame could not be tracked; ``frames.csv`` says why on the keyframe's row), a hint when parallel mapping fell
    behind the camera (more than half of its solves cut short), and the option that takes the keyframes it refused;
    None for a run written before the statistics were. The undone solves are the map's trouble spots: on the
    HoloLens walk none at every frame, 5-11 of 50 at every second frame and 10-13 of 51 in parallel mode
    (docs/results/slam_table.md, session of 2026-12-04, fortieth)."""
    m, mode = summary.get("mapping_statistics"), str(summary.get("mapping", "?"))
    if not isinstance(m, dict):
        return None
    it = m["median_iterations"]
    text = f"{mode}: {m['window_solves']} window solves, median {it:g} iteration{'' if it == 1 else 's'}"
    if m["cut_short"]:
        text += (f"; {m['cut_short']} cut short by the tracker ({m['cut_before_first_iteration']} before their "
                 f"first iteration)")
    if n := summary.get("window_rollbacks"):
        text += f"; {n} undone by the window's checks (window_rejected and rolled_back in frames.csv)"
    if m["refused_busy"]:  # the option that takes them: measured to hold the parallel HoloLens map at 1.3-1.8x
        # the wall time (docs/results/slam_table.md, fortieth session)
        text += (f"; {m['refused_busy']} frames asked for a keyframe while the mapping thread was busy "
                 "(keyframes: {take_when_busy: true} in a --config takes them)")
    if mode == "parallel" and 2 * m["cut_short"] > m["window_solves"]:
        text += "; the mapping fell behind the camera (--sequential solves every window in full)"
    return text


def live_text(summary: dict) -> str | None:
    """The summary's line on a live run (``result.json``'s ``live``, ``codeslam slam --realtime``): how many of the
    frames that came were processed and how many skipped while the system was busy; None for an offline run."""
    live = summary.get("live")
    if not isinstance(live, dict):
        return None
    speed = "" if live["speed"] == 1 else f" ({live['speed']:g} times the recording's rate)"
    return (f"{live['frames_processed']} of {live['frames_offered']} frames processed, {live['frames_skipped']} "
            f"skipped while the system was busy; they came at {live['offered_fps']:.1f} frames/s{speed}")


#: A map whose keyframes end outside this range of the network's zero-code depth gets the summary's hint.
MAP_SCALE_HINT = (0.67, 1.5)


def map_scale_text(summary: dict) -> str | None:
    """The summary's line on where the window left the map's scale (``result.json``'s ``map_scale``), with a hint
    when it is far from the network's prediction; None for a run written before it or without a zero code."""
    m = summary.get("map_scale")
    if not isinstance(m, dict):
        return None
    r = m["depth_over_prior"]
    text = f"keyframe depths {r:.2f} x the network's zero-code prediction (median over {m['keyframes']} keyframes)"
    if m.get("depth_over_truth") is not None:
        text += f", {m['depth_over_truth']:.2f} x the dataset's depth"
    lo, hi = MAP_SCALE_HINT
    if not lo <= r <= hi:
        text += ("; the window moved the map's scale away from the network's (monocular scale is held only by "
                 "its prior)")
    return text


def trajectory_text(smoothing_s: float) -> str:
    """The summary's line on how ``trajectory.txt`` was written (``result.json``'s ``trajectory_smoothing_s``)."""
    return (f"positions smoothed over the whole run (a spline, time scale {smoothing_s:g} s); rotations, keyframes "
            f"and the live poses as estimated")
