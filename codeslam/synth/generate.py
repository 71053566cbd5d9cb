"""Synthetic RGB-D sequences in the TUM RGB-D layout.

``OUT/scene_000/`` holds ``rgb/<t>.png`` (8-bit RGB), ``depth/<t>.png`` (16-bit, value / 5000 = metres,
0 = invalid), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (``t tx ty tz qx qy qz qw``, camera-to-world)
and ``calib.txt`` (``fx fy cx cy``), which :class:`codeslam.data.tum.TumSequence` reads unchanged. Colour and
depth share timestamps (``SEQUENCE_T0 + i / fps``) and the ground truth is given at exactly those times.

Default image size 256x192 (the CLI's; half a Kinect frame per side, twice the network's 128x96 so that
readers can downsample), rendered with 2x2 anti-aliasing by the CLI: about 1.5-2 frames per CPU second,
so ``--scenes 2 --frames 40`` takes about a minute on one core (``--workers`` splits the scenes).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from codeslam.data.imageio import write_depth_png, write_rgb_png
from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, canonical_camera
from codeslam.io import atomic_write, ensure_dir
from codeslam.synth.motion import get_preset, preset_trajectory
from codeslam.synth.render import RenderConfig, render
from codeslam.synth.scene import build_scene
from codeslam.synth.shards import DEPTH_FACTOR
from codeslam.synth.trajectory import random_trajectory

#: Timestamp (seconds) of the first frame of every sequence.
SEQUENCE_T0 = 1000.0
#: Default frame rate of the sequences (a Kinect's).
DEFAULT_FPS = 30.0
#: Frames rendered per call (bounds memory; results do not depend on it).
FRAME_BATCH = 8


def scene_seed(seed: int, index: int) -> int:
    """Seed of sequence ``index`` of a run with base ``seed``."""
    return int(np.random.SeedSequence([seed, index, 0x5E9]).generate_state(1, np.uint32)[0])


def generate_sequence(
    out_dir: str | Path,
    seed: int,
    frames: int,
    camera: PinholeCamera | None = None,
    config: RenderConfig = RenderConfig(),
    fps: float = DEFAULT_FPS,
    motion: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict:
    """Build the room of ``seed``, move a camera through it and write the sequence to ``out_dir``.

    ``motion`` names a preset of :mod:`codeslam.synth.motion` (``handheld``, ``walk``, ``fast-turn``: a person
    carrying the camera, in a room of the preset's size); None keeps the default slow path (and every seed's
    bytes as before presets existed). ``progress(frames_written)`` is called after every batch of frames.
    Returns a summary: path, frames, seconds, primitives, path_length (metres), motion.
    """
    if frames < 1:
        raise CodeSLAMError(f"--frames must be at least 1, got {frames}")
    if not (math.isfinite(fps) and fps > 0):
        raise CodeSLAMError(f"--fps must be positive, got {fps}")
    preset = None if motion is None else get_preset(motion)
    camera = canonical_camera(256, 192) if camera is None else camera
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7247]))
    if preset is None:
        scene = build_scene(seed)
        poses = random_trajectory(scene, frames, rng, fps=fps)
    else:
        scene = preset.scene(seed)
        poses = preset_trajectory(scene, frames, rng, preset, fps=fps)
    stamps = SEQUENCE_T0 + np.arange(frames) / fps
    names = [f"{t:.6f}" for t in stamps]
    for a in range(0, frames, FRAME_BATCH):
        img, dep = render(scene, camera, poses[a:a + FRAME_BATCH], config, noise_seed=seed + a)
        for j in range(img.shape[0]):
            write_rgb_png(out_dir / "rgb" / f"{names[a + j]}.png", img[j])
            write_depth_png(out_dir / "depth" / f"{names[a + j]}.png", dep[j], DEPTH_FACTOR)
        if progress:
            progress(a + img.shape[0])
    for kind in ("rgb", "depth"):
        with atomic_write(out_dir / f"{kind}.txt") as f:
            f.write(f"# {kind} maps\n# synthetic sequence (codeslam synth), seed {seed}\n# timestamp filename\n")
            for n in names:
                f.write(f"{n} {kind}/{n}.png\n")
    traj = Trajectory(np.array([float(n) for n in names]), poses)
    write_tum(out_dir / "groundtruth.txt", traj)
    with atomic_write(out_dir / "calib.txt") as f:
        f.write(f"{camera.fx!r} {camera.fy!r} {camera.cx!r} {camera.cy!r}\n")
    return {
        "path": str(out_dir),
        "frames": frames,
        "seconds": time.perf_counter() - t0,
        "primitives": scene.num_primitives,
        "path_length": traj.path_length,
        "motion": preset.name if preset else None,
    }


def _generate_job(args) -> dict:
    return generate_sequence(*args)


def generate_sequences(
    out_dir: str | Path,
    scenes: int,
    frames: int,
    seed: int = 0,
    camera: PinholeCamera | None = None,
    config: RenderConfig = RenderConfig(),
    fps: float = DEFAULT_FPS,
    progress=None,
    workers: int = 1,
    motion: str | None = None,
) -> dict:
    """Write ``scenes`` sequences ``out_dir/scene_000`` ... (``workers > 1``: that many processes, one
    sequence each at a time, one torch thread each; the output does not depend on it); ``motion`` and ``fps``
    as in :func:`generate_sequence`. ``progress(frames_done, frames_total)`` counts frames over all sequences
    (after every batch of frames with one worker, after every sequence with several). Returns a summary dict
    (scenes, frames, size, seed, motion, frame_rate, seconds, fps (frames rendered per second), paths)."""
    if scenes < 1:
        raise CodeSLAMError(f"--scenes must be at least 1, got {scenes}")
    if frames < 1:
        raise CodeSLAMError(f"--frames must be at least 1, got {frames}")
    if not (math.isfinite(fps) and fps > 0):
        raise CodeSLAMError(f"--fps must be positive, got {fps}")
    if motion is not None:
        get_preset(motion)  # an unknown name fails before any work
    ensure_dir(out_dir)  # fails before rendering when OUT (or a parent) is a file
    camera = canonical_camera(256, 192) if camera is None else camera
    t0 = time.perf_counter()
    jobs = [(Path(out_dir) / f"scene_{i:03d}", scene_seed(seed, i), frames, camera, config, fps, motion)
            for i in range(scenes)]
    paths = []
    total = scenes * frames
    if workers <= 1:
        for i, job in enumerate(jobs):
            done = i * frames
            paths.append(generate_sequence(*job, progress=progress and (lambda n, d=done: progress(d + n, total)))
                         ["path"])
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        from codeslam.synth.shards import worker_init

        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=worker_init) as pool:
            for i, info in enumerate(pool.map(_generate_job, jobs)):
                paths.append(info["path"])
                if progress:
                    progress((i + 1) * frames, total)
    seconds = time.perf_counter() - t0
    return {
        "scenes": scenes,
        "frames": frames,
        "size": [camera.width, camera.height],
        "seed": seed,
        "motion": motion,
        "frame_rate": fps,
        "seconds": seconds,
        "fps": scenes * frames / seconds if seconds > 0 else 0.0,
        "paths": paths,
    }


__all__ = ["generate_sequence", "generate_sequences", "scene_seed", "SEQUENCE_T0", "DEFAULT_FPS"]
