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

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]


def small_config(**window) -> SLAMConfig:
    """The defaults with three pyramid levels (a 64x48 image's fourth level is 8x6 pixels) and ``window``
    fields replaced."""
    base = SLAMConfig()
    sfm = replace(base.window.sfm, pyramid_levels=(2, 1, 0), max_iterations=(8, 6, 5))
    return replace(
        base,
        tracker=replace(TrackerConfig(), pyramid_levels=(2, 1, 0), max_iterations=(8, 6, 5)),
        keyframes=KeyframeConfig(),
        window=replace(WindowConfig(), sfm=sfm, **window),
    )


@functools.lru_cache(maxsize=4)
def _rendered_preset(seed: int, frames: int, motion: str, fps: float, width: int, height: int):
    from codeslam.synth.motion import get_preset, preset_trajectory

    scene = build_scene(seed, room=get_preset(motion).room)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7247]))
    poses = preset_trajectory(scene, frames, rng, motion, fps=fps)
    cam = canonical_camera(width, height)
    image, depth = render(scene, cam, poses, RenderConfig(ao_samples=0, supersample=2))
    return cam, image, depth, poses


def preset_frames(seed: int, frames: int, motion: str, fps: float, width: int = 160, height: int = 120) -> list[Frame]:
    """``frames`` frames of a generator room along a motion preset's path (a person walking or turning with the
    camera, :mod:`codeslam.synth.motion`) at ``fps``, with exact depth and poses."""
    cam, image, depth, poses = _rendered_preset(seed, frames, motion, fps, width, height)
    return [Frame(1000.0 + i / fps, image[i].clone(), cam, depth[i].clone(), poses[i].clone(), i)
            for i in range(frames)]
