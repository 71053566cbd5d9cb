"""Camera paths: inside the room, clear of objects, smooth, with rotation-dominant stretches."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from codeslam.synth.scene import build_scene
from codeslam.synth.trajectory import DEFAULT_CLEARANCE, look_at, matmul3, random_trajectory, random_views


def _rot_angle(Ra: torch.Tensor, Rb: torch.Tensor) -> torch.Tensor:
    cos = ((Ra.transpose(-1, -2) @ Rb).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    return torch.acos(cos.clamp(-1, 1))


def test_look_at_gives_a_rotation_looking_at_the_target():
    p = torch.tensor([[1.0, 2.0, 1.5], [0.5, 0.5, 0.5]], dtype=torch.float64)
    q = torch.tensor([[3.0, 2.5, 0.5], [0.6, 2.0, 2.0]], dtype=torch.float64)
    T = look_at(p, q, torch.tensor([0.0, 0.3], dtype=torch.float64))
    R = T[:, :3, :3]
    assert torch.allclose(R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand(2, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(2, dtype=torch.float64))
    fwd = (q - p) / (q - p).norm(dim=-1, keepdim=True)
    assert torch.allclose(R[:, :, 2], fwd)
    assert float(R[0, 2, 1]) < 0  # without roll the image y axis points down in the world
    assert torch.equal(T[:, :3, 3], p)
    a = torch.randn(4, 3, 3, dtype=torch.float64)
    assert torch.allclose(matmul3(a, a), a @ a)


@pytest.mark.parametrize("seed", [1, 4])
def test_trajectory_is_free_smooth_and_turns_in_place_sometimes(seed):
    scene = build_scene(seed)
    T = random_trajectory(scene, 300, np.random.default_rng(seed))
    pos = T[:, :3, 3].float()
    assert float(scene.free_distance(pos).min()) >= DEFAULT_CLEARANCE - 1e-6
    step = (pos[1:] - pos[:-1]).norm(dim=-1)
    turn = _rot_angle(T[:-1, :3, :3], T[1:, :3, :3])
    assert float(step.max()) < 0.06  # < 1.8 m/s at 30 fps
    assert float(turn.max()) < math.radians(6.0)
    assert float(step.mean()) > 0.003 and float(turn.mean()) > math.radians(0.2)  # it moves and turns
    # second differences small: no jumps in velocity
    assert float((pos[2:] - 2 * pos[1:-1] + pos[:-2]).norm(dim=-1).max()) < 0.01
    # a rotation-dominant stretch: somewhere a half second turns > 8 degrees while moving < 5 cm
    w = 15
    trans = (pos[w:] - pos[:-w]).norm(dim=-1)
    rot = _rot_angle(T[:-w, :3, :3], T[w:, :3, :3])
    assert bool(((trans < 0.05) & (rot > math.radians(8.0))).any())


def test_random_views_are_inside_the_room_and_varied():
    scene = build_scene(9)
    T = random_views(scene, 40, np.random.default_rng(0))
    pos = T[:, :3, 3].float()
    assert float(scene.free_distance(pos).min()) >= 0.15 - 1e-6
    height = pos[:, 2]
    assert float(height.max() - height.min()) > 0.5
    pitch = torch.asin(T[:, 2, 2])  # world z of the optical axis
    assert float(pitch.min()) < -0.5 and float(pitch.max()) > -0.2
    roll_dirs = T[:, 2, 0]  # world z of the image x axis: non-zero when rolled
    assert float(roll_dirs.abs().max()) > 0.05


def test_trajectories_are_reproducible():
    scene = build_scene(3)
    a = random_trajectory(scene, 50, np.random.default_rng(5))
    b = random_trajectory(scene, 50, np.random.default_rng(5))
    c = random_trajectory(scene, 50, np.random.default_rng(6))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_version_2_views_look_along_the_room_from_standing_and_sitting_height():
    from codeslam.synth.scene import build_scene_v2
    from codeslam.synth.trajectory import random_views_v2

    scene = build_scene_v2(1)  # a large room
    T = random_views_v2(scene, 60, np.random.default_rng(3))
    assert T.shape == (60, 4, 4)
    pos = T[:, :3, 3].float()
    assert float(scene.free_distance(pos).min()) >= 0.15 - 1e-6
    pitch = torch.asin(T[:, 2, 2])
    level = (pitch.abs() < math.radians(31.0)) & (pos[:, 2] >= 0.99) & (pos[:, 2] <= 1.81)
    assert 0.4 < float(level.float().mean()) < 0.95  # about half look along the room, the rest are close-ups
    again = random_views_v2(scene, 60, np.random.default_rng(3))
    assert torch.equal(T, again)


def test_version_3_views_see_things_from_a_persons_height():
    from codeslam.synth.scene import build_scene_v2
    from codeslam.synth.trajectory import look_at_views, random_views_v3

    scene = build_scene_v2(1)
    T = look_at_views(scene, 40, np.random.default_rng(0))
    pos = T[:, :3, 3].float()
    assert float(scene.free_distance(pos).min()) >= 0.25 - 1e-6
    assert float(pos[:, 2].min()) >= 0.99 and float(pos[:, 2].max()) <= 1.81  # sitting or standing
    pitch = torch.asin(T[:, 2, 2])
    assert float(pitch.min()) >= math.radians(-71.0) and float(pitch.max()) <= math.radians(21.0)
    assert float((pitch < math.radians(-20.0)).float().mean()) > 0.2  # many look down at tables and floors
    V = random_views_v3(scene, 50, np.random.default_rng(1))
    assert V.shape == (50, 4, 4) and torch.equal(V, random_views_v3(scene, 50, np.random.default_rng(1)))
    person = ((V[:, 2, 3] >= 0.99) & (V[:, 2, 3] <= 1.81)).float().mean()
    assert float(person) > 0.75  # 85% of the views are from a person's height (the close-ups vary)
