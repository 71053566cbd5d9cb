"""Motion presets: per-frame motion inside the stated ranges at 10 and 30 frames/s, continuous paths clear of
every surface, deterministic per seed, the same path in time at any frame rate, default seeds untouched."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from codeslam.errors import CodeSLAMError
from codeslam.synth.generate import generate_sequence, scene_seed
from codeslam.synth.motion import PRESETS, preset_trajectory
from codeslam.synth.scene import build_scene

SEEDS = (0, 1, 2)
FRAMES_10 = 120  # 12 s of motion per seed

# Stated per-frame ranges at 10 frames/s (the module docstring's table, with margins): translation (cm) median
# and 95th percentile, rotation (deg) median and 95th percentile, as (low, high) bounds. At 30 frames/s the
# same path gives a third of the motion per frame.
RANGES_10 = {
    "handheld": {"t_med": (3.0, 6.0), "t_95": (4.5, 8.0), "r_med": (0.8, 4.0), "r_95": (2.5, 7.0)},
    "walk": {"t_med": (7.0, 15.0), "t_95": (11.0, 17.0), "r_med": (0.8, 4.0), "r_95": (3.5, 9.0)},
    "fast-turn": {"t_med": (0.0, 2.0), "t_95": (0.0, 4.0), "r_med": (3.0, 9.0), "r_95": (6.0, 10.0)},
    "corridor": {"t_med": (7.0, 14.0), "t_95": (11.0, 16.0), "r_med": (0.5, 4.0), "r_95": (3.5, 9.0)},
}


def _frame_motion(T: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Translation (cm) and rotation (deg) between consecutive poses (N, 4, 4): two (N - 1,) arrays."""
    step = (T[1:, :3, 3] - T[:-1, :3, 3]).norm(dim=-1)
    R = T[:-1, :3, :3].transpose(-1, -2) @ T[1:, :3, :3]
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    return step.numpy() * 100, np.degrees(torch.acos(cos).numpy())


def _paths(name: str, fps: float, frames: int):
    out = []
    for i in SEEDS:
        s = scene_seed(0, i)
        scene = PRESETS[name].scene(s)
        T = preset_trajectory(scene, frames, np.random.default_rng(np.random.SeedSequence([s, 0x7247])), name,
                              fps=fps)
        out.append((scene, T))
    return out


@pytest.mark.parametrize("name", list(PRESETS))
@pytest.mark.parametrize("fps", [10.0, 30.0])
def test_per_frame_motion_inside_the_stated_ranges(name, fps):
    scale = 10.0 / fps
    frames = int(round((FRAMES_10 - 1) / scale)) + 1
    paths = _paths(name, fps, frames)
    tr = np.concatenate([_frame_motion(T)[0] for _, T in paths])
    rot = np.concatenate([_frame_motion(T)[1] for _, T in paths])
    got = {"t_med": np.median(tr), "t_95": np.percentile(tr, 95), "r_med": np.median(rot),
           "r_95": np.percentile(rot, 95)}
    for key, (lo, hi) in RANGES_10[name].items():
        assert lo * scale <= got[key] <= hi * scale, (name, fps, key, got[key])
    preset = PRESETS[name]
    # no teleport: no frame moves faster than the fastest walk plus its bob and shake, or turns faster than
    # the preset's rate plus the shake's
    assert tr.max() / 100 * fps < max(preset.speed[1], 0.1) + 0.35
    assert rot.max() * fps < preset.max_rate_deg + 45.0
    for scene, T in paths:
        pos = T[:, :3, 3].float()
        assert float(scene.free_distance(pos).min()) >= preset.clearance - 1e-6
        R = T[:, :3, :3]
        assert torch.allclose(R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand_as(R), atol=1e-9)


def test_walk_is_at_standing_height_and_travels_far():
    for scene, T in _paths("walk", 10.0, FRAMES_10):
        z = T[:, 2, 3]
        assert float(z.min()) > 1.35 and float(z.max()) < 1.9
        travelled = float((T[1:, :3, 3] - T[:-1, :3, 3]).norm(dim=-1).sum())
        assert travelled > 0.7 * (FRAMES_10 - 1) / 10.0  # at least 0.7 m/s on average
        assert min(scene.size[:2]) >= 6.0
        # it looks along the room: the optical axis stays within 40 degrees of horizontal
        assert float(T[:, 2, 2].abs().max()) < math.sin(math.radians(40.0))


