"""The written trajectory's smoothing spline (codeslam.slam.smoothing) and where the system applies it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from slam_scene import MemorySequence

from codeslam.errors import ConfigError
from codeslam.slam.config import SLAMConfig
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import run_slam
from codeslam.slam.smoothing import smooth_positions, solve_pentadiagonal
from codeslam.slam.system import CodeSLAM


def _irregular_times(n: int, seed: int) -> np.ndarray:
    return 100.0 + np.cumsum(np.random.default_rng(seed).uniform(0.02, 0.12, n))


def _dense_spline(t, z, m, tau):
    """The module docstring's cost written out densely: rows sqrt(m_k) (x_k - z_k) and tau^2 a_k."""
    n = len(t)
    A = np.zeros((n - 2, n))
    for k in range(1, n - 1):
        dt0, dt1 = t[k] - t[k - 1], t[k + 1] - t[k]
        mid = 0.5 * (dt0 + dt1)
        A[k - 1, k - 1], A[k - 1, k], A[k - 1, k + 1] = 1 / (dt0 * mid), -(1 / dt0 + 1 / dt1) / mid, 1 / (dt1 * mid)
    rows = np.vstack([np.diag(np.sqrt(m)), tau**2 * A])
    rhs = np.vstack([np.sqrt(m)[:, None] * z, np.zeros((n - 2, z.shape[1]))])
    return np.linalg.lstsq(rows, rhs, rcond=None)[0]


def test_the_spline_is_the_least_squares_minimiser_of_its_cost():
    n = 40
    t = _irregular_times(n, 0)
    z = np.random.default_rng(1).normal(size=(n, 3))
    m = np.random.default_rng(2).random(n) > 0.25  # some frames only predicted: no measurement
    m[[0, -1]] = False  # unmeasured at both ends too
    x = smooth_positions(t, z, m, 0.05)
    np.testing.assert_allclose(x, _dense_spline(t, z, m.astype(float), 0.05), rtol=0, atol=1e-9)
    assert np.abs(x - z).max() > 1e-3  # and it did move them


def test_the_banded_solver_against_a_dense_solve():
    n = 25
    rng = np.random.default_rng(3)
    B = np.zeros((n, n))
    for off in range(3):  # a random banded L, M = L L^T + I: symmetric positive definite and pentadiagonal
        B += np.diag(rng.normal(size=n - off), -off)
    M = B @ B.T + np.eye(n)
    b = rng.normal(size=(n, 2))
    x = solve_pentadiagonal(np.diag(M).copy(), np.diag(M, 1).copy(), np.diag(M, 2).copy(), b)
    np.testing.assert_allclose(x, np.linalg.solve(M, b), rtol=0, atol=1e-10)
    with pytest.raises(np.linalg.LinAlgError):
        solve_pentadiagonal(-np.ones(n), np.zeros(n - 1), np.zeros(n - 2), b)


def test_an_anchored_spline_holds_the_first_position_and_minimises_the_rest():
    n = 30
    t = _irregular_times(n, 7)
    z = np.random.default_rng(8).normal(size=(n, 3))
    m = np.ones(n, bool)
    x = smooth_positions(t, z, m, 0.05, anchor=True)
    np.testing.assert_array_equal(x[0], z[0])
    # the same as the free spline with the first frame's measurement weighted without bound
    heavy = _dense_spline(t, z, np.r_[1e12, np.ones(n - 1)], 0.05)
    np.testing.assert_allclose(x, heavy, rtol=0, atol=1e-6)
    assert np.abs(x[1:] - smooth_positions(t, z, m, 0.05)[1:]).max() > 1e-4  # the anchor matters


def test_a_path_linear_in_time_is_kept_whatever_its_speed():
    n = 30
    t = _irregular_times(n, 4)
    z = np.array([0.1, -0.2, 0.3]) + (t - t[0])[:, None] * np.array([1.5, 0.0, -4.0])  # metres per second
    m = np.ones(n, bool)
    m[10:14] = False
    np.testing.assert_allclose(smooth_positions(t, z, m, 0.2), z, rtol=0, atol=1e-9)
    np.testing.assert_allclose(smooth_positions(t, z, m, 0.2, anchor=True), z, rtol=0, atol=1e-9)


def test_zig_zag_faster_than_the_time_scale_is_taken_out_and_slower_motion_kept():
    t = np.arange(90) / 30.0
    slow = np.stack([0.3 * np.sin(2 * np.pi * 0.5 * t), 0.1 * t, np.zeros_like(t)], 1)  # 0.5 Hz sway
    zig = 0.01 * (-1.0) ** np.arange(90)  # +-1 cm from frame to frame, as tracking jitter
    z = slow + zig[:, None] * np.array([1.0, 0.0, 0.0])
    x = smooth_positions(t, z, np.ones(90, bool), 0.05)
    inner = slice(5, -5)
    err_before = np.abs(z - slow)[inner].max()
    err_after = np.abs(x - slow)[inner].max()
    assert err_before == pytest.approx(0.01)
    assert err_after < 0.25 * err_before, err_after


def test_nothing_to_smooth_returns_the_input():
    t = _irregular_times(10, 5)
    z = np.random.default_rng(6).normal(size=(10, 3))
    ok = np.ones(10, bool)
    np.testing.assert_array_equal(smooth_positions(t, z, ok, 0.0), z)  # switched off
    np.testing.assert_array_equal(smooth_positions(t[:2], z[:2], ok[:2], 0.05), z[:2])  # too short
    one = np.zeros(10, bool)
    one[3] = True
    np.testing.assert_array_equal(smooth_positions(t, z, one, 0.05), z)  # a single measured frame
    assert not np.array_equal(smooth_positions(t, z, one, 0.05, anchor=True), z)  # the anchor fixes the line
    np.testing.assert_array_equal(smooth_positions(t, z, np.zeros(10, bool), 0.05, anchor=True), z)
    flat = np.full(10, 5.0)
    np.testing.assert_array_equal(smooth_positions(flat, z, ok, 0.05), z)  # no time scale


def test_config_refuses_a_negative_time_scale():
    with pytest.raises(ConfigError, match="trajectory_smoothing"):
        SLAMConfig(trajectory_smoothing=-0.1)


def test_the_system_smooths_the_written_positions_only():
    # A short hand-held preset: the written trajectory's positions move, its rotations and the keyframes' poses
    # stay; switched off, the trajectory is the interpolated one.
    from slam_scene import preset_frames

    seq = MemorySequence(preset_frames(5, 14, "handheld", 10.0))
    system = CodeSLAM(SLAMConfig(), standin_depth_model(code_offset_scale=0.3))
    run_slam(seq, system, seq.frames[0].camera)
    smoothed = system.trajectory()
    keyframes = system.keyframe_trajectory()
    system.config = dataclasses.replace(system.config, trajectory_smoothing=0.0)
    plain = system.trajectory()
    torch.testing.assert_close(smoothed.poses[:, :3, :3], plain.poses[:, :3, :3], rtol=0, atol=0)
    assert torch.equal(smoothed.poses[0], torch.eye(4, dtype=torch.float64))  # the map's origin stays
    shift = (smoothed.poses[:, :3, 3] - plain.poses[:, :3, 3]).norm(dim=1)
    assert float(shift.max()) > 0
    torch.testing.assert_close(system.keyframe_trajectory().poses, keyframes.poses, rtol=0, atol=0)
