"""The SLAM runner (the tools layer around :class:`~codeslam.slam.system.CodeSLAM`): it owns the dataset loop,
the resampling of every frame to the depth model's camera (the paper's intrinsics correction, Sec. 5.3), timing,
the ground truth of the processed frames and the output files. The algorithm itself never opens a file; the
evaluation against ground truth is :mod:`codeslam.eval.slam_run` (SLAM never imports evaluation code).

Outputs of :func:`write_outputs` (all written atomically):

* ``trajectory.txt``: every processed frame's final pose, TUM format (camera-to-world), its positions smoothed over
  the whole run (``trajectory_smoothing``, :mod:`codeslam.slam.smoothing`; 0 writes them as placed by the keyframes
  and tracking);
* ``keyframes.txt``: the keyframes' final poses, TUM format; ``keyframes.npz``: their ids, frame indices,
  timestamps, poses, codes, final depth maps, images and camera (for reconstruction), and each keyframe's pose as
  the tracker gave it in the keyframe it was tracked against, before any window solve (``tracked_from``,
  ``T_tracked``);
* ``map.ply``: the keyframes' depths fused into one coloured point cloud (bilateral-filtered, slanted elements
  dropped, as the paper's Fig. 8; :func:`codeslam.recon.fuse`);
* ``result.json``: counts, timings, frames per second and, with ground truth, the metrics;
* ``config.yaml``: the resolved configuration; with ground truth the caller adds ``trajectory.png`` (the aligned
  trajectory, :func:`codeslam.eval.slam_run.plot_run`).

A run is offline by default (every frame, however long each takes) or live (:class:`Live`, ``codeslam slam
--realtime``): the frames arrive at the recording's own times and a frame that arrives while the system is still
busy with an earlier one is skipped, as a camera's frames are when the system falls behind (DSO's realtime mode).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from codeslam.data.base import Sequence
from codeslam.data.frame import Frame
from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera
from codeslam.io import atomic_path, atomic_write, write_json
from codeslam.slam.config import SLAMConfig
from codeslam.slam.keyframes import MAPPING_BUSY
from codeslam.slam.segments import SegmentMerge
from codeslam.slam.system import STATUSES, CodeSLAM, FrameResult
from codeslam.slam.window import MapKeyframe
from codeslam.viz import Visualizer

#: The system's stages, in the order :attr:`FrameResult.timings_ms` reports them, plus the runner's own.
STAGES = ("read", "resample", "features", "track", "relocalise", "merge", "readout", "wait", "decode", "marginalise",
          "window")


@dataclass
class SLAMRun:
    """The outcome of :func:`run_slam`.

    Attributes:
        results: one :class:`FrameResult` per processed frame.
        trajectory: the final poses of the processed frames; keyframe_trajectory: the keyframes'.
        keyframes: every keyframe (marginalised ones with their final depth).
        camera: the camera the system ran in.
        timings_ms: total wall time per stage (:data:`STAGES`) over the run; "read" is the time the loop waited for
            each frame (frames are read one ahead on a thread of their own, :func:`read_ahead`) and, when the
            frames were read without depth, the keyframes' depth read after the run (:func:`read_keyframe_depths`).
        process_s: wall time inside the system; wall_s: of the whole loop (reading and resampling included).
        readout: the online choice of the rolling-shutter readout and its evidence (None: not estimated).
        trajectory_smoothing: the time scale (s) of the spline that smoothed ``trajectory``'s positions (0: none).
        keyframe_tracking: per keyframe, the keyframe it was tracked against and the tracked pose in it
            (:meth:`~codeslam.slam.system.CodeSLAM.keyframe_tracking`).
        merges: the map segments moved into an older map (:class:`~codeslam.slam.segments.SegmentMerge`).
        live: for a live run (:class:`Live`), the frames offered and skipped and the rate they came at; None
            offline.
    """

    results: list[FrameResult]
    trajectory: Trajectory
    keyframe_trajectory: Trajectory
    keyframes: list[MapKeyframe]
    camera: PinholeCamera
    timings_ms: dict[str, float] = field(default_factory=dict)
    process_s: float = 0.0
    wall_s: float = 0.0
    readout: dict | None = None
    trajectory_smoothing: float = 0.0
    keyframe_tracking: list[tuple[int, torch.Tensor | None]] = field(default_factory=list)
    merges: list[SegmentMerge] = field(default_factory=list)
    live: dict | None = None

    @property
    def fps(self) -> float:
        """Frames per second of the system (reading and resampling excluded)."""
        return len(self.results) / self.process_s if self.process_s > 0 else math.inf


def run_slam(
    sequence: Sequence,
    system: CodeSLAM,
    camera: PinholeCamera,
    frames: list[int] | range | None = None,
    visualizer: Visualizer | None = None,
    progress: Callable[[int, int, FrameResult], None] | None = None,
    live: Live | None = None,
) -> SLAMRun:
    """Run ``system`` over the frame indices ``frames`` of ``sequence`` (all when None), in the order given, each
    frame resampled to ``camera``. ``progress(done, total, result)`` is called after every frame. When the system
    never reads the frames' depth (the network's depth model, :attr:`CodeSLAM.reads_frame_depth`) the frames are
    read without it and the keyframes get theirs after the run (:func:`read_keyframe_depths`).

    With ``live`` the frames arrive at the recording's times (:func:`live_frames`): those that come while the
    system is busy are skipped, the system is told the recording's frame period (:attr:`CodeSLAM.frame_period`:
    the frames it gets are unevenly spaced) and no frame is processed twice (a live camera's frames cannot be fed
    again: no rolling-shutter restart, :meth:`CodeSLAM.restart_with_readout`)."""
    frames = range(len(sequence)) if frames is None else frames
    if live is not None:
        frames = list(frames)
        position = {f: k for k, f in enumerate(frames)}
        stamps = np.asarray(sequence.timestamps, dtype=np.float64)[frames]
        if system.frame_period is None:
            system.frame_period = frame_period(stamps)
    if system.camera is None:
        system.camera = camera
    elif system.camera != camera:
        raise CodeSLAMError("the system runs in another camera than the one given to run_slam")
    visualizer = visualizer or Visualizer()
    results: list[FrameResult] = []
    process_s = 0.0
    t_start = time.perf_counter()
    every_depth = system.reads_frame_depth  # else the keyframes' depth only, read after the run
    try:
        with system.tracking_threads():  # parallel: this thread keeps to the tracker's share of the cores
            while True:  # a second pass when the rolling-shutter readout is chosen after some frames
                restart: float | None = None
                feed = (read_ahead(sequence, frames, depth=every_depth) if live is None
                        else live_frames(sequence, frames, live, depth=every_depth))
                try:  # closed at once on a break or an error: no reading thread outlives its pass
                    for n, (frame, read_ms) in enumerate(feed):
                        t1 = time.perf_counter()
                        result = system.process(frame)  # resamples to the system's camera (its "resample" stage)
                        restart = system.readout_restart if live is None else None
                        process_s += time.perf_counter() - t1
                        result.timings_ms["read"] = read_ms
                        results.append(result)
                        visualizer.update(frame, result, system)
                        if progress is not None:  # live: how far through the recording (skipped frames count)
                            done = n + 1 if live is None else position.get(frame.index, n) + 1
                            progress(done, len(frames), result)
                        if restart is not None:
                            break
                finally:
                    feed.close()
                if restart is None:
                    break
                system.restart_with_readout(restart)
                results = []
        t2 = time.perf_counter()
        system.finish()  # the mapping thread's last keyframe (parallel mode)
        process_s += time.perf_counter() - t2
    except BaseException:
        system.close()  # no mapping thread outlives a failed run
        raise
    totals = dict.fromkeys(STAGES, 0.0)
    for r in results:  # stage times once mapping has finished (a keyframe's mapping is added to its frame)
        for k, v in r.timings_ms.items():
            totals[k] = totals.get(k, 0.0) + v
    if not every_depth and sequence.has_depth:
        totals["read"] += read_keyframe_depths(sequence, system)
    visualizer.close()
    return SLAMRun(
        results=results, trajectory=system.trajectory(), keyframe_trajectory=system.keyframe_trajectory(),
        keyframes=list(system.keyframes), camera=camera, timings_ms=totals, process_s=process_s,
        wall_s=time.perf_counter() - t_start, readout=system.readout_summary(),
        trajectory_smoothing=float(system.config.trajectory_smoothing), keyframe_tracking=system.keyframe_tracking(),
        merges=list(system.merges),
        live=None if live is None else live.summary(stamps, len(results)),
    )


@dataclass(frozen=True)
class Live:
    """How a live run's frames arrive (:func:`live_frames`): frame k at ``(t_k - t_0) / speed`` seconds after the
    run starts, ``t`` the recording's timestamps; ``clock`` and ``sleep`` are the stopwatch and the wait (seconds;
    a test passes its own)."""

    speed: float = 1.0
    clock: Callable[[], float] = time.perf_counter
    sleep: Callable[[float], None] = time.sleep

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise CodeSLAMError(f"a live run's speed must be a positive number, got {self.speed}")

    def summary(self, stamps: np.ndarray, processed: int) -> dict:
        """What a live run over frames at ``stamps`` (seconds) did, having processed ``processed`` of them."""
        span = float(stamps[-1] - stamps[0]) / self.speed if len(stamps) > 1 else 0.0
        return {"speed": self.speed, "frames_offered": int(len(stamps)), "frames_processed": processed,
                "frames_skipped": int(len(stamps)) - processed, "duration_s": span,
                "offered_fps": (len(stamps) - 1) / span if span > 0 else math.inf}


def frame_period(stamps: np.ndarray) -> float | None:
    """The median interval (s) of increasing timestamps: a camera's frame period; None for fewer than two frames or
    intervals that are not positive."""
    steps = np.diff(np.asarray(stamps, dtype=np.float64))
    if len(steps) == 0 or not np.all(np.isfinite(steps)):
        return None
    period = float(np.median(steps))
    return period if period > 0 else None


def live_schedule(stamps: np.ndarray, taken: int, now: float, speed: float) -> tuple[int, float]:
    """The frame a live run takes next: ``stamps`` (N,) the offered frames' timestamps, ``taken`` the position of
    the last frame taken (-1 before the first), ``now`` the seconds since the run started. Frame k arrives at
    ``(stamps[k] - stamps[0]) / speed``; the newest frame that has arrived after the last one taken is taken (those
    between are skipped), or, when none has, the next one once it arrives. Returns (its position, the seconds to
    wait for it); the position is N when every frame has been offered."""
    nxt = taken + 1
    if nxt >= len(stamps):
        return len(stamps), 0.0
    arrival = (np.asarray(stamps[nxt:], dtype=np.float64) - float(stamps[0])) / speed
    come = int(np.searchsorted(arrival, now, side="right"))  # frames nxt .. nxt + come - 1 have arrived
    if come == 0:
        return nxt, float(arrival[0]) - now
    return nxt + come - 1, 0.0


def live_frames(sequence: Sequence, frames: list[int] | range, live: Live,
                depth: bool = True) -> Iterator[tuple[Frame, float]]:
    """The frames ``frames`` of ``sequence`` as a live camera delivers them to a system that asks for the next one
    when it is done with the last (:func:`live_schedule`, on ``live``'s clock from the first request): each with
    the ms the caller waited for it (for its arrival and its reading). A frame is read (decoded, undistorted) when
    it is taken, so its reading counts against the system, as a camera driver's decoding does; skipped frames are
    never read."""
    frames = list(frames)
    stamps = np.asarray(sequence.timestamps, dtype=np.float64)[frames] if frames else np.zeros(0)
    if not np.all(np.diff(stamps) >= 0):  # a camera's frames come in time order (NaN times fail too)
        raise CodeSLAMError("a live run needs its frames in time order, with finite timestamps")
    start = live.clock()
    taken = -1
    while True:
        t0 = live.clock()
        taken, wait = live_schedule(stamps, taken, t0 - start, live.speed)
        if taken >= len(frames):
            return
        if wait > 0:
            live.sleep(wait)
        frame = sequence.frame(frames[taken], depth)
        yield frame, 1e3 * (live.clock() - t0)


def read_ahead(sequence: Sequence, frames: list[int] | range, depth: bool = True) -> Iterator[tuple[Frame, float]]:
    """The frames ``frames`` of ``sequence`` in order, each with the ms the caller waited for it: frame n + 1 is
    read (decoded, undistorted) on a thread of its own while the caller works on frame n, as a camera driver or
    a data loader delivers frames. Image decoding and torch's kernels release the GIL, so on a TUM frame the
    caller waits for little of the 16 ms a read takes alone. One frame ahead at most: memory stays bounded and a
    reading error surfaces at the frame it belongs to. The reading thread runs one torch thread (torch's count is
    per thread), so it takes no cores from the tracking and mapping threads' share. ``depth=False``: the frames
    come without their depth (:meth:`~codeslam.data.base.Sequence.frame`)."""

    frames = list(frames)
    if not frames:
        return
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="codeslam-read", initializer=torch.set_num_threads,
                              initargs=(1,))
    try:
        ahead = pool.submit(sequence.frame, frames[0], depth)
        for k in range(len(frames)):
            t0 = time.perf_counter()
            frame = ahead.result()
            waited = 1e3 * (time.perf_counter() - t0)
            if k + 1 < len(frames):
                ahead = pool.submit(sequence.frame, frames[k + 1], depth)
            yield frame, waited
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def read_keyframe_depths(sequence: Sequence, system: CodeSLAM) -> float:
    """Give every keyframe of ``system`` without ``depth_gt`` the dataset's depth of its frame, in its view
    (:meth:`~codeslam.slam.system.CodeSLAM.keyframe_depth`): what a run on frames read without depth keeps for the
    report (the map's scale against the dataset's, the keyframes' depth maps). Returns the ms it took."""
    t0 = time.perf_counter()
    for kf in system.keyframes:
        if kf.depth_gt is None:
            depth = sequence.depth(kf.frame_index)
            if depth is not None:
                kf.depth_gt = system.keyframe_depth(kf, depth)
    return 1e3 * (time.perf_counter() - t0)


# ---- ground truth -------------------------------------------------------------------------------------------
def ground_truth(sequence: Sequence, frames: list[int] | range) -> Trajectory | None:
    """The ground-truth poses of the processed frames that have one, or None without ground truth."""
    gt = sequence.gt_poses
    if gt is None:
        return None
    idx = [i for i in frames if bool(torch.isfinite(gt[i]).all())]
    if not idx:
        return None
    return Trajectory(sequence.timestamps[idx], gt[idx])


def summarise(run: SLAMRun, evaluation: dict | None = None, **extra) -> dict:
    """The JSON-ready summary of a run (``extra`` keys are added as they are)."""
    res = run.results
    n = len(res)
    out = {
        "frames": n,
        "first_frame": res[0].index,
        "last_frame": res[-1].index,
        "keyframes": len(run.keyframes),
        "keyframe_frames": [k.frame_index for k in run.keyframes],
        "tracking_failures": sum(not r.tracking_ok for r in res),
        "failed_frames": [r.index for r in res if not r.tracking_ok],
        "marginalised": sum(r.marginalised_id is not None for r in res),
        "width": run.camera.width,
        "height": run.camera.height,
        "code_size": int(run.keyframes[0].network_code.shape[0]),
        "code_directions": int(run.keyframes[0].code.shape[0]),
        "fps": run.fps,
        "fps_with_io": n / run.wall_s if run.wall_s > 0 else math.inf,
        "process_s": run.process_s,
        "wall_s": run.wall_s,
        "ms_per_frame": {k: v / n for k, v in run.timings_ms.items()},
        "ms_per_keyframe": {k: run.timings_ms.get(k, 0.0) / max(len(run.keyframes) - 1, 1)
                            for k in ("decode", "marginalise", "window")},
        "status_counts": {s: sum(r.status == s for r in res) for s in STATUSES},
        "failures_by_reason": failures_by_reason(res),
        "segments": 1 + max(r.segment for r in res),
        "segment_merges": [{"segment": m.segment, "into": m.into, "frame": m.frame_index, "keyframe": m.keyframe_id,
                            "inliers": m.inliers} for m in run.merges],
        "window_rollbacks": sum(bool(r.window is not None and r.window.rejected) or bool(r.rolled_back)
                                for r in res),
        "mapping_statistics": mapping_statistics(res),
        "map_scale": map_scale(run.keyframes),
    }
    if run.readout is not None:
        out["rolling_shutter"] = run.readout
    if run.live is not None:
        out["live"] = run.live
    out["trajectory_smoothing_s"] = run.trajectory_smoothing
    if evaluation is not None:
        out.update(evaluation)
    out.update(extra)
    return out


def mapping_statistics(results: list[FrameResult]) -> dict:
    """How the window solves went: how many ran, how many the tracker cut short (parallel mode: an urgent keyframe
    stops the running solve after its current iteration, ``window.interruptible``) and how many of those before
    their first iteration, the median iterations per solve, and the frames whose keyframe was refused while the
    mapping thread was busy (``keyframes.take_when_busy`` off; a frame asks again on the next one). Measured on the
    HoloLens walk in parallel mode on two cores: 47 of 50 solves cut short, 18 before their first iteration, and
    0.50-0.69 m against 0.14 m sequential; a user should see that in the summary."""
    solves = [r.window for r in results if r.window is not None]
    cut = [w for w in solves if w.interrupted]
    iterations = [w.iterations for w in solves]
    return {
        "window_solves": len(solves),
        "cut_short": len(cut),
        "cut_before_first_iteration": sum(w.iterations == 0 for w in cut),
        "median_iterations": float(np.median(iterations)) if iterations else 0.0,
        "refused_busy": sum(r.keyframe is not None and r.keyframe.reason == MAPPING_BUSY for r in results),
    }


def map_scale(keyframes: list[MapKeyframe]) -> dict | None:
    """Where the window left the map's scale: per keyframe the median over its pixels of its depth after the
    window over the network's zero-code depth (and over the dataset's depth, where it has one), the median of
    those over the keyframes; None without a zero-code depth. Monocular scale is held only by the network's
    prior, so a ratio far from 1 says the window fitted the codes at another scale: measured on the generator's
    walks, 0.44-0.55, the map at half its true size (docs/results/slam_table.md, twenty-first session). A user
    without ground truth sees it here."""

    prior: list[float] = []
    truth: list[float] = []
    for k in keyframes:
        refs = [(out, r) for out, r in ((prior, k.depth_zero), (truth, k.depth_gt)) if r is not None]
        if not refs:
            continue
        d = k.depth_map().detach().cpu().float()  # decoded once per keyframe
        for out, ref in refs:
            ref = ref.detach().cpu().float()
            ok = torch.isfinite(d) & (d > 0) & torch.isfinite(ref) & (ref > 0)
            if bool(ok.any()):
                out.append(float((d[ok] / ref[ok]).median()))
    if not prior:
        return None
    return {"keyframes": len(prior), "depth_over_prior": float(np.median(prior)),
            "depth_over_truth": float(np.median(truth)) if truth else None}


def failure_kind(reason: str) -> str:
    """A failure reason without its numbers ('overlap 0.12 below 0.30' -> 'overlap below'), so that reasons can
    be counted."""
    words = [w for w in reason.replace("(", " ").replace(")", " ").split() if not _is_number(w)]
    return " ".join(words[:4]) or "unknown"


def _is_number(word: str) -> bool:
    try:
        float(word.strip(",;:%"))
    except ValueError:
        return False
    return True


def failures_by_reason(results: list[FrameResult]) -> dict[str, int]:
    """Frames whose pose is only predicted, counted by the kind of their failure reason."""
    out: dict[str, int] = {}
    for r in results:
        if not r.tracking_ok:
            k = failure_kind(r.reason)
            out[k] = out.get(k, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


#: Columns of the per-frame log ``frames.csv``.
FRAME_LOG_COLUMNS = ("frame", "timestamp", "status", "reason", "is_keyframe", "keyframe_reason", "ref_keyframe",
                     "segment", "source", "photometric_reason", "overlap", "inlier_ratio", "explained",
                     "feature_inliers", "feature_matches", "residual", "texture", "iterations", "window_ms",
                     "window_iterations",
                     "window_interrupted", "window_rejected", "rolled_back", "track_ms", "total_ms")


def frame_log_rows(results: list[FrameResult]) -> list[dict]:
    """One row per frame for ``frames.csv`` (:data:`FRAME_LOG_COLUMNS`): what the tracker saw and decided."""
    rows = []
    for r in results:
        t, w = r.track, r.window
        nan = float("nan")
        rows.append({
            "frame": r.index, "timestamp": f"{r.timestamp:.6f}", "status": r.status,
            "reason": "" if r.is_keyframe else r.reason, "is_keyframe": int(r.is_keyframe),
            "keyframe_reason": r.reason if r.is_keyframe else "", "ref_keyframe": r.keyframe_id,
            "segment": r.segment, "source": r.source,
            "photometric_reason": t.photometric_reason if t and r.tracking_ok else "",  # why 'features' alone
            "overlap": _fmt(t.overlap if t else nan), "inlier_ratio": _fmt(t.inlier_ratio if t else nan),
            "explained": _fmt(t.explained if t else nan), "feature_inliers": t.feature_inliers if t else 0,
            "feature_matches": t.feature_matches if t else 0, "residual": _fmt(t.residual if t else nan),
            "texture": _fmt(t.texture if t else nan),
            "iterations": t.iterations if t else 0, "window_ms": _fmt(r.timings_ms.get("window", nan) if w else nan, 1),
            "window_iterations": w.iterations if w else "", "window_interrupted": int(w.interrupted) if w else "",
            "window_rejected": w.rejected if w else "", "rolled_back": r.rolled_back,
            "track_ms": _fmt(r.timings_ms.get("track", 0.0), 2), "total_ms": _fmt(sum(r.timings_ms.values()), 2),
        })
    return rows


def _fmt(x: float, digits: int = 4) -> str:
    return "" if not math.isfinite(x) else f"{x:.{digits}f}"


def write_frame_log(path: str | Path, results: list[FrameResult]) -> None:
    """The per-frame log as CSV (atomically)."""
    import csv

    with atomic_write(path) as f:
        w = csv.DictWriter(f, fieldnames=list(FRAME_LOG_COLUMNS), lineterminator="\n")
        w.writeheader()
        w.writerows(frame_log_rows(results))


# ---- outputs --------------------------------------------------------------------------------------------------
def _rgb(kf: MapKeyframe) -> np.ndarray:
    """(3, H, W) float32 colour image of a keyframe (grey repeated when it has no colour)."""
    img = kf.view.image.detach().cpu().float()
    img = img if img.dim() == 3 else img[None]
    return img.expand(3, -1, -1).numpy() if img.shape[0] == 1 else img.numpy()


def fuse_keyframes(keyframes: list[MapKeyframe], camera: PinholeCamera):
    """The keyframes' final depths fused into one coloured point cloud (:func:`codeslam.recon.fuse`)."""
    from codeslam.recon import FusionView, fuse

    return fuse([FusionView(torch.from_numpy(_rgb(k)), k.depth_map().detach().cpu().float(), camera, k.T_wc)
                 for k in keyframes])


def write_keyframes(path: str | Path, keyframes: list[MapKeyframe], camera: PinholeCamera,
                    tracking: list[tuple[int, torch.Tensor | None]] | None = None) -> None:
    """The keyframes for reconstruction as an .npz (arrays only, no pickled objects); with ``tracking``
    (:attr:`SLAMRun.keyframe_tracking`) each keyframe's tracked pose in its reference too. Not compressed: its
    float images and depths deflate by under a third (the HoloLens walk's 88 keyframes: 30.4 MB, 21.6 MB
    compressed), and compressing took 1.0 s of that run's whole process against 0.07 s written as they are."""
    depths = np.stack([k.depth_map().detach().cpu().float().numpy() for k in keyframes])  # (K, H, W)
    arrays = {
        "id": np.array([k.id for k in keyframes], dtype=np.int64),
        "frame_index": np.array([k.frame_index for k in keyframes], dtype=np.int64),
        "timestamp": np.array([k.timestamp for k in keyframes], dtype=np.float64),
        "T_wc": np.stack([k.T_wc.numpy() for k in keyframes]),  # (K, 4, 4)
        "code": np.stack([k.network_code.detach().cpu().double().numpy() for k in keyframes]),  # (K, C)
        "depth": depths,
        "image": np.stack([_rgb(k) for k in keyframes]),  # (K, 3, H, W) in [0, 1]
        "camera": np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height]),
        "segment": np.array([k.segment for k in keyframes], dtype=np.int64),
    }
    if tracking is not None:  # the tracker's own pose of each keyframe in its reference (-1 and NaN: none)
        arrays["tracked_from"] = np.array([r for r, _ in tracking], dtype=np.int64)
        arrays["T_tracked"] = np.stack([np.full((4, 4), np.nan) if T is None else T.numpy() for _, T in tracking])
    H, W = depths.shape[1:]
    for name in ("depth_zero", "uncertainty", "depth_gt"):  # NaN where a keyframe has none
        arrays[name] = np.stack([np.full((H, W), np.nan, np.float32) if getattr(k, name) is None
                                 else getattr(k, name).detach().cpu().float().numpy() for k in keyframes])
    with atomic_path(path) as tmp:
        np.savez(tmp, **arrays)


def write_outputs(
    out_dir: str | Path, run: SLAMRun, config: SLAMConfig, summary: dict, written: dict[str, str] | None = None,
) -> dict[str, str]:
    """Write the run's files into ``out_dir`` (see the module docstring); returns name -> path, including
    ``written``: files the caller already wrote there (e.g. the evaluation's plot). result.json is written last,
    so a run interrupted while writing leaves no summary pointing at missing files."""
    out = Path(out_dir)
    paths = {name: out / name for name in ("trajectory.txt", "keyframes.txt", "keyframes.npz", "config.yaml",
                                           "frames.csv")}
    write_tum(paths["trajectory.txt"], run.trajectory)
    write_frame_log(paths["frames.csv"], run.results)
    write_tum(paths["keyframes.txt"], run.keyframe_trajectory)
    write_keyframes(paths["keyframes.npz"], run.keyframes, run.camera, run.keyframe_tracking)
    with atomic_write(paths["config.yaml"]) as f:
        f.write(config.to_yaml())
    from codeslam.recon.ply import write_ply

    paths["map.ply"] = out / "map.ply"
    write_ply(paths["map.ply"], fuse_keyframes(run.keyframes, run.camera),
              comments=[f"codeslam slam: {len(run.keyframes)} keyframes fused"])
    paths["result.json"] = out / "result.json"
    files = {**(written or {}), **{k: str(v) for k, v in paths.items()}}
    write_json(paths["result.json"], {**summary, "outputs": files})
    return files
