"""The SLAM runner (the tools layer around :class:`~codeslam.slam.system.CodeSLAM`): it owns the dataset loop,
the resampling of every frame to the depth model's camera (the paper's intrinsics correction, Sec. 5.3), timing,
the ground truth of the processed frames and the output files. The algorithm itself never opens a file; the
evaluation against ground truth is :mod:`codeslam.eval.slam_run` (SLAM never imports evaluation code).

Outputs of :func:`write_outputs` (all written atomically):

* ``trajectory.txt``: every processed frame's final pose, TUM format (camera-to-world);
* ``keyframes.txt``: the keyframes' final poses, TUM format; ``keyframes.npz``: their ids, frame indices,
  timestamps, poses, codes, final depth maps, images and camera (for reconstruction);
* ``map.ply``: the keyframes' depths fused into one coloured point cloud (bilateral-filtered, slanted elements
  dropped, as the paper's Fig. 8; :func:`codeslam.recon.fuse`);
* ``result.json``: counts, timings, frames per second and, with ground truth, the metrics;
* ``config.yaml``: the resolved configuration; with ground truth the caller adds ``trajectory.png`` (the aligned
  trajectory, :func:`codeslam.eval.slam_run.plot_run`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from codeslam.data.base import Sequence
from codeslam.data.frame import resample_frame
from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.geometry.camera import PinholeCamera
from codeslam.io import atomic_path, atomic_write, write_json
from codeslam.slam.config import SLAMConfig
from codeslam.slam.system import CodeSLAM, FrameResult
from codeslam.slam.window import MapKeyframe
from codeslam.viz import Visualizer

#: The system's stages, in the order :attr:`FrameResult.timings_ms` reports them, plus the runner's own.
STAGES = ("read", "resample", "track", "decode", "marginalise", "window")


@dataclass
class SLAMRun:
    """The outcome of :func:`run_slam`.

    Attributes:
        results: one :class:`FrameResult` per processed frame.
        trajectory: the final poses of the processed frames; keyframe_trajectory: the keyframes'.
        keyframes: every keyframe (marginalised ones with their final depth).
        camera: the camera the system ran in.
        timings_ms: total wall time per stage (:data:`STAGES`) over the run.
        process_s: wall time inside the system; wall_s: of the whole loop (reading and resampling included).
    """

    results: list[FrameResult]
    trajectory: Trajectory
    keyframe_trajectory: Trajectory
    keyframes: list[MapKeyframe]
    camera: PinholeCamera
    timings_ms: dict[str, float] = field(default_factory=dict)
    process_s: float = 0.0
    wall_s: float = 0.0

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
) -> SLAMRun:
    """Run ``system`` over the frame indices ``frames`` of ``sequence`` (all when None), in the order given, each
    frame resampled to ``camera``. ``progress(done, total, result)`` is called after every frame."""
    frames = range(len(sequence)) if frames is None else frames
    visualizer = visualizer or Visualizer()
    totals = dict.fromkeys(STAGES, 0.0)
    results = []
    process_s = 0.0
    t_start = time.perf_counter()
    for n, i in enumerate(frames):
        t0 = time.perf_counter()
        raw = sequence[i]
        t1 = time.perf_counter()
        frame = resample_frame(raw, camera)
        t2 = time.perf_counter()
        result = system.process(frame)
        t3 = time.perf_counter()
        process_s += t3 - t2
        totals["read"] += 1e3 * (t1 - t0)
        totals["resample"] += 1e3 * (t2 - t1)
        for k, v in result.timings_ms.items():
            totals[k] = totals.get(k, 0.0) + v
        results.append(result)
        visualizer.update(frame, result, system)
        if progress is not None:
            progress(n + 1, len(frames), result)
    visualizer.close()
    return SLAMRun(
        results=results, trajectory=system.trajectory(), keyframe_trajectory=system.keyframe_trajectory(),
        keyframes=list(system.keyframes), camera=camera, timings_ms=totals, process_s=process_s,
        wall_s=time.perf_counter() - t_start,
    )


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
        "code_size": int(run.keyframes[0].code.shape[0]),
        "fps": run.fps,
        "fps_with_io": n / run.wall_s if run.wall_s > 0 else math.inf,
        "process_s": run.process_s,
        "wall_s": run.wall_s,
        "ms_per_frame": {k: v / n for k, v in run.timings_ms.items()},
        "ms_per_keyframe": {k: run.timings_ms.get(k, 0.0) / max(len(run.keyframes) - 1, 1)
                            for k in ("decode", "marginalise", "window")},
    }
    if evaluation is not None:
        out.update(evaluation)
    out.update(extra)
    return out


# ---- outputs --------------------------------------------------------------------------------------------------
def _rgb(kf: MapKeyframe) -> np.ndarray:
    """(3, H, W) float32 colour image of a keyframe (grey repeated when it has no colour)."""
    img = kf.keyframe.image.detach().cpu().float()
    img = img if img.dim() == 3 else img[None]
    return img.expand(3, -1, -1).numpy() if img.shape[0] == 1 else img.numpy()


def fuse_keyframes(keyframes: list[MapKeyframe], camera: PinholeCamera):
    """The keyframes' final depths fused into one coloured point cloud (:func:`codeslam.recon.fuse`)."""
    from codeslam.recon import FusionView, fuse

    return fuse([FusionView(torch.from_numpy(_rgb(k)), k.depth_map().detach().cpu().float(), camera, k.T_wc)
                 for k in keyframes])


def write_keyframes(path: str | Path, keyframes: list[MapKeyframe], camera: PinholeCamera) -> None:
    """The keyframes for reconstruction as a compressed .npz (arrays only, no pickled objects)."""
    depths = np.stack([k.depth_map().detach().cpu().float().numpy() for k in keyframes])  # (K, H, W)
    arrays = {
        "id": np.array([k.id for k in keyframes], dtype=np.int64),
        "frame_index": np.array([k.frame_index for k in keyframes], dtype=np.int64),
        "timestamp": np.array([k.timestamp for k in keyframes], dtype=np.float64),
        "T_wc": np.stack([k.T_wc.numpy() for k in keyframes]),  # (K, 4, 4)
        "code": np.stack([k.code.detach().cpu().double().numpy() for k in keyframes]),  # (K, C)
        "depth": depths,
        "image": np.stack([_rgb(k) for k in keyframes]),  # (K, 3, H, W) in [0, 1]
        "camera": np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height]),
    }
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, **arrays)


def write_outputs(
    out_dir: str | Path, run: SLAMRun, config: SLAMConfig, summary: dict, written: dict[str, str] | None = None,
) -> dict[str, str]:
    """Write the run's files into ``out_dir`` (see the module docstring); returns name -> path, including
    ``written``: files the caller already wrote there (e.g. the evaluation's plot). result.json is written last,
    so a run interrupted while writing leaves no summary pointing at missing files."""
    out = Path(out_dir)
    paths = {name: out / name for name in ("trajectory.txt", "keyframes.txt", "keyframes.npz", "config.yaml")}
    write_tum(paths["trajectory.txt"], run.trajectory)
    write_tum(paths["keyframes.txt"], run.keyframe_trajectory)
    write_keyframes(paths["keyframes.npz"], run.keyframes, run.camera)
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
