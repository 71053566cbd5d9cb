"""The tracker's dedicated solver (codeslam.slam.alignment): its analytic Jacobians against autograd in float64,
its normal equations against the dense J^T W J and the cost's gradient, and the same frames tracked by the
dedicated and the generic solver ending at the same pose and cost (generator frames and real TUM frames)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from slam_scene import small_config, synth_frames

from codeslam.geometry.camera import pixel_grid, project
from codeslam.geometry.image import pixels_to_grid, rgb_to_gray
from codeslam.geometry.lie import se3_act, se3_exp, se3_inverse, se3_log
from codeslam.sfm.keyframes import Keyframe
from codeslam.sfm.variables import CODE, POSE, BlockId, VariableLayout
from codeslam.slam.alignment import (
    FramePyramid,
    KeypointTerm,
    PosePrior,
    TrackingProblem,
    TrackingReference,
    TrackingState,
    photometric_jacobian,
    photometric_residuals,
)
from codeslam.slam.depth import standin_depth_model, standin_true_code
from codeslam.slam.reprojection import ReprojectionTerm
from codeslam.slam.tracker import PhotometricTracker

D = torch.float64
LAYOUT = VariableLayout.for_sfm(2, 1, 1, True, [BlockId(POSE, 0), BlockId(CODE, 0), BlockId(CODE, 1)])


def _scene(dtype=D, gradient_mode="sobel", motion_prior=0.0):
    """Generator frames, the small SLAM config's tracker (both solvers), the keyframe with the stand-in depth model
    and the code at which that depth is right."""
    frames = synth_frames(3, 12, 10.0)
    cfg = small_config()
    cfg = replace(cfg, tracker=replace(cfg.tracker, motion_prior_acceleration=motion_prior,
                                       motion_prior_angular_acceleration_deg=50.0 if motion_prior else 0.0),
                  window=replace(cfg.window, sfm=replace(cfg.window.sfm, gradient_mode=gradient_mode)))
    trackers = {s: PhotometricTracker(cfg.tracker, cfg.window.sfm, solver=s) for s in ("generic", "dedicated")}
    dec = standin_depth_model(num_levels=3, seed=7)(frames[0])
    kf = Keyframe(frames[0].gray.to(dtype), frames[0].camera, dec.to(dtype))
    return frames, trackers, kf, standin_true_code(0, 32, 0.2, seed=7).to(dtype)


def _keypoints(frames, j, dtype=D, every=37, noise=1.0, seed=0):
    """Keypoints of frame 0 (every ``every``-th pixel, true depth) matched to frame j in a camera with 4x the
    pixels, their observations moved by ``noise`` pixels: a ReprojectionTerm keyframe -> frame."""
    cam0 = frames[0].camera
    cam = cam0.scaled(4.0)
    uv = pixel_grid(cam0.height, cam0.width, D).reshape(-1, 2)[::every]
    d = frames[0].depth.to(D).reshape(-1)[::every]
    ray = torch.cat([(uv - torch.tensor([cam0.cx, cam0.cy], dtype=D)) / torch.tensor([cam0.fx, cam0.fy], dtype=D),
                     torch.ones(len(d), 1, dtype=D)], dim=1)
    xyz = ray * d[:, None]
    T_BA = se3_inverse(frames[j].pose) @ frames[0].pose
    g = torch.Generator().manual_seed(seed)
    uv_b = project(se3_act(T_BA, xyz), cam.params(D)) + noise * torch.randn(len(d), 2, generator=g, dtype=D)
    return ReprojectionTerm(0, 1, xyz.to(dtype), uv_b.to(dtype), torch.full((len(d),), 1.5, dtype=dtype), cam)


def _level_problem(lvl=1, gradient_mode="interpolant", with_keypoints=True, masked_rows=None):
    """One level of the tracking problem of frame 2 at a pose and brightness off the optimum (float64); the
    tracker's ``masked_rows`` unless given."""
    frames, trackers, kf, code = _scene(D, gradient_mode)
    tracker = trackers["dedicated"]
    ref = tracker.reference(kf, code).levels[lvl]
    frame = FramePyramid(frames[2].gray, frames[2].camera, None, (lvl,), D, torch.device("cpu")).levels[lvl]
    T_true = se3_inverse(frames[0].pose) @ frames[2].pose
    T_kf = se3_exp(torch.tensor([0.004, -0.003, 0.002, 0.003, -0.004, 0.002], dtype=D)) @ T_true
    state = TrackingState(T_kf.numpy(), torch.tensor([0.05, -0.02], dtype=D).numpy())
    kp = KeypointTerm(_keypoints(frames, 2), D, torch.device("cpu")) if with_keypoints else None
    cfg = tracker.sfm_cfg if masked_rows is None else replace(tracker.sfm_cfg, masked_rows=masked_rows)
    return TrackingProblem(ref, frame, cfg, kp), state