def test_fast_turn_stands_and_pans_fast():
    for _, T in _paths("fast-turn", 30.0, 150):
        pos = T[:, :3, 3]
        assert float((pos - pos.mean(0)).norm(dim=-1).max()) < 0.1  # standing
        _, rot = _frame_motion(T)
        assert rot.max() * 30 > 60.0  # some pan reaches more than 60 deg/s


def test_deterministic_per_seed_and_same_path_at_any_frame_rate():
    scene = PRESETS["walk"].scene(5)
    a = preset_trajectory(scene, 31, np.random.default_rng(9), "walk", fps=10)
    b = preset_trajectory(scene, 31, np.random.default_rng(9), "walk", fps=10)
    c = preset_trajectory(scene, 31, np.random.default_rng(10), "walk", fps=10)
    assert torch.equal(a, b) and not torch.allclose(a, c)
    d = preset_trajectory(scene, 91, np.random.default_rng(9), "walk", fps=30)  # the same 3 s
    assert torch.allclose(d[::3], a, atol=1e-9)


@pytest.mark.parametrize("name", list(PRESETS))
def test_a_shorter_path_and_its_render_are_the_start_of_a_longer_one(name):
    # A path does not depend on how many frames are asked for, nor a frame's rendering on the others rendered with
    # it (tests/slam/slam_scene.py serves shorter requests from a longer render on the strength of this).
    from codeslam.geometry.camera import canonical_camera
    from codeslam.synth.render import RenderConfig, render

    scene = PRESETS[name].scene(scene_seed(0, 1))
    long, short = (preset_trajectory(scene, n, np.random.default_rng(np.random.SeedSequence([7, 0x7247])), name,
                                     fps=10.0) for n in (9, 4))
    assert torch.equal(long[:4], short)
    cam, cfg = canonical_camera(32, 24), RenderConfig(ao_samples=0, supersample=2)
    (im_l, d_l), (im_s, d_s) = render(scene, cam, long[:6], cfg), render(scene, cam, short, cfg)
    assert torch.equal(im_l[:4], im_s) and torch.equal(d_l[:4], d_s)


def test_bad_presets_and_rates_are_refused(tmp_path):
    scene = build_scene(1)
    with pytest.raises(CodeSLAMError, match="unknown motion preset 'run'"):
        preset_trajectory(scene, 5, np.random.default_rng(0), "run")
    with pytest.raises(CodeSLAMError, match="fps"):
        preset_trajectory(scene, 5, np.random.default_rng(0), "walk", fps=0.0)
    with pytest.raises(CodeSLAMError, match="unknown motion preset"):
        generate_sequence(tmp_path / "x", 1, 3, motion="jog")
    assert not (tmp_path / "x").exists()


def test_path_views_are_frames_of_a_preset_path_in_its_room():
    """Training data version 4: views of one preset's room, on a path a person walks (at the preset's heights,
    clear of every surface), in time order, reproducible; every preset is drawn over a few rooms."""
    from codeslam.synth.motion import PATH_VIEW_SHARES, preset_path_views

    rooms = {}
    for seed in range(12):
        scene, T = preset_path_views(seed, 16, np.random.default_rng(seed))
        assert T.shape == (16, 4, 4) and T.dtype == torch.float64
        scene2, T2 = preset_path_views(seed, 16, np.random.default_rng(seed))
        assert torch.equal(T, T2) and scene2.size == scene.size
        name = next(n for n in PATH_VIEW_SHARES if PRESETS[n].scene(seed).size == scene.size)
        rooms[name] = rooms.get(name, 0) + 1
        lo = min(PRESETS[name].height) - 0.15  # the preset's heights, give or take the bob and shake
        hi = max(PRESETS[name].height) + 0.15
        z = T[:, 2, 3]
        assert bool(((z > lo) & (z < hi)).all()), (name, z)
        assert bool((scene.free_distance(T[:, :3, 3].float()) >= PRESETS[name].clearance - 1e-3).all())
        R = T[:, :3, :3]
        assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(16, 3, 3), atol=1e-9)
    assert len(rooms) >= 3, rooms  # 0.2-0.3 shares each: three presets or more over 12 rooms
    _, many = preset_path_views(0, 400, np.random.default_rng(0))  # more views than the path's frames: repeats
    assert many.shape == (400, 4, 4)
