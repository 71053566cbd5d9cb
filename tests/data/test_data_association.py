"""Timestamp association (TUM associate.py semantics) and ground-truth interpolation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from codeslam.data.association import associate, interpolate_poses
from codeslam.data.trajectory import Trajectory
from codeslam.geometry.quaternion import quat_xyzw_to_rotmat


def _reference_associate(a, b, max_diff):
    """TUM associate.py's algorithm written out literally: every pair, closest first, greedy."""
    pairs = sorted((abs(x - y), i, j) for i, x in enumerate(a) for j, y in enumerate(b) if abs(x - y) <= max_diff)
    used_a, used_b, out = set(), set(), []
    for _, i, j in pairs:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            out.append((i, j))
    return sorted(out)


def test_associate_pairs_nearest_and_drops_far():
    a = np.array([0.0, 1.0, 2.0, 3.0])
    b = np.array([0.01, 1.015, 2.5, 2.99, 3.005])
    ia, ib = associate(a, b, 0.02)
    # 2.0 has no partner within 0.02 s; 3.0 takes 3.005 (closer than 2.99).
    assert ia.tolist() == [0, 1, 3]
    assert ib.tolist() == [0, 1, 4]


def test_associate_is_one_to_one_greedy_by_difference():
    # Both a's are within reach of the single b; the closer one wins, the other stays unmatched.
    ia, ib = associate(np.array([0.0, 0.012]), np.array([0.01]), 0.02)
    assert ia.tolist() == [1] and ib.tolist() == [0]


def test_associate_offset_and_empty():
    ia, ib = associate(np.array([1.0, 2.0]), np.array([0.5, 1.5]), 0.01, offset=0.5)
    assert ia.tolist() == [0, 1] and ib.tolist() == [0, 1]
    ia, ib = associate(np.array([]), np.array([1.0]), 0.02)
    assert len(ia) == 0 and len(ib) == 0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0, 2, allow_nan=False), max_size=25),
    st.lists(st.floats(0, 2, allow_nan=False), max_size=25),
    st.floats(0.001, 0.3),
)
def test_associate_matches_reference_algorithm(a, b, max_diff):
    # Round to a grid so that ties between differences are exact and ordering by index is well defined.
    a = [round(x, 2) for x in a]
    b = [round(x, 2) for x in b]
    ia, ib = associate(np.array(a), np.array(b), max_diff)
    ref = _reference_associate(a, b, max_diff)
    assert list(zip(ia.tolist(), ib.tolist())) == ref


def _rot_y(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=torch.float64)


def _motion(t: float) -> torch.Tensor:
    """Constant-velocity motion: slerp and linear interpolation reproduce it exactly between samples."""
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = _rot_y(0.5 * t)
    T[:3, 3] = torch.tensor([0.3 * t, -0.1 * t, 2.0], dtype=torch.float64)
    return T


def test_interpolate_poses_exact_for_constant_velocity():
    ts = np.arange(0.0, 1.01, 0.1)
    traj = Trajectory(ts, torch.stack([_motion(t) for t in ts]))
    query = np.array([0.0, 0.05, 0.333, 0.999, 1.0])
    poses, valid = interpolate_poses(traj, query, max_gap=0.2)
    assert valid.all()
    for t, P in zip(query, poses):
        torch.testing.assert_close(P, _motion(t), rtol=0, atol=1e-9)


def test_interpolate_poses_invalid_outside_span_and_across_gaps():
    ts = np.array([0.0, 0.1, 0.2, 1.0, 1.1])  # a 0.8 s capture gap
    traj = Trajectory(ts, torch.stack([_motion(t) for t in ts]))
    query = np.array([-0.01, 0.15, 0.5, 1.0, 1.05, 1.2])
    poses, valid = interpolate_poses(traj, query, max_gap=0.15)
    assert valid.tolist() == [False, True, False, True, True, False]
    assert torch.isnan(poses[~valid]).all()
    assert not torch.isnan(poses[valid]).any()
    # A sample time is valid even next to a gap (t = 0.2 borders the gap).
    _, v = interpolate_poses(traj, np.array([0.2]), max_gap=0.15)
    assert v.tolist() == [True]


def test_interpolate_single_pose_trajectory():
    traj = Trajectory(np.array([5.0]), _motion(5.0)[None])
    poses, valid = interpolate_poses(traj, np.array([5.0, 5.01]), max_gap=1.0)
    assert valid.tolist() == [True, False]
    torch.testing.assert_close(poses[0], _motion(5.0))


def test_interpolate_takes_short_way_round_quaternion_sign():
    # Two samples whose rotations are close but built from quaternions of opposite sign.
    q0 = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    q1 = -torch.tensor([0.0, math.sin(0.05), 0.0, math.cos(0.05)], dtype=torch.float64)
    P = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    P[:, :3, :3] = quat_xyzw_to_rotmat(torch.stack([q0, q1]))
    poses, valid = interpolate_poses(Trajectory(np.array([0.0, 1.0]), P), np.array([0.5]), 2.0)
    torch.testing.assert_close(poses[0, :3, :3], _rot_y(0.05), rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [2, 7])
def test_interpolate_at_samples_returns_samples(n):
    ts = np.linspace(0, 1, n)
    P = torch.stack([_motion(t) for t in ts])
    poses, valid = interpolate_poses(Trajectory(ts, P), ts, max_gap=10)
    assert valid.all()
    torch.testing.assert_close(poses, P, rtol=0, atol=0)