def _relative(T_kf):
    T_BA = se3_inverse(T_kf)
    return T_BA[:3, :3], T_BA[:3, 3]


def test_photometric_jacobian_matches_autograd_float64():
    problem, state = _level_problem()
    R_BA, t_BA = _relative(torch.from_numpy(state.T_kf))
    ev = photometric_residuals(problem.ref, problem.frame, R_BA, t_BA, torch.from_numpy(state.affine), problem.cfg)
    valid = ev.valid
    J = photometric_jacobian(ev.x[:, valid], ev.grad_B[:, valid], ev.gray_B[valid], ev.gain, problem.frame.params)

    def residuals(theta):  # left increment of T_BA, then the affine parameters
        T = se3_exp(theta[:6]) @ se3_inverse(torch.from_numpy(state.T_kf))
        affine = torch.from_numpy(state.affine) + theta[6:]
        return photometric_residuals(problem.ref, problem.frame, T[:3, :3], T[:3, 3], affine, problem.cfg).r

    J_auto = torch.autograd.functional.jacobian(residuals, torch.zeros(8, dtype=D))  # (N, 8)
    assert int(valid.sum()) > 0.5 * valid.numel() and ev.r[valid].abs().max() > 0.05  # away from the optimum
    torch.testing.assert_close(J.T, J_auto[valid], atol=1e-9, rtol=1e-7)
    assert J_auto[~valid].abs().max() == 0  # masked rows do not move


def test_keypoint_jacobian_matches_autograd_float64():
    problem, state = _level_problem()
    kp = problem.keypoints
    R_BA, t_BA = _relative(torch.from_numpy(state.T_kf))
    _, r, x, _ = kp.evaluate(R_BA, t_BA)
    J = kp.jacobian(x)  # (6, 2, M)

    def residuals(xi):
        T = se3_exp(xi) @ se3_inverse(torch.from_numpy(state.T_kf))
        return kp.evaluate(T[:3, :3], T[:3, 3])[1]  # (2, M)

    J_auto = torch.autograd.functional.jacobian(residuals, torch.zeros(6, dtype=D))  # (2, M, 6)
    assert r.abs().max() > 1.0
    torch.testing.assert_close(J.permute(1, 2, 0), J_auto, atol=1e-9, rtol=1e-7)


def test_keypoint_inliers_are_the_reprojection_terms_own():
    frames, _, _, _ = _scene(D)
    term = _keypoints(frames, 2, noise=3.0, seed=1)
    kp = KeypointTerm(term, D, torch.device("cpu"))
    T_kf = se3_exp(torch.tensor([0.01, -0.005, 0.0, 0.002, 0.0, -0.003], dtype=D)) @ (
        se3_inverse(frames[0].pose) @ frames[2].pose)
    state = TrackingState(T_kf.numpy(), torch.zeros(2, dtype=D).numpy())
    R_BA, t_BA = _relative(T_kf)
    _, r, x, _ = kp.evaluate(R_BA, t_BA)
    for threshold in (1.0, 3.0, 6.0):
        ours = KeypointTerm.inliers(r, x, threshold)
        assert 0 < int(ours.sum()) < len(term)  # the threshold splits the matches
        assert torch.equal(ours, term.inliers(state.to_sfm(), threshold))


