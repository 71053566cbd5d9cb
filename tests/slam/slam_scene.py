"""Test helper imported by the tests/slam modules: short synthetic RGB-D sequences rendered in memory by the
generator (codeslam.synth) at 64x48, an in-memory Sequence, and the small SLAM configuration the tests use."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import torch

from codeslam.data.base import Sequence
from codeslam.data.frame import Frame
from codeslam.geometry.camera import canonical_camera
from codeslam.slam.config import KeyframeConfig, SLAMConfig, TrackerConfig, WindowConfig
from codeslam.synth.render import RenderConfig, render
from codeslam.synth.scene import build_scene
from codeslam.synth.trajectory import random_trajectory

WIDTH, HEIGHT = 64, 48


@functools.lru_cache(maxsize=8)
def _rendered(seed: int, frames: int, fps: float, width: int, height: int):
    scene = build_scene(seed)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7247]))
    poses = random_trajectory(scene, frames, rng, fps=fps)
    cam = canonical_camera(width, height)
    image, depth = render(scene, cam, poses, RenderConfig(ao_samples=0, supersample=2))  # anti-aliased
    return cam, image, depth, poses


def synth_frames(seed: int = 3, frames: int = 12, fps: float = 10.0, width: int = WIDTH,
                 height: int = HEIGHT) -> list[Frame]:
    """``frames`` frames of the generator's room ``seed`` along its handheld trajectory sampled at ``fps``
    (a low rate = large inter-frame motion), with exact depth and ground-truth poses."""
    cam, image, depth, poses = _rendered(seed, frames, fps, width, height)
    return [Frame(1000.0 + i / fps, image[i].clone(), cam, depth[i].clone(), poses[i].clone(), i)
            for i in range(frames)]


class MemorySequence(Sequence):
    """A :class:`~codeslam.data.base.Sequence` over frames held in memory."""

    format_name = "memory"

    def __init__(self, frames: list[Frame]) -> None:
        super().__init__(".")
        self.frames = frames

    @staticmethod
    def detect(root) -> bool:
        return False

    @property
    def camera(self):
        return self.frames[0].camera

    @property
    def timestamps(self) -> np.ndarray:
        return np.array([f.timestamp for f in self.frames])

    @property
    def has_depth(self) -> bool:
        return self.frames[0].depth is not None

    @property
    def gt_poses(self):
        if self.frames[0].pose is None:
            return None
        return torch.stack([f.pose for f in self.frames])

    def __len__(self) -> int:
        return len(self.frames)

    def frame(self, i: int, depth: bool = True) -> Frame:
        return self.frames[i] if depth else replace(self.frames[i], depth=None)


def small_config(sfm: dict | None = None, **window) -> SLAMConfig:
    """The defaults with three pyramid levels (a 64x48 image's fourth level is 8x6 pixels) and ``window``
    fields replaced (``sfm``: fields of the window's solver settings)."""
    base = SLAMConfig()
    sfm = replace(base.window.sfm, pyramid_levels=(2, 1, 0), max_iterations=(8, 6, 5), **(sfm or {}))
    return replace(
        base,
        tracker=replace(TrackerConfig(), pyramid_levels=(2, 1, 0), max_iterations=(8, 6, 5)),
        keyframes=KeyframeConfig(),
        window=replace(WindowConfig(), sfm=sfm, **window),
    )


_PRESET_RENDERS: dict[tuple, tuple] = {}


def _rendered_preset(seed: int, frames: int, motion: str, fps: float, width: int, height: int):
    """The first ``frames`` frames of a preset's path, rendered. A preset's path and each frame's rendering do not
    depend on how many frames are asked for (tests/synth/test_synth_motion.py checks it bit for bit), so the
    longest render of a path so far serves every shorter request: the SLAM tests ask for 8 to 24 frames of the same
    few paths, and each frame at 160x120 takes about 0.4 s to render."""
    from codeslam.synth.motion import get_preset, preset_trajectory

    key = (seed, motion, fps, width, height)
    hit = _PRESET_RENDERS.get(key)
    if hit is None or hit[3].shape[0] < frames:
        scene = get_preset(motion).scene(seed)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7247]))
        poses = preset_trajectory(scene, frames, rng, motion, fps=fps)
        cam = canonical_camera(width, height)
        image, depth = render(scene, cam, poses, RenderConfig(ao_samples=0, supersample=2))
        hit = _PRESET_RENDERS[key] = (cam, image, depth, poses)
        while len(_PRESET_RENDERS) > 6:  # the oldest path goes (a test module uses one or two)
            _PRESET_RENDERS.pop(next(iter(_PRESET_RENDERS)))
    cam, image, depth, poses = hit
    return cam, image[:frames], depth[:frames], poses[:frames]


