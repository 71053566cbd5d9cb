"""Tracking (paper Sec. 4.2): the current frame is paired with the last keyframe and its pose relative to that
keyframe is the minimiser of the photometric error, coarse to fine over the image pyramid. The keyframe's depth
(decoded at its current code) is held fixed and there is no geometric term: the frame has no depth of its own.

The cost is that of a two-frame instance of the SfM back-end (:class:`~codeslam.sfm.PairProblem` with the
keyframe as frame 0 at the identity and the frame as frame 1 without a decoder): the mapping's residuals and loss
functions, minimised by its damped Gauss-Newton solver; only the frame's pose and the pair's affine brightness
are free. By default it is solved by :mod:`codeslam.slam.alignment`, written for those 8 variables, with the
keyframe's side computed once per keyframe and code (TUM fr1/rpy at 128x96, one thread: median 77 -> 14 ms per
frame, poses within 1e-6, ``benchmarks/bench_tracker.py``); the generic problem stays reachable
(``solver='generic'``) to check it. The result is checked before it is trusted: a non-finite cost or pose, too
little overlap or too few photometric inliers mark the tracking as failed, and the caller falls back to its
motion model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from codeslam.geometry.camera import PinholeCamera
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import Keyframe, build_levels
from codeslam.sfm.solver import PairProblem, coarse_to_fine
from codeslam.sfm.variables import AFFINE_DIM, CODE, POSE, BlockId, SfMState, VariableLayout
from codeslam.slam.alignment import (
    FramePyramid,
    KeypointTerm,
    PosePrior,
    TrackingProblem,
    TrackingReference,
    TrackingState,
    fixed_depth_decoder,
)
from codeslam.slam.config import TrackerConfig
from codeslam.slam.features import pose_distance
from codeslam.slam.poses import project_to_se3
from codeslam.slam.reprojection import ReprojectionTerm


@dataclass
class TrackResult:
    """Outcome of tracking one frame against a keyframe.

    Attributes:
        T_kf: (4, 4) float64 pose of the frame in the keyframe's camera frame (``T_kf`` maps the frame's points
            into the keyframe; with the keyframe's ``T_wk`` the frame's pose is ``T_wk @ T_kf``).
        affine: (2,) log-gain and bias of ``I_keyframe ~ exp(a) I_frame + b``.
        ok: whether the estimate passed the checks; when False, ``T_kf`` is the optimiser's output for
            diagnosis only and must not be used as the frame's pose.
        reason: why tracking failed ('' when ok).
        overlap: fraction of the keyframe's pixels (finest tracked level) that land inside the frame.
        inlier_ratio: fraction of those whose photometric residual is below ``inlier_sigmas`` sigmas.
        explained: ``1 - mean(r^2) / var(I_keyframe)`` over those pixels, the share of the keyframe's intensity
            variance the warped frame explains (near 1 when aligned; an unrelated image can keep many residuals
            small by fitting a near-zero gain, but explains little of the variance).
        cost: final robust cost at the finest level; iterations: LM iterations over all levels.
        feature_matches, feature_inliers: reprojection residuals in the alignment and those within the PnP
            threshold at the final pose (0 without features).
        photometric_reason: why the photometric checks alone would have failed ('' when they pass); tracking is
            still ok when enough feature matches agree with the pose (forward motion changes much of the image
            and fails the explained-variance check while the pose is right).
        residual: RMS photometric residual over the overlap at the finest level (intensity units).
        texture: standard deviation of the keyframe's intensities over that overlap, what the alignment has to go
            on (a blank wall in the generator's fast turns: 0.05, textured views 0.1-0.2; below
            ``min_intensity_std`` the tracking fails).
    """

    T_kf: torch.Tensor
    affine: torch.Tensor
    ok: bool
    reason: str
    overlap: float
    inlier_ratio: float
    explained: float
    cost: float
    iterations: int
    feature_matches: int = 0
    feature_inliers: int = 0
    photometric_reason: str = ""
    residual: float = float("nan")
    texture: float = float("nan")


SOLVERS = ("dedicated", "generic")
REFERENCE_CACHE_SIZE = 4  # keyframes whose tracking data are kept (the reference and relocalisation candidates)


class PhotometricTracker:
    """Coarse-to-fine photometric alignment of a frame to a keyframe (paper Sec. 4.2).

    cfg: levels, iterations and failure thresholds; residuals: the photometric residual's settings (sigma, Huber,
    border, slant and occlusion weights), normally the window's SfM config (its geometric term is switched off).
    solver: 'dedicated' (:class:`~codeslam.slam.alignment.TrackingProblem`, the keyframe's side cached per keyframe
    and code) or 'generic' (the two-frame :class:`~codeslam.sfm.solver.PairProblem`, rebuilt for every frame); both
    minimise the same cost with the same Levenberg-Marquardt loop, the generic one is kept to check the other.
    """

    def __init__(self, cfg: TrackerConfig, residuals: SfMConfig, solver: str = "dedicated") -> None:
        if solver not in SOLVERS:
            raise ValueError(f"tracker solver must be one of {SOLVERS}, got {solver!r}")
        self.cfg = cfg
        self.solver = solver
        self.sfm_cfg = replace(
            residuals, photometric=True, geometric=False, affine_brightness=cfg.affine_brightness,
            pyramid_levels=cfg.pyramid_levels, max_iterations=cfg.max_iterations,
            relative_cost_tolerance=cfg.relative_cost_tolerance,
        )
        self._references: list[TrackingReference] = []  # most recently used last
        self._real_pixels: tuple | None = None  # (the frames' validity mask, (dtype, device), its pyramid levels)

    def reference(self, keyframe: Keyframe, code: torch.Tensor) -> TrackingReference:
        """The keyframe's tracking data at ``code`` (points, intensities, slant weights and masks per level), built
        on first use and kept for the next frames while the keyframe and its code stay the same."""
        ref = keyframe.decoder.levels[0].jac
        for i, r in enumerate(self._references):
            if r.dtype == ref.dtype and r.device == ref.device and r.matches(keyframe, code):
                self._references.append(self._references.pop(i))
                return r
        r = TrackingReference(keyframe, code, self.cfg.pyramid_levels, self.sfm_cfg, ref.dtype, ref.device)
        self._references = [*self._references[-(REFERENCE_CACHE_SIZE - 1):], r]
        return r

    def track(
        self,
        keyframe: Keyframe,
        code: torch.Tensor,
        image: torch.Tensor,
        camera: PinholeCamera,
        T_kf_init: torch.Tensor,
        affine_init: torch.Tensor | None = None,
        valid: torch.Tensor | None = None,
        reprojection: ReprojectionTerm | None = None,
        min_feature_inliers: int = 0,
        feature_threshold: float = 3.0,
        T_kf_prior: torch.Tensor | None = None,
        prior_dt: float | None = None,
        every_level: bool = False,
        start_level: int | None = None,
    ) -> TrackResult:
        """Align ``image`` ((1, H, W) grey or (3, H, W) RGB, seen by ``camera``) to ``keyframe`` (with decoder)
        whose depth is decoded at ``code`` (C,), starting from ``T_kf_init`` (4, 4) and ``affine_init`` (2,).
        ``valid`` (H, W) bool marks the image's real pixels (None: all). ``reprojection``: matched keypoints
        (keyframe = frame 0, this frame = frame 1) whose residuals join the photometric ones; the result is then
        also ok when at least ``min_feature_inliers`` of them lie within ``feature_threshold`` pixels; with at
        least that many matches (the PnP inliers that gave ``T_kf_init``) the alignment skips the levels coarser than
        ``cfg.feature_start_level``.
        ``T_kf_prior``: the motion model's prediction of the pose, a soft prior on it (``prior_dt`` seconds since
        the last frame; see ``TrackerConfig.motion_prior_acceleration``). ``every_level``: visit all
        ``cfg.pyramid_levels`` even with the matches (``T_kf_init`` did not come from them). ``start_level``: skip
        the levels coarser than this one (``T_kf_init`` lies within its basin by other evidence)."""
        cfg = self.cfg
        ref = keyframe.decoder.levels[0].jac
        dtype, device = ref.dtype, ref.device
        eye = torch.eye(4, dtype=dtype, device=device)
        affine = torch.zeros(1, AFFINE_DIM, dtype=dtype, device=device)
        if affine_init is not None:
            affine[0] = affine_init.to(dtype=dtype, device=device)
        state = SfMState(
            poses=torch.stack([eye, T_kf_init.to(dtype=dtype, device=device)]),  # keyframe at the origin
            codes=torch.zeros(2, 1, dtype=dtype, device=device),  # the code is baked into the fixed depth
            affine=affine,
        )
        # Only the frame's pose and the pair's brightness are free: keyframe pose and depth are fixed (Sec. 4.2).
        fixed = [BlockId(POSE, 0), BlockId(CODE, 0), BlockId(CODE, 1)]
        layout = VariableLayout.for_sfm(2, 1, 1, cfg.affine_brightness, fixed)
        terms = [] if reprojection is None or len(reprojection) == 0 else [reprojection]
        if T_kf_prior is not None and prior_dt is not None and cfg.motion_prior_acceleration > 0:
            terms.append(self._motion_prior(T_kf_prior, prior_dt, dtype, device))  # the motion model, soft
        levels = list(zip(cfg.pyramid_levels, cfg.max_iterations))
        started_by_features = (reprojection is not None and min_feature_inliers > 0 and not every_level
                               and len(reprojection) >= min_feature_inliers)
        if start_level is None and started_by_features and cfg.feature_start_level >= 0:
            start_level = cfg.feature_start_level  # within the fine levels' basin already
        if start_level is not None:
            levels = [(lvl, it) for lvl, it in levels if lvl <= start_level]
        align = self._align_dedicated if self.solver == "dedicated" else self._align_generic
        state, cost, valid_px, r, sigma, gray_A, iterations, kp = align(keyframe, code, image, camera, valid, state,
                                                                        layout, terms, levels)
        result = self._checked(state, valid_px, r, sigma, gray_A, cost, iterations, T_kf_prior)
        if reprojection is not None and len(reprojection) > 0:  # not the motion prior alone (a frame without matches)
            result.feature_matches = len(reprojection)
            if kp is None:
                inliers = reprojection.inliers(state, feature_threshold)
            else:  # the alignment's own reprojection residuals at the final pose
                inliers = KeypointTerm.inliers(*kp, feature_threshold)
            result.feature_inliers = int(inliers.sum())
            finite = "non-finite" not in result.reason
            if not result.ok and finite and min_feature_inliers > 0 and result.feature_inliers >= min_feature_inliers:
                result.ok, result.reason = True, ""  # the features vouch for the pose (see TrackResult)
        return result

    def _align_dedicated(self, keyframe: Keyframe, code: torch.Tensor, image: torch.Tensor, camera: PinholeCamera,
                         valid: torch.Tensor | None, state: SfMState, layout: VariableLayout, terms: list,
                         levels: list[tuple[int, int]]):
        """Coarse to fine over :class:`~codeslam.slam.alignment.TrackingProblem` with the keyframe's cached data,
        ``levels`` (level, iterations) in order.
        Returns (state, cost, valid (N,), r (N,), sigma, gray_A (N,), iterations) at the finest level and the matched
        keypoints' residuals (2, M) and points in the frame (3, M) at the final pose (None without keypoints)."""
        cfg, sfm_cfg = self.cfg, self.sfm_cfg
        reference = self.reference(keyframe, code)
        visited = [lvl for lvl, _ in levels]
        real = None if valid is None else self._kept_real_pixels(valid, visited, reference.dtype, reference.device)
        frame = FramePyramid(image, camera, valid, visited, reference.dtype, reference.device, real)  # only those
        if valid is not None and real is None:  # a mask not seen before: its levels came with the frame's
            self._real_pixels = (valid.clone(), (reference.dtype, reference.device), frame.real)
        current = TrackingState.from_sfm(state)
        keypoints, others = None, []
        for term in terms:  # the keypoints' residuals in the tracker's own layout, the motion prior as it is
            if type(term) is ReprojectionTerm and (term.a, term.b) == (0, 1):
                keypoints = KeypointTerm(term, reference.dtype, reference.device)
            else:
                others.append(term)
        current, reports, problem = coarse_to_fine(  # Sec. 4.2
            lambda lvl: TrackingProblem(reference.levels[lvl], frame.levels[lvl], sfm_cfg, keypoints, others),
            current, layout, sfm_cfg, levels)
        iterations = sum(r.iterations for _, r in reports)
        cost, ev = problem.evaluation(current)  # the finest level at the final state (the solver evaluated it)
        kp = None if ev.keypoints is None else ev.keypoints[1:3]
        return (current.to_sfm(), cost, ev.valid, ev.r, ev.sigma, reference.levels[cfg.pyramid_levels[-1]].gray,
                iterations, kp)

    def _kept_real_pixels(self, valid: torch.Tensor, levels: list[int], dtype: torch.dtype,
                            device: torch.device) -> dict[int, torch.Tensor] | None:
        """The real-pixel masks of a frame's validity mask at ``levels`` (those the alignment visits) if the last
        frame's mask was the same and its masks cover them (a reader that masks a fixed border gives every frame
        the same one), else None: then :class:`~codeslam.slam.alignment.FramePyramid` builds them with the
        frame's pyramid and they are kept from there (its ``real``). A rolling-shutter rectification gives every
        frame its own mask: then only the visited levels are kept (a frame started from the matches visits 1 and
        0, and the four levels took 1.1 of its 18.5 ms on TUM fr1/rpy). A level's mask does not depend on how many
        levels are built: each is made from the one below it."""
        c = self._real_pixels
        same = (c is not None and c[1] == (dtype, device) and c[0].shape == valid.shape
                and c[0].device == valid.device and set(levels) <= c[2].keys() and torch.equal(c[0], valid))
        return c[2] if same else None

    def _align_generic(self, keyframe: Keyframe, code: torch.Tensor, image: torch.Tensor, camera: PinholeCamera,
                       valid: torch.Tensor | None, state: SfMState, layout: VariableLayout, terms: list,
                       levels: list[tuple[int, int]]):
        """The same alignment as a two-frame :class:`~codeslam.sfm.solver.PairProblem` (A = keyframe with its
        depth decoded at ``code``, B = the frame), its levels rebuilt for every frame; same returns as
        :meth:`_align_dedicated`, without the keypoints' residuals (None)."""
        cfg, sfm_cfg = self.cfg, self.sfm_cfg
        dtype, device = state.poses.dtype, state.poses.device
        fixed_depth = Keyframe(keyframe.image, keyframe.camera, fixed_depth_decoder(keyframe.decoder, code),
                               keyframe.valid)
        frame = Keyframe(image.to(dtype=dtype, device=device), camera, None, valid)  # no depth: B of the pair only
        pyramid = build_levels([fixed_depth, frame], cfg.pyramid_levels, dtype, device)
        pairs = torch.tensor([[0, 1]], device=device)  # A = keyframe (decoded depth), B = frame
        state, reports, _ = coarse_to_fine(lambda lvl: PairProblem(pyramid[lvl], pairs, sfm_cfg, terms), state,
                                           layout, sfm_cfg, levels)  # Sec. 4.2
        iterations = sum(r.iterations for _, r in reports)
        finest = pyramid[cfg.pyramid_levels[-1]]
        cost, ev = PairProblem(finest, pairs, sfm_cfg, terms).evaluate(state)
        return (state, cost, ev.valid[0, 0], ev.r[0, 0], ev.sigma[0, 0], finest.gray[0, 0].reshape(-1), iterations,
                None)

    def _motion_prior(self, T_kf_prior: torch.Tensor, dt: float, dtype: torch.dtype,
                      device: torch.device) -> PosePrior:
        """``0.5 |log(T T_pred^-1)|^2_W`` on the frame's pose around the motion model's prediction, with the noise of
        a constant-velocity model whose acceleration is unknown: ``motion_prior_acceleration * dt^2`` in
        translation and, if set, ``motion_prior_angular_acceleration_deg * dt^2`` in rotation. It resolves what the
        images leave ambiguous (a small rotation and a small translation move a distant scene alike), which on a
        rotating camera turned into translation jitter of several millimetres per frame."""
        cfg = self.cfg
        inv = [1.0 / (cfg.motion_prior_acceleration * dt**2) ** 2] * 3
        rot = cfg.motion_prior_angular_acceleration_deg * dt**2
        inv += [0.0 if rot <= 0 else 1.0 / math.radians(rot) ** 2] * 3
        return PosePrior(1, torch.diag(torch.tensor(inv, dtype=dtype, device=device)),
                         T_kf_prior.to(dtype=dtype, device=device))

    def _checked(self, state: SfMState, valid: torch.Tensor, r: torch.Tensor, sigma: torch.Tensor,
                 gray_A: torch.Tensor, cost: float, iterations: int,
                 T_pred: torch.Tensor | None = None) -> TrackResult:
        """The track result with the photometric failure checks applied (non-finite, overlap, inlier ratio,
        explained variance, brightness gain, rotation from the motion model's prediction ``T_pred`` when given).
        At the finest tracked level: ``valid`` (N,) the photometric residuals' mask, ``r`` (N,) the residuals,
        ``sigma`` their noise, ``gray_A`` (N,) the keyframe's intensities. Matched keypoints may still vouch for
        a pose that fails them (:meth:`track`)."""
        cfg = self.cfg
        n_valid = int(valid.sum())
        overlap = n_valid / valid.numel()
        inliers = valid & (r.abs() <= cfg.inlier_sigmas * sigma)
        inlier_ratio = int(inliers.sum()) / max(n_valid, 1)
        explained = 0.0
        var_A = 0.0
        rms = float("nan")
        if n_valid > 1:
            var_A = float(gray_A[valid].var())
            rms = float(r[valid].square().mean().sqrt())
            explained = 1.0 - rms**2 / max(var_A, torch.finfo(r.dtype).tiny)
        T_kf = project_to_se3(state.poses[1])
        affine = state.affine[0].to(device="cpu", dtype=torch.float64)
        reason = ""
        if not (math.isfinite(cost) and bool(torch.isfinite(T_kf).all()) and bool(torch.isfinite(affine).all())):
            reason = "non-finite cost or pose"
        elif overlap < cfg.min_overlap:
            reason = f"overlap {overlap:.2f} below {cfg.min_overlap:.2f}"
        elif inlier_ratio < cfg.min_inlier_ratio:
            reason = f"inlier ratio {inlier_ratio:.2f} below {cfg.min_inlier_ratio:.2f}"
        elif var_A < cfg.min_intensity_std**2:
            reason = f"no texture to track (intensity std {math.sqrt(var_A):.4f} below {cfg.min_intensity_std:g})"
        elif explained < cfg.min_explained_variance:
            reason = f"explained intensity variance {explained:.2f} below {cfg.min_explained_variance:.2f}"
        elif abs(float(affine[0])) > cfg.max_log_gain:
            reason = f"brightness gain {math.exp(float(affine[0])):.2f} outside exp(+-{cfg.max_log_gain:g})"
        elif (T_pred is not None and cfg.max_rotation_from_prediction_deg > 0
              and (turn := pose_distance(T_pred.to(T_kf), T_kf)[1]) > cfg.max_rotation_from_prediction_deg):
            reason = (f"rotation {turn:.1f} deg from the motion model's prediction (more than "
                      f"{cfg.max_rotation_from_prediction_deg:g})")
        return TrackResult(T_kf=T_kf, affine=affine, ok=not reason, reason=reason, overlap=overlap,
                           inlier_ratio=inlier_ratio, explained=explained, cost=cost, iterations=iterations,
                           photometric_reason=reason, residual=rms, texture=math.sqrt(var_A))