@pytest.mark.parametrize("masked_rows", ["threshold", "common"])
def test_the_constants_a_problem_makes_once_give_its_evaluations_bit_for_bit(masked_rows):
    # TrackingProblem makes the photometric cost's constants once (PhotometricConstants), the frame level its
    # intrinsics and pixels_to_grid's scale (FrameLevel): the frame level's are its params and its size's scale, and
    # an evaluation with the problem's constants is, to the last bit, one that makes the constants as it goes.
    problem, state = _level_problem(masked_rows=masked_rows)
    frame = problem.frame
    assert torch.equal(torch.stack(frame.intrinsics), frame.params)
    uv = torch.rand(7, 2, dtype=D, generator=torch.Generator().manual_seed(3)) * 60.0
    assert torch.equal(pixels_to_grid(uv, frame.height, frame.width, frame.grid_scale),
                       pixels_to_grid(uv, frame.height, frame.width))
    R_BA, t_BA = _relative(torch.from_numpy(state.T_kf))
    affine = torch.from_numpy(state.affine)
    made_here = photometric_residuals(problem.ref, problem.frame, R_BA, t_BA, affine, problem.cfg)
    _, ev = problem.evaluate(state)
    for name in ("r", "valid", "w", "sigma", "cost", "row_cost", "gray_B", "grad_B", "x"):
        assert torch.equal(getattr(ev, name), getattr(made_here, name)), name
    # and both are the loss's definitions, written out here: Huber (iii) of r / sigma (ii), slant-weighted (iv),
    # masked rows at rho(k) ('threshold') or at the valid rows' mean ('common') (i)
    sigma, k = problem.cfg.sigma_photometric, problem.cfg.huber_photometric
    s = ev.r / sigma
    a = s.abs()
    rho = torch.where(a <= k, 0.5 * s * s, k * a - 0.5 * k * k)
    vf = ev.valid.to(D)
    irls = torch.where(a <= k, torch.ones_like(a), k / a)
    torch.testing.assert_close(ev.w, problem.ref.slant * irls * vf / sigma**2)
    rows, n, N = (problem.ref.slant * rho * vf).sum(), vf.sum(), ev.r.numel()
    expected = rows + 0.5 * k * k * (N - n) if masked_rows == "threshold" else rows * N / n
    assert 0 < n < N  # some rows masked: their price is tested
    torch.testing.assert_close(ev.cost, expected)


@pytest.mark.parametrize("masked_rows", ["threshold", "common"])
@pytest.mark.parametrize("with_keypoints", [False, True])
def test_normal_equations_are_the_dense_irls_system_and_the_cost_gradient(with_keypoints, masked_rows):
    # 'threshold': the normal equations are the robust cost's. 'common' (the SLAM default): the cost prices the
    # masked rows at the valid rows' mean, N / n times their sum; the steps descend that sum (what the solver
    # judges them on, over the rows valid before and after: TrackingProblem.cost_change).
    problem, state = _level_problem(with_keypoints=with_keypoints, masked_rows=masked_rows)
    cost, ev = problem.evaluate(state)
    H, g = (torch.from_numpy(a) for a in problem.linearize(state, ev, LAYOUT))  # float64 on the host
    sig = torch.tensor(problem.cfg.affine_prior_sigma, dtype=D)

    def pieces(theta):  # left increment of the frame's pose T_kf, then the affine parameters
        T_kf = se3_exp(theta[:6]) @ torch.from_numpy(state.T_kf)
        R_BA, t_BA = _relative(T_kf)
        affine = torch.from_numpy(state.affine) + theta[6:]
        e = photometric_residuals(problem.ref, problem.frame, R_BA, t_BA, affine, problem.cfg)
        others = 0.5 * (affine / sig).square().sum()
        r = [e.r]
        if problem.keypoints is not None:
            c, r_k, _, _ = problem.keypoints.evaluate(R_BA, t_BA)
            others, r = others + c, [*r, r_k.reshape(-1)]
        descended = e.cost if masked_rows == "threshold" else e.row_cost.sum()
        return descended + others, torch.cat(r), e.cost + others

    theta = torch.zeros(8, dtype=D, requires_grad=True)
    descended, _, total = pieces(theta)
    (grad,) = torch.autograd.grad(descended, theta)
    assert abs(float(total.detach()) - cost) <= 1e-12 * cost
    if masked_rows == "common":
        n, N = int(ev.valid.sum()), ev.valid.numel()
        assert 0 < n < N  # some rows masked: the two costs differ
        descended_cost, total_cost = float(descended.detach()), float(total.detach())
        assert descended_cost < total_cost - 1e-6 * total_cost
    torch.testing.assert_close(g, grad, atol=1e-8, rtol=1e-8)  # IRLS: J^T W r is the descended cost's gradient

    J = torch.autograd.functional.jacobian(lambda t: pieces(t)[1], torch.zeros(8, dtype=D))  # (rows, 8)
    w = [ev.w]
    if problem.keypoints is not None:
        w.append(ev.keypoints[3].repeat(2))
    W = torch.cat(w)
    H_dense = J.T @ (W[:, None] * J) + torch.diag(torch.cat([torch.zeros(6, dtype=D), 1.0 / sig**2]))
    torch.testing.assert_close(H, H_dense, atol=1e-8, rtol=1e-8)


