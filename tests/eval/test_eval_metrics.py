"""ATE, RPE, Umeyama, drift and segment errors on synthetic trajectories with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from codeslam.data.trajectory import Trajectory
from codeslam.errors import CodeSLAMError
from codeslam.eval.metrics import (
    ErrorStats,
    Sim3,
    accumulated_distances,
    ate,
    drift_vs_distance,
    evaluate,
    match_trajectories,
    pairs_by_frames,
    pairs_by_path,
    rpe,
    scale_drift,
    segment_errors,
    umeyama,
)


def random_sim3(rng: np.random.Generator, scale: float) -> Sim3:
    return Sim3(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3) * 3, scale)


def helix(n: int = 200, seed: int = 0) -> Trajectory:
    """A camera on a helix (non-planar, so the alignment is well posed), turning as it goes, 30 Hz."""
    s = np.linspace(0, 4 * np.pi, n)
    xyz = np.stack([np.cos(s), np.sin(s), 0.2 * s], axis=1)
    R = Rotation.from_euler("zyx", np.stack([s, 0.3 * np.sin(s), 0.1 * s], 1)).as_matrix()
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = xyz
    return Trajectory(100.0 + np.arange(n) / 30.0, torch.from_numpy(T))


def transformed(traj: Trajectory, S: Sim3) -> Trajectory:
    return Trajectory(traj.timestamps.copy(), torch.from_numpy(S.apply_poses(traj.poses.numpy())))


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_recovers_known_similarity(with_scale):
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    truth = random_sim3(rng, 2.5 if with_scale else 1.0)
    dst = truth.apply_points(src)
    S = umeyama(src, dst, with_scale=with_scale)
    np.testing.assert_allclose(S.R, truth.R, atol=1e-12)
    np.testing.assert_allclose(S.t, truth.t, atol=1e-12)
    assert S.s == pytest.approx(truth.s, rel=1e-12)
    assert np.linalg.det(S.R) == pytest.approx(1.0)
    R, t, s = S
    np.testing.assert_allclose(s * src @ R.T + t, dst, atol=1e-12)


def test_umeyama_never_returns_a_reflection():
    """Mirrored points: the best proper rotation, not the reflection that would fit exactly (eq. 43)."""
    rng = np.random.default_rng(2)
    src = rng.normal(size=(30, 3))
    dst = src * np.array([1.0, 1.0, -1.0])
    S = umeyama(src, dst)
    assert np.linalg.det(S.R) == pytest.approx(1.0)
    assert np.abs(S.apply_points(src) - dst).max() > 0.1


def test_umeyama_minimises_the_squared_error():
    """Perturbing the solution in any direction increases the sum of squared residuals."""
    rng = np.random.default_rng(3)
    src = rng.normal(size=(40, 3))
    dst = random_sim3(rng, 0.7).apply_points(src) + rng.normal(scale=0.05, size=src.shape)
    S = umeyama(src, dst, with_scale=True)

    def cost(R, t, s):
        return np.sum((s * src @ R.T + t - dst) ** 2)

    best = cost(S.R, S.t, S.s)
    for k in range(3):
        dR = Rotation.from_rotvec(1e-4 * np.eye(3)[k]).as_matrix()
        assert cost(dR @ S.R, S.t, S.s) > best
        assert cost(S.R, S.t + 1e-4 * np.eye(3)[k], S.s) > best
    assert cost(S.R, S.t, S.s * 1.0001) > best and cost(S.R, S.t, S.s * 0.9999) > best


@pytest.mark.parametrize(
    "src",
    [
        np.zeros((2, 3)),  # too few
        np.ones((10, 3)),  # all equal
        np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 3.0]),  # collinear
    ],
)
def test_umeyama_degenerate_input_raises(src):
    with pytest.raises(CodeSLAMError, match="align"):
        umeyama(src, src + 1.0, with_scale=True)


def test_error_stats():
    s = ErrorStats.from_errors(np.array([3.0, 4.0]))
    assert s.rmse == pytest.approx(np.sqrt(12.5))
    assert (s.mean, s.median, s.std, s.min, s.max) == (3.5, 3.5, 0.5, 3.0, 4.0)


@pytest.mark.parametrize("scale", [1.0, 0.3])
def test_ate_of_transformed_copy_is_zero_with_alignment(scale):
    ref = helix()
    est = transformed(ref, random_sim3(np.random.default_rng(4), scale))
    r = ate(est, ref, align="sim3")
    assert r.rmse < 1e-12 and r.max < 1e-12
    assert r.alignment.s == pytest.approx(1 / scale, rel=1e-12)
    assert r.n_matched == len(ref)
    # Without the scale a scaled copy cannot be aligned exactly; a rigid copy can.
    r_se3 = ate(est, ref, align="se3")
    assert (r_se3.rmse < 1e-12) == (scale == 1.0)
    # Unaligned, the error is the full offset.
    assert ate(est, ref, align="none").rmse > 0.1


def test_ate_known_value_for_constant_offset_without_alignment():
    ref = helix()
    S = Sim3(np.eye(3), np.array([0.3, 0.0, 0.4]))
    r = ate(transformed(ref, S), ref, align="none")
    assert r.rmse == pytest.approx(0.5) and r.std == pytest.approx(0.0, abs=1e-12)


def test_ate_uses_timestamp_association():
    ref = helix(300)
    # Estimate at every other reference stamp, 3 ms late, plus one stamp far from any reference stamp.
    idx = np.arange(0, 300, 2)
    est = Trajectory(np.append(ref.timestamps[idx] + 0.003, 200.0), torch.cat([ref.poses[idx], ref.poses[-1:]]))
    r = ate(est, ref, align="se3")
    assert r.n_matched == len(idx)
    np.testing.assert_array_equal(r.ref_idx, idx)
    assert r.rmse < 1e-12
    with pytest.raises(CodeSLAMError, match="do not overlap"):
        ate(est, ref, max_diff=0.002)


def test_too_few_matches_raise():
    ref = helix()
    est = ref.subset([0, 1])
    with pytest.raises(CodeSLAMError, match="at least 3"):
        match_trajectories(est, ref)
    with pytest.raises(CodeSLAMError, match="max_diff"):
        match_trajectories(ref, ref, max_diff=-1.0)


def test_rpe_zero_for_rigidly_moved_copy_and_known_for_scaled_copy():
    ref = helix()
    est = transformed(ref, random_sim3(np.random.default_rng(5), 1.0))
    r = rpe(est, ref, delta=1)
    assert r.trans.max < 1e-12 and r.rot_deg.max < 1e-9
    assert r.n_pairs == len(ref) - 1
    # A copy at half scale: each relative translation is half as long, so the error is half the step.
    half = transformed(ref, Sim3(np.eye(3), np.zeros(3), 0.5))
    r = rpe(half, ref, delta=1)
    steps = np.linalg.norm(np.diff(ref.positions_xyz.numpy(), axis=0), axis=1)
    np.testing.assert_allclose(r.trans_errors, 0.5 * steps, rtol=1e-10)
    assert r.rot_deg.max < 1e-9
    assert rpe(half, ref, delta=1, align="sim3").trans.max < 1e-12


def test_rpe_rotation_error_of_a_known_perturbation():
    """From pose 25 on, the estimate is rotated by 2 degrees about the world origin: only the pair (24, 25)
    sees it, with E = Q_25^-1 D Q_25, a rotation by the same 2 degrees."""
    ref = helix(50)
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec([0, 0, np.deg2rad(2.0)]).as_matrix()
    P = ref.poses.numpy().copy()
    P[25:] = D @ P[25:]
    est = Trajectory(ref.timestamps, torch.from_numpy(P))
    r = rpe(est, ref, delta=1)
    assert r.rot_deg.max == pytest.approx(2.0, rel=1e-9)
    assert np.flatnonzero(r.rot_errors_deg > 1e-6).tolist() == [24]
    assert np.flatnonzero(r.trans_errors > 1e-9).tolist() == [24]


def test_pairs():
    i, j = pairs_by_frames(10, 3)
    assert list(zip(i, j, strict=True)) == [(0, 3), (3, 6), (6, 9)]
    i, j = pairs_by_frames(5, 2, all_pairs=True)
    assert list(zip(i, j, strict=True)) == [(0, 2), (1, 3), (2, 4)]
    xyz = np.outer(np.arange(11) * 0.1, [1.0, 0, 0])  # 0.1 m steps
    i, j = pairs_by_path(xyz, 0.25)
    assert list(zip(i, j, strict=True)) == [(0, 3), (3, 6), (6, 9)]
    i, j = pairs_by_path(xyz, 0.3, all_pairs=True, rel_tol=0.1)
    assert list(zip(i, j, strict=True)) == [(k, k + 3) for k in range(8)]


def test_rpe_bad_delta():
    ref = helix(20)
    with pytest.raises(CodeSLAMError, match="smaller --delta"):
        rpe(ref, ref, delta=50)
    with pytest.raises(CodeSLAMError, match="positive integer"):
        rpe(ref, ref, delta=1.5)
    with pytest.raises(CodeSLAMError, match="delta unit"):
        rpe(ref, ref, delta=1, delta_unit="deg")


def test_drift_anchored_at_first_pose_grows_linearly_with_a_scale_error():
    """A straight line walked 10 % too far: anchored at the first pose, the error is 10 % of the distance;
    with the Sim(3) scale, it vanishes."""
    n = 101
    xyz = np.zeros((n, 3))
    xyz[:, 0] = np.linspace(0, 10, n)
    xyz[:, 1] = 0.3 * np.sin(np.linspace(0, 3, n))  # not collinear, so the scale fit is defined
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = xyz
    ref = Trajectory(np.arange(n) * 0.1, torch.from_numpy(T))
    moved = random_sim3(np.random.default_rng(6), 1.1)
    est = transformed(ref, moved)
    d = drift_vs_distance(est, ref, anchor="first")
    np.testing.assert_allclose(d.distances, accumulated_distances(xyz))
    assert d.errors[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(d.errors, 0.1 * np.linalg.norm(xyz - xyz[0], axis=1), atol=1e-9)
    assert drift_vs_distance(est, ref, anchor="first", with_scale=True).errors.max() < 1e-9
    assert drift_vs_distance(est, ref, anchor="aligned", with_scale=True).errors.max() < 1e-9
    with pytest.raises(CodeSLAMError, match="anchor"):
        drift_vs_distance(est, ref, anchor="last")


def test_segment_errors_of_scaled_copy():
    ref = helix(300)
    est = transformed(ref, random_sim3(np.random.default_rng(7), 1.05))
    path = ref.path_length
    segs = segment_errors(est, ref, lengths=(1.0, 2.0, 1e6))
    assert [s.length for s in segs] == [1.0, 2.0]  # no segment is a million metres long
    # 5 % too long everywhere; the chord of a segment is shorter than L, so the error is below 5 % of L.
    for s in segs:
        assert 0 < s.trans_pct < 5.0 and s.rot_deg_per_m < 1e-9 and s.n > 0
    assert all(s.trans_pct < 1e-9 for s in segment_errors(est, ref, lengths=(1.0,), with_scale=True))
    assert path > 2.0


def _growing(ref: Trajectory, a: float, b: float) -> Trajectory:
    """The reference's positions times a, over its first 30% of path, times b over its last 30%, and between the
    two a factor that moves linearly with the path: a map whose scale grew by b / a."""
    xyz = ref.positions_xyz.numpy()
    d = accumulated_distances(xyz) / ref.path_length
    k = np.interp(d, [0.3, 0.7], [a, b])
    T = ref.poses.numpy().copy()
    T[:, :3, 3] = k[:, None] * xyz
    return Trajectory(ref.timestamps.copy(), torch.from_numpy(T))


@pytest.mark.parametrize("straight", [False, True])
def test_scale_drift_reads_how_much_the_maps_scale_grew_from_the_start_to_the_end(straight):
    ref = helix(300)
    if straight:  # a straight walk: collinear segments carry a scale though no unique rotation
        T = ref.poses.numpy().copy()
        T[:, :3, 3] = np.linspace(0, 1, len(T))[:, None] * np.array([10.0, 2.0, 0.5])
        ref = Trajectory(ref.timestamps.copy(), torch.from_numpy(T))
        with pytest.raises(CodeSLAMError, match="collinear"):
            ate(ref, ref, align="sim3")
    est = transformed(_growing(ref, 0.5, 0.8), random_sim3(np.random.default_rng(9), 3.0))  # any frame, any scale
    drift = scale_drift(est, ref)
    assert drift.growth == pytest.approx(0.8 / 0.5, rel=1e-9)
    assert drift.start == pytest.approx(1 / (3.0 * 0.5), rel=1e-9) and drift.reliable
    assert drift.fit_start < 1e-9 and drift.fit_end < 1e-9 and drift.n_start > 3 and drift.n_end > 3
    held = transformed(ref, random_sim3(np.random.default_rng(2), 0.7))  # one scale all along
    assert scale_drift(held, ref).growth == pytest.approx(1.0, rel=1e-9)


def test_scale_drift_of_a_camera_turning_on_the_spot_is_not_read():
    from codeslam.eval.slam_run import evaluate_run

    ref = helix(200)
    T = ref.poses.numpy().copy()
    T[:, :3, 3] = 0.002 * np.random.default_rng(0).normal(size=(len(T), 3))  # 2 mm of shake, no path
    spot = Trajectory(ref.timestamps.copy(), torch.from_numpy(T))
    E = T.copy()
    E[:, :3, 3] += 0.002 * np.random.default_rng(1).normal(size=(len(T), 3))  # the estimate's noise as large
    noisy = Trajectory(ref.timestamps.copy(), torch.from_numpy(E))
    drift = scale_drift(noisy, spot)
    assert not drift.reliable and max(drift.fit_start, drift.fit_end) > 0.5
    assert evaluate_run(noisy, spot)["scale_drift"] is None
    assert evaluate_run(_growing(ref, 1.0, 1.25), ref)["scale_drift"] == pytest.approx(1.25, rel=1e-9)
    with pytest.raises(CodeSLAMError, match="share"):
        scale_drift(noisy, spot, fraction=0.6)
    with pytest.raises(CodeSLAMError, match="at least 3"):
        scale_drift(ref, ref, fraction=0.001)


def test_evaluate_summary_keys():
    ref = helix()
    est = transformed(ref, random_sim3(np.random.default_rng(8), 0.5))
    summ = evaluate(est, ref, align="sim3").summary()
    for key in ("ate_rmse", "ate_mean", "ate_median", "ate_max", "rpe_trans_rmse", "rpe_rot_rmse_deg",
                "n_matched", "align", "scale", "path_length_gt"):
        assert key in summ
    assert summ["scale"] == pytest.approx(2.0)
    assert summ["ate_rmse"] < 1e-12
    assert summ["path_length_gt"] == pytest.approx(ref.path_length)


def test_orientation_errors_after_the_best_rotation_alignment():
    from codeslam.eval.metrics import orientation_errors_aligned
    from codeslam.geometry.lie import so3_exp

    g = torch.Generator().manual_seed(4)
    R_ref = so3_exp(0.5 * torch.randn(30, 3, generator=g, dtype=torch.float64)).numpy()
    R_w = so3_exp(torch.tensor([0.3, -0.2, 0.7], dtype=torch.float64)).numpy()
    # The estimate lives in a rotated world frame: after alignment its orientations are exact.
    est = np.swapaxes(R_w, 0, 1) @ R_ref
    assert np.abs(orientation_errors_aligned(est, R_ref)).max() < 1e-9
    # With per-frame noise of known angle the aligned errors are about that angle, and never above the raw ones.
    noise = so3_exp(0.02 * torch.randn(30, 3, generator=g, dtype=torch.float64)).numpy()
    err = orientation_errors_aligned(est @ noise, R_ref)
    raw = orientation_errors_aligned(R_ref @ noise, R_ref)
    assert np.sqrt(np.mean(err**2)) <= np.sqrt(np.mean(raw**2)) + 1e-9
    assert 0.01 < np.sqrt(np.mean(err**2)) < 0.06


def test_a_runs_rpe_is_also_read_after_the_sim3_scale():
    """A monocular map at half the true scale: its per-frame translations are half the truth's, so the rigid RPE
    is half the true motion per frame while the Sim(3)-scaled one (evo_rpe -as) is zero."""
    from codeslam.eval.slam_run import evaluate_run

    gt = helix()
    est = transformed(gt, random_sim3(np.random.default_rng(3), 0.5))
    out = evaluate_run(est, gt)
    step = np.linalg.norm(np.diff(gt.positions_xyz.numpy(), axis=0), axis=1)
    assert out["rpe_trans_rmse"] == pytest.approx(0.5 * np.sqrt(np.mean(step**2)), rel=1e-6)
    assert out["rpe_trans_sim3_rmse"] < 1e-9
    assert out["sim3_scale"] == pytest.approx(2.0, rel=1e-9)