def preset_frames(seed: int, frames: int, motion: str, fps: float, width: int = 160, height: int = 120) -> list[Frame]:
    """``frames`` frames of a generator room along a motion preset's path (a person walking or turning with the
    camera, :mod:`codeslam.synth.motion`) at ``fps``, with exact depth and poses."""
    cam, image, depth, poses = _rendered_preset(seed, frames, motion, fps, width, height)
    return [Frame(1000.0 + i / fps, image[i].clone(), cam, depth[i].clone(), poses[i].clone(), i)
            for i in range(frames)]


def _turn(t: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) orientation at time t (frames) of a camera that turns in place, yawing back and forth by up to
    5 degrees per frame (so that frames and their keyframes turn at different speeds) and nodding a little."""
    yaw, pitch = 0.25 * torch.sin(0.35 * t), 0.04 * torch.sin(0.6 * t)
    cy, sy, cp, sp = torch.cos(yaw), torch.sin(yaw), torch.cos(pitch), torch.sin(pitch)
    o, z = torch.ones_like(t), torch.zeros_like(t)
    Ry = torch.stack([torch.stack([cy, z, sy], -1), torch.stack([z, o, z], -1), torch.stack([-sy, z, cy], -1)], -2)
    Rx = torch.stack([torch.stack([o, z, z], -1), torch.stack([z, cp, -sp], -1), torch.stack([z, sp, cp], -1)], -2)
    return Ry @ Rx


def _wall_texture(X: torch.Tensor, Y: torch.Tensor) -> torch.Tensor:
    """Grey level in [0, 1] on the wall: twelve gratings of random direction and 2-16 cycles per 2 pi metres."""
    g = torch.Generator().manual_seed(0)
    out = torch.full_like(X, 0.5)
    for _ in range(12):
        f, a, phase = (torch.rand(3, generator=g, dtype=X.dtype) * torch.tensor([14.0, 2 * np.pi, 2 * np.pi])).unbind()
        out = out + (0.25 / (1 + 0.15 * (2 + f))) * torch.sin((2 + f) * (torch.cos(a) * X + torch.sin(a) * Y) + phase)
    return out.clamp(0, 1)


def rolling_shutter_frames(readout: float, frames: int = 10, width: int = WIDTH, height: int = HEIGHT,
                           axis: str = "rows") -> list[Frame]:
    """A camera turning in place before a textured wall 3 m away, ray-cast pixel by pixel: row y of frame i is seen
    at time i + readout (y - (H - 1) / 2) / H frames (``readout`` 0: a global shutter); with ``axis`` "columns"
    column x at i + readout (x - (W - 1) / 2) / W (a portrait video's sensor rows, the frames marked so); depth
    and ground-truth pose at mid-readout (exact)."""
    cam = canonical_camera(width, height)
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64),
                          indexing="ij")
    rays = torch.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, torch.ones_like(u)], -1)
    out = []
    for i in range(frames):
        row = (v - 0.5 * (height - 1)) / height if axis == "rows" else (u - 0.5 * (width - 1)) / width
        d = (_turn(i + readout * row) @ rays.unsqueeze(-1)).squeeze(-1)
        depth = 3.0 / d[..., 2]  # the wall z = 3 in the world, the camera at the origin
        image = _wall_texture(depth * d[..., 0], depth * d[..., 1]).float()
        pose = torch.eye(4, dtype=torch.float64)
        pose[:3, :3] = _turn(torch.tensor(float(i), dtype=torch.float64))
        out.append(Frame(1000.0 + i / 10, image[None].repeat(3, 1, 1), cam, depth.float(), pose, i,
                         readout_axis=axis))
    return out