class _SeenAsGeneric:
    """A term the tracking problem knows only by the generic interface (``cost``, ``add_to`` on the generic
    state), as it takes any term that is neither the keypoints' nor a prior on the frame's pose."""

    def __init__(self, term):
        self.term = term

    def cost(self, state):
        return self.term.cost(state)

    def add_to(self, H, g, layout, state):
        self.term.add_to(H, g, layout, state)


def test_a_term_through_the_generic_interface_adds_what_the_tracker_adds_on_the_host():
    # The frame's pose prior, added by the problem on the host (float64 NumPy) or through the generic interface on
    # the keyframe's tensors: the same cost and normal equations.
    problem, state = _level_problem()
    T_pred = se3_exp(torch.tensor([0.01, 0.0, -0.005, 0.0, 0.004, 0.0], dtype=D)) @ torch.from_numpy(state.T_kf)
    prior = PosePrior(1, torch.diag(torch.tensor([1e5] * 3 + [3e5] * 3, dtype=D)), T_pred)
    host, generic = (TrackingProblem(problem.ref, problem.frame, problem.cfg, problem.keypoints, [t])
                     for t in (prior, _SeenAsGeneric(prior)))
    assert host.pose_priors and not host.terms and generic.terms and not generic.pose_priors
    (c_h, ev_h), (c_g, ev_g) = host.evaluate(state), generic.evaluate(state)
    assert c_h > problem.evaluate(state)[0] + 1.0  # the prior is far enough from the state to count
    assert abs(c_h - c_g) <= 1e-12 * c_h
    for a, b in zip(host.linearize(state, ev_h, LAYOUT), generic.linearize(state, ev_g, LAYOUT)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)


def _pose_difference(a, b, depth):
    e = se3_log(se3_inverse(a) @ b)
    return float(e[3:].norm()), float(e[:3].norm()) / depth


def _same_result(res, depth, rot=1e-4, trans=1e-4, cost=1e-6):
    g, d = res["generic"], res["dedicated"]
    dr, dt = _pose_difference(g.T_kf, d.T_kf, depth)
    assert dr < rot and dt < trans, (dr, dt)
    assert abs(g.cost - d.cost) <= cost * abs(g.cost), (g.cost, d.cost)
    assert (g.ok, g.reason, g.iterations) == (d.ok, d.reason, d.iterations)
    assert abs(g.overlap - d.overlap) < 1e-3 and abs(g.inlier_ratio - d.inlier_ratio) < 1e-3
    assert torch.allclose(g.affine, d.affine, atol=1e-4)
    assert g.feature_inliers == d.feature_inliers


@pytest.mark.parametrize("dtype, rot, cost", [(D, 1e-9, 1e-9), (torch.float32, 1e-4, 1e-5)])
def test_dedicated_and_generic_solvers_track_generator_frames_alike(dtype, rot, cost):
    # float64: the two agree to rounding; float32 (SLAM's default): measured 3e-8 rad and 2.4e-7 of the cost (the
    # cost is summed over the pixels in another order).
    frames, trackers, kf, code = _scene(dtype)
    depth = float(frames[0].depth.median())
    for j in (1, 3):
        res = {s: t.track(kf, code, frames[j].gray, frames[j].camera, torch.eye(4, dtype=D))
               for s, t in trackers.items()}
        assert res["generic"].ok
        _same_result(res, depth, rot, rot, cost)


def test_dedicated_and_generic_solvers_agree_with_keypoints_and_the_motion_prior():
    frames, trackers, kf, code = _scene(torch.float32, motion_prior=1.0)
    depth = float(frames[0].depth.median())
    for j in (2, 4):
        term = _keypoints(frames, j, torch.float32)
        T_prior = se3_inverse(frames[0].pose) @ frames[j].pose
        res = {s: t.track(kf, code, frames[j].gray, frames[j].camera, torch.eye(4, dtype=D), reprojection=term,
                          min_feature_inliers=20, T_kf_prior=T_prior, prior_dt=0.1) for s, t in trackers.items()}
        assert res["generic"].ok and res["generic"].feature_inliers > 0.9 * len(term)
        _same_result(res, depth, cost=1e-5)


def test_the_motion_prior_alone_without_keypoints_tracks():
    """A frame with no matched keypoints (a blank wall) and the motion prior on: the prior is the only extra term
    (it once was taken for the keypoints' and the frame failed with an internal error)."""
    frames, trackers, kf, code = _scene(torch.float32, motion_prior=1.0)
    T_prior = se3_inverse(frames[0].pose) @ frames[2].pose
    res = {s: t.track(kf, code, frames[2].gray, frames[2].camera, torch.eye(4, dtype=D), T_kf_prior=T_prior,
                      prior_dt=0.1) for s, t in trackers.items()}
    assert res["generic"].ok and res["generic"].feature_matches == 0
    _same_result(res, float(frames[0].depth.median()), cost=1e-5)


def test_the_motion_priors_noise_grows_with_the_square_of_the_frame_interval():
    """A constant-velocity model's unexplained acceleration a moves the frame by about a dt^2 per frame: at 10
    frames per second the prior's noise is 4 times, its information 16 times what they are at 20."""
    _, trackers, _, _ = _scene(D, motion_prior=2.0)
    t = trackers["dedicated"]
    H = {dt: torch.diag(t._motion_prior(torch.eye(4, dtype=D), dt, D, torch.device("cpu")).H) for dt in (0.05, 0.1)}
    sigma_t = 2.0 * 0.1**2  # translation noise at dt = 0.1: 2 cm
    sigma_r = math.radians(50.0 * 0.1**2)  # rotation: 0.5 deg
    torch.testing.assert_close(H[0.1], torch.tensor([sigma_t**-2] * 3 + [sigma_r**-2] * 3, dtype=D))
    torch.testing.assert_close(H[0.05], 16.0 * H[0.1])


def test_interpolant_gradients_track_alike():
    frames, trackers, kf, code = _scene(D, gradient_mode="interpolant")
    res = {s: t.track(kf, code, frames[2].gray, frames[2].camera, torch.eye(4, dtype=D)) for s, t in trackers.items()}
    _same_result(res, float(frames[0].depth.median()), 1e-9, 1e-9, 1e-9)


def test_validity_masks_track_alike_and_the_mask_pyramid_is_kept_while_the_mask_stays():
    frames, trackers, kf, code = _scene()
    depth = float(frames[0].depth.median())
    valid = torch.ones(frames[0].camera.height, frames[0].camera.width, dtype=torch.bool)
    valid[-3:] = False  # a border the reader could not fill
    kf = Keyframe(kf.image, kf.camera, kf.decoder, valid)
    dedicated = trackers["dedicated"]
    for j, mask in ((1, valid), (2, valid.clone()), (3, valid.clone())):
        if j == 3:
            mask[10:20, 30:40] = False  # another mask: its pyramid is rebuilt
        res = {s: t.track(kf, code, frames[j].gray, frames[j].camera, torch.eye(4, dtype=D), valid=mask)
               for s, t in trackers.items()}
        assert res["generic"].overlap < 0.95
        _same_result(res, depth, 1e-9, 1e-9, 1e-9)
        if j == 1:
            kept = dedicated._real_pixels[2]
        else:
            assert (dedicated._real_pixels[2] is kept) == (j == 2)


def test_a_frames_mask_pyramid_built_with_its_image_is_the_masks_own_bit_for_bit():
    """FramePyramid builds an unseen mask's pyramid in the same call as the image's: the same masks and levels as
    the mask's own pyramid gives (build_levels' definition: 1 where only real pixels contribute), to the last bit."""
    from codeslam.geometry.image import image_pyramid
    from codeslam.sfm.keyframes import real_pixels
    from codeslam.slam.alignment import FramePyramid

    frames, *_ = _scene()
    f = frames[1]
    valid = torch.ones(f.camera.height, f.camera.width, dtype=torch.bool)
    valid[-3:] = False
    valid[10:20, 30:40] = False
    for dtype in (torch.float32, D):
        for levels in ((1, 0), (3, 2, 1, 0)):
            own = image_pyramid(valid.to(dtype)[None, None], max(levels) + 1)  # the mask's pyramid alone
            real = {lvl: real_pixels(own[lvl]) for lvl in levels}
            given = FramePyramid(f.gray, f.camera, valid, levels, dtype, torch.device("cpu"), real)
            built = FramePyramid(f.gray, f.camera, valid, levels, dtype, torch.device("cpu"))
            assert built.real.keys() == real.keys() == set(levels)
            for lvl in levels:
                assert torch.equal(built.real[lvl], real[lvl])
                assert torch.equal(built.levels[lvl].stack, given.levels[lvl].stack)
                assert float(built.levels[lvl].stack[0, 3].min()) == 0.0  # the mask's holes are there
    assert FramePyramid(f.gray, f.camera, None, (0,), D, torch.device("cpu")).real is None


@pytest.fixture(scope="module")
def tum_model():
    from codeslam.depthmodel import DepthModel

    return DepthModel.load(None)  # the shipped default weights


@pytest.mark.parametrize("j", [2, 6])
def test_dedicated_and_generic_solvers_track_real_tum_frames_alike(tum_rpy, tum_model, j):
    # Real frames (TUM fr1/rpy, 128x96 with the canonical frames' validity masks), the network's depth at the zero
    # code, float32 as in SLAM, four pyramid levels from the identity. Measured: rotation 5e-8 rad, translation
    # 1.4e-7 of the median depth, cost 2-4e-7 (its sum over 12,288 pixels in float32 in another order; up to 1.7e-6
    # over frames 1-60 in benchmarks/bench_tracker.py).
    from codeslam.data.registry import open_dataset
    from codeslam.slam.config import SLAMConfig

    model = tum_model
    seq = open_dataset(tum_rpy)
    kf = model.keyframe(model.canonical(seq[0]))
    code = torch.zeros(kf.decoder.code_size, dtype=kf.decoder.levels[0].jac.dtype)
    depth = float(kf.decoder.depth(code).median())
    cfg = SLAMConfig()
    frame = model.canonical(seq[j])
    gray = rgb_to_gray(frame.image[None])[0]
    res = {}
    for solver in ("generic", "dedicated"):
        tracker = PhotometricTracker(cfg.tracker, cfg.window.sfm, solver=solver)
        res[solver] = tracker.track(kf, code, gray, model.camera, torch.eye(4, dtype=D), valid=frame.valid)
    assert res["generic"].ok and frame.valid is not None and not bool(frame.valid.all())
    _same_result(res, depth, cost=1e-5)


def test_the_keyframe_reference_is_kept_until_its_code_changes():
    frames, trackers, kf, code = _scene()
    tracker = trackers["dedicated"]
    ref = tracker.reference(kf, code)
    assert tracker.reference(kf, code.clone()) is ref  # same values: reused
    other = code.clone()
    other[0] += 0.1
    ref2 = tracker.reference(kf, other)
    assert ref2 is not ref and tracker.reference(kf, code) is ref  # a changed code: rebuilt; the old one kept
    kf2 = Keyframe(kf.image, kf.camera, kf.decoder)
    assert tracker.reference(kf2, code) is not ref  # another keyframe object
    # The reference decodes the depth at its code: tracking with the changed code equals the generic solver's.
    res = {s: t.track(kf, other, frames[1].gray, frames[1].camera, torch.eye(4, dtype=D))
           for s, t in trackers.items()}
    _same_result(res, float(frames[0].depth.median()), 1e-9, 1e-9, 1e-9)
    fresh = TrackingReference(kf, code, (0,), tracker.sfm_cfg, D, torch.device("cpu"))
    assert fresh.matches(kf, code) and not fresh.matches(kf, other) and not fresh.matches(kf, code[:3])


def test_a_start_from_the_matches_skips_the_coarse_levels_and_ends_where_all_levels_do(monkeypatch):
    """``tracker.feature_start_level``: with a start pose vouched for by enough matches the alignment begins at that
    level; a frame started by the motion model alone still visits every level. Both end at the same pose."""
    import codeslam.sfm.solver as solver_module  # the coarse-to-fine loop calls its levenberg_marquardt

    frames, trackers, kf, code = _scene(torch.float32)
    cfg, sfm_cfg = trackers["dedicated"].cfg, trackers["dedicated"].sfm_cfg
    levels = cfg.pyramid_levels
    assert len(levels) >= 3
    start = sorted(levels)[1]  # skip all but the two finest
    base = PhotometricTracker(replace(cfg, feature_start_level=-1), sfm_cfg)
    skipping = PhotometricTracker(replace(cfg, feature_start_level=start), sfm_cfg)
    visited = []
    lm = solver_module.levenberg_marquardt

    def recording(problem, *args, **kwargs):
        visited.append(problem.ref.gray.numel())  # the level's pixel count tells the level
        return lm(problem, *args, **kwargs)

    monkeypatch.setattr(solver_module, "levenberg_marquardt", recording)
    depth = float(frames[0].depth.median())
    for j in (2, 4):
        term = _keypoints(frames, j, torch.float32)
        T_true = se3_inverse(frames[0].pose) @ frames[j].pose
        T_start = se3_exp(torch.tensor([0.002, -0.001, 0.001, 0.002, 0.001, -0.002], dtype=D)) @ T_true  # a PnP pose
        res = {}
        for name, t in (("all", base), ("skip", skipping)):
            visited.clear()
            res[name] = t.track(kf, code, frames[j].gray, frames[j].camera, T_start, reprojection=term,
                                min_feature_inliers=20)
            res[name + " levels"] = list(visited)
        assert len(res["all levels"]) == len(levels) and len(res["skip levels"]) == 2
        assert res["skip levels"] == res["all levels"][-2:]  # the two finest, in order
        assert res["all"].ok and res["skip"].ok
        err = {k: _pose_difference(res[k].T_kf, T_true, depth) for k in ("all", "skip")}
        # measured (rotation rad, translation / depth): all levels (1.7e-3, 8.1e-4) and (9.8e-4, 1.8e-3), the
        # finest two (1.4e-3, 6.6e-4) and (9.4e-4, 1.7e-3)
        assert all(s <= 1.2 * a for s, a in zip(err["skip"], err["all"])), err
        visited.clear()  # too few matches to vouch for the start: every level
        skipping.track(kf, code, frames[j].gray, frames[j].camera, T_start, reprojection=term,
                       min_feature_inliers=len(term) + 1)
        assert len(visited) == len(levels)
        visited.clear()  # a start that is not the matches' (the retry from the prediction): every level
        skipping.track(kf, code, frames[j].gray, frames[j].camera, T_start, reprojection=term,
                       min_feature_inliers=20, every_level=True)
        assert len(visited) == len(levels)


def test_keypoints_vouch_for_a_pose_far_from_the_motion_models_prediction():
    # The rotation check against the motion model fails a frame only where no matched keypoints agree with its pose.
    frames, trackers, kf, code = _scene(torch.float32)
    T_true = se3_inverse(frames[0].pose) @ frames[2].pose
    T_prior = T_true @ se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.0, math.radians(30.0), 0.0], dtype=D))
    term = _keypoints(frames, 2, torch.float32)
    alone = trackers["dedicated"].track(kf, code, frames[2].gray, frames[2].camera, torch.eye(4, dtype=D),
                                        T_kf_prior=T_prior)
    vouched = trackers["dedicated"].track(kf, code, frames[2].gray, frames[2].camera, torch.eye(4, dtype=D),
                                          reprojection=term, min_feature_inliers=20, T_kf_prior=T_prior)
    assert not alone.ok and "motion model" in alone.reason, alone.reason
    assert vouched.ok and vouched.feature_inliers >= 20, (vouched.reason, vouched.feature_inliers)
    assert "motion model" in vouched.photometric_reason
