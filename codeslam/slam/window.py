"""The sliding window of keyframes (paper Sec. 4.3): the codes and poses of the last K keyframes are optimised
jointly on the photometric and geometric residuals of every overlapping keyframe pair (the N-frame SfM of
Sec. 4.1), and a keyframe leaving the window is marginalised into a linear prior on the ones that stay.

Marginalisation. Let ``x_m`` be the leaving keyframe's variables (its code, its pose unless it is the fixed
gauge, and the affine brightness of its pairs) and ``x_r`` the remaining keyframes' poses and codes. Only the
cost terms that involve ``x_m`` are marginalised: the residuals of the pairs that contain the leaving keyframe,
its code prior and the previous linear prior. Their Gauss-Newton normal equations at the current linearisation
point ``x0``, ``[[H_mm, H_mr], [H_rm, H_rr]]`` and ``[g_m; g_r]``, are reduced by the Schur complement::

    H' = H_rr - H_rm H_mm^-1 H_mr,        b' = g_r - H_rm H_mm^-1 g_m

which gives the prior ``0.5 d^T H' d + b'^T d`` with ``d = x_r ominus x0_r`` (a
:class:`~codeslam.sfm.variables.LinearPrior`, entering later windows through the solver's ``priors``). For a
linear-Gaussian problem this is the exact marginal: minimising the prior plus the terms that do not involve
``x_m`` gives the same ``x_r`` as the full problem. Pairs among the remaining keyframes stay in the window as
residuals and are not part of the prior (they would be counted twice otherwise).

Gauge. While no prior exists, the oldest keyframe's pose is fixed (the first keyframe of the map is the world
origin). Its marginal prior then anchors the remaining poses, so later windows fix no pose. Monocular scale is
held by the code prior, as in two-frame SfM.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.constants import MAX_PROXIMITY, MIN_PROXIMITY
from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.lie import se3_inverse, so3_angle_host
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import Keyframe, LevelData, build_levels
from codeslam.sfm.normal_equations import assemble
from codeslam.sfm.pairs import view_overlap
from codeslam.sfm.priors import AffinePrior, CodePrior
from codeslam.sfm.residuals import evaluate_pairs, pair_jacobians
from codeslam.sfm.scale_prior import DepthScalePrior, WindowScalePrior
from codeslam.sfm.solver import LMReport, PairProblem, coarse_to_fine
from codeslam.sfm.variables import (
    AFFINE,
    AFFINE_DIM,
    CODE,
    POSE,
    POSE_DIM,
    BlockId,
    LinearPrior,
    SfMState,
    VariableLayout,
)
from codeslam.slam.config import WindowConfig
from codeslam.slam.frontend import KeyframeFeatures
from codeslam.slam.poses import project_to_se3
from codeslam.slam.reprojection import DecodedReprojectionTerm, StackedReprojectionTerm, keyframe_pair_term
from codeslam.slam.velocity_prior import VelocityPrior


@dataclass
class MapKeyframe:
    """A keyframe of the map.

    Attributes:
        id: running keyframe number (0 = the map's origin).
        frame_index, timestamp: the frame it was made from.
        view: what the SfM problems see of it: image (RGB or grey), camera, validity and linear depth decoder
            (the decoder is dropped once the keyframe is marginalised; its final depth is kept in ``depth``).
        T_wc: (4, 4) float64 CPU pose, updated by every window optimisation until marginalised.
        code: (C,) depth code (solver dtype and device), likewise; (k,) in ``code_basis``'s coordinates when that
            is set.
        depth: (H, W) final depth once marginalised, else None (use :meth:`depth_map`).
        sparse: its ORB keypoints and their 3D points at the current code (None without features).
        depth_zero, uncertainty: (H, W) the network's zero-code depth and Laplace scale b (proximity units) at
            the finest level, kept for reports; depth_gt: (H, W) the dataset's depth when it has one.
        segment: the map segment the keyframe belongs to (a new one starts after tracking was lost).
        code_basis: (C, k) when the code is optimised in a subspace of the network's code
            (``window.code_directions``): the network's code is ``code_basis @ code``; None otherwise.
        free_scale: the code's last entry is a log scale of the depth (``window.free_scale``), not the network's.
        input_camera, rectified_by, readout_axis: the camera of the input frame it was made from, the rotation over
            the readout its image was rectified by (None: not) and the image axis its sensor's rows ran along, to
            bring the input's depth into its view later (:meth:`~codeslam.slam.system.CodeSLAM.keyframe_depth`).
    """

    id: int
    frame_index: int
    timestamp: float
    view: Keyframe
    T_wc: torch.Tensor
    code: torch.Tensor
    depth: torch.Tensor | None = None
    sparse: KeyframeFeatures | None = None
    depth_zero: torch.Tensor | None = None
    uncertainty: torch.Tensor | None = None
    depth_gt: torch.Tensor | None = None
    segment: int = 0
    code_basis: torch.Tensor | None = None
    free_scale: bool = False
    input_camera: PinholeCamera | None = None
    rectified_by: torch.Tensor | None = None
    readout_axis: str = "rows"
    _median: tuple | None = field(default=None, init=False, repr=False, compare=False)  # see median_depth

    @property
    def network_code(self) -> torch.Tensor:
        """(C,) the keyframe's code in the network's coordinates."""
        code = self.code[:-1] if self.free_scale else self.code  # the last entry is a log scale (free_scale)
        return code if self.code_basis is None else self.code_basis @ code.to(self.code_basis.dtype)

    @property
    def active(self) -> bool:
        return self.view.decoder is not None

    def depth_map(self, level: int = 0) -> torch.Tensor:
        """(H_l, W_l) depth in metres at the current code."""
        if self.view.decoder is None:
            if level != 0:
                raise ValueError("a marginalised keyframe keeps its finest depth only")
            return self.depth
        return self.view.decoder.depth(self.code, level)

    def runaway_share(self, code: torch.Tensor | None = None) -> float:
        """Share of the finest level's pixels whose proximity at ``code`` (default: the keyframe's) lies at or
        beyond the ends of (0, 1), where the depth is clamped to infinity or to zero (0 once marginalised)."""
        if self.view.decoder is None:
            return 0.0
        p = self.view.decoder.prox(self.code if code is None else code, 0)
        return float(((p <= MIN_PROXIMITY) | (p >= MAX_PROXIMITY) | ~torch.isfinite(p)).float().mean())

    def median_depth(self) -> float:
        """Median of the decoded depth (metres): the scene scale that keyframe selection compares against.

        Kept with the code, decoder and depth objects it was computed from and computed again when any of them is
        another: the mapping thread replaces those attributes and never edits them (:mod:`codeslam.slam.mapping`),
        and the tracker asks for the same keyframe's median several times a frame (TUM fr1/rpy in parallel mode:
        496 decodings of 1 ms each on the tracking thread of a 14.5 s run)."""
        key = (self.code, self.view.decoder, self.depth)
        memo = self._median  # one read: the other thread may replace it meanwhile
        if memo is None or any(a is not b for a, b in zip(memo[0], key)):
            d = self.depth_map()
            memo = (key, float(d[d > 0].median()))
            self._median = memo
        return memo[1]

    def freeze(self) -> None:
        """Keep the final depth, drop the decoder (its Jacobian is the bulk of a keyframe's memory)."""
        self.depth = self.depth_map().detach()
        self.view = Keyframe(self.view.image, self.view.camera, None, self.view.valid)
        self._median = None  # it holds the decoder too


@dataclass
class WindowReport:
    """What one window optimisation did. pairs: (A, B) keyframe ids with residuals; levels: (level, LM report)
    coarse to fine; rejected: why the solve was rolled back ('' when kept); interrupted: the solve
    stopped early because the tracker needed the mapping thread (its values are the last accepted step's);
    depth_scale: keyframe id -> median depth after / before the solve, set for a map segment's first solve (see
    ``CodeSLAM._rescale``)."""

    pairs: list[tuple[int, int]] = field(default_factory=list)
    levels: list[tuple[int, LMReport]] = field(default_factory=list)
    rejected: str = ""
    interrupted: bool = False
    depth_scale: dict[int, float] = field(default_factory=dict)

    @property
    def iterations(self) -> int:
        return sum(r.iterations for _, r in self.levels)


@dataclass
class WindowSolution:
    """What one window solve reached (:meth:`SlidingWindow.solve`): the keyframe ids in window order, their poses
    (4, 4) and codes, each solved pair's affine brightness (id pair -> (2,)) and the report."""

    ids: list[int]
    poses: list[torch.Tensor]
    codes: list[torch.Tensor]
    affine: dict[tuple[int, int], torch.Tensor]
    report: WindowReport


def schur_complement(
    H: torch.Tensor, g: torch.Tensor, marg: torch.Tensor, keep: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Marginalise the variables ``marg`` out of the quadratic ``0.5 d^T H d + g^T d``.

    H (D, D) symmetric, g (D,), marg / keep: long index tensors partitioning (a subset of) range(D)
    -> H' (k, k) = ``H_rr - H_rm H_mm^-1 H_mr``, b' (k,) = ``g_r - H_rm H_mm^-1 g_m`` over ``keep``, in float64.
    ``H_mm`` is inverted by Cholesky; if it is singular (a direction no term constrains) the pseudo-inverse
    is used, which marginalises only the constrained directions.
    """
    H64, g64 = H.to(torch.float64), g.to(torch.float64)
    H_mm = H64[marg[:, None], marg[None, :]]
    H_mr = H64[marg[:, None], keep[None, :]]
    H_rr = H64[keep[:, None], keep[None, :]]
    g_m, g_r = g64[marg], g64[keep]
    L, info = torch.linalg.cholesky_ex(H_mm)
    if int(info) == 0:
        X = torch.cholesky_solve(torch.cat([H_mr, g_m[:, None]], dim=1), L)  # H_mm^-1 [H_mr, g_m]
    else:
        X = torch.linalg.pinv(H_mm, hermitian=True) @ torch.cat([H_mr, g_m[:, None]], dim=1)
    H_new = H_rr - H_mr.T @ X[:, :-1]
    g_new = g_r - H_mr.T @ X[:, -1]
    return 0.5 * (H_new + H_new.T), g_new


@dataclass(frozen=True)
class SparseSettings:
    """What the window needs to weigh matched keypoints: the feature camera, the pixel noise of a keypoint at
    ORB's finest level and the pyramid's scale factor (noise grows by it per octave)."""

    camera: PinholeCamera
    sigma: float
    octave_scale: float


@dataclass
class WindowSnapshot:
    """Values of the window's variables at one moment: keyframe id -> (T_wc, code), pair -> affine, the pairs."""

    values: dict[int, tuple[torch.Tensor, torch.Tensor]]
    affine: dict[tuple[int, int], torch.Tensor]
    pairs: list[tuple[int, int]]


def bounded_quadratic(H: torch.Tensor, b: torch.Tensor, rtol: float = 1e-9) -> tuple[torch.Tensor, torch.Tensor]:
    """The quadratic ``0.5 d^T H d + b^T d`` made bounded below: eigenvalues of the symmetric PSD ``H`` under
    ``rtol`` times the largest become 0 and ``b`` loses its components along them. A marginal prior's ``b`` can
    point along directions ``H`` does not constrain (the gauge, numerically), and along those the prior's cost
    falls without end: measured on the HoloLens walk, window solves then ran the keyframes off by kilometres with
    ever more negative costs."""
    # Jacobi scaling first: code and pose blocks differ by orders of magnitude in information, and a threshold
    # relative to the largest eigenvalue of H itself dropped the (real) translation information of the poses.
    d = H.diagonal().clamp_min(0.0)
    s = torch.where(d > 0, d.rsqrt(), torch.zeros_like(d))
    Hs = s[:, None] * H * s[None, :]
    lam, U = torch.linalg.eigh(0.5 * (Hs + Hs.T))
    keep = lam > rtol * lam.abs().max().clamp_min(torch.finfo(H.dtype).tiny)
    lam = torch.where(keep, lam, torch.zeros_like(lam))
    Uk = U[:, keep]
    inv_s = torch.where(s > 0, 1.0 / s, torch.zeros_like(s))
    H_new = inv_s[:, None] * ((U * lam) @ U.T) * inv_s[None, :]
    b_new = inv_s * (Uk @ (Uk.T @ (s * b)))
    return 0.5 * (H_new + H_new.T), b_new


class SlidingWindow:
    """The active keyframes (oldest first), their linear prior and the pairwise affine brightness estimates.

    The prior's blocks are stored by keyframe id (``BlockId(kind, keyframe id)``) and mapped to window
    positions for each solve.
    """

    def __init__(self, cfg: WindowConfig) -> None:
        self.cfg = cfg
        self.keyframes: list[MapKeyframe] = []
        self.prior: LinearPrior | None = None
        self.prior_level: int = min(cfg.sfm.pyramid_levels)  # the level the prior's Hessian was built at
        self._affine: dict[tuple[int, int], torch.Tensor] = {}  # (id A, id B) -> (2,) last estimate
        self._pairs: list[tuple[int, int]] = []  # id pairs of the last optimisation (its linearisation point)
        # Matched keypoints between keyframes: (id A, id B) -> keypoint indices into A's and B's features.
        self.matches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.sparse: SparseSettings | None = None  # set by the system when it uses features
        # whether the last solve left the window unsettled (WindowConfig.coarsest_level): the next one visits the
        # coarsest level
        self.unsettled = True

    def __len__(self) -> int:
        return len(self.keyframes)

    @property
    def is_full(self) -> bool:
        return len(self.keyframes) >= self.cfg.size

    def add(self, kf: MapKeyframe) -> None:
        self.keyframes.append(kf)

    # ---- problem set-up -------------------------------------------------------------------------------------
    def _tensors(self) -> tuple[torch.dtype, torch.device]:
        ref = self.keyframes[-1].view.decoder.levels[0].jac
        return ref.dtype, ref.device

    def _state(self, id_pairs: list[tuple[int, int]]) -> SfMState:
        dtype, device = self._tensors()
        zero = torch.zeros(AFFINE_DIM, dtype=dtype, device=device)
        affine = [self._affine.get(p, zero).to(dtype=dtype, device=device) for p in id_pairs]
        return SfMState(
            poses=torch.stack([k.T_wc for k in self.keyframes]).to(dtype=dtype, device=device),
            codes=torch.stack([k.code for k in self.keyframes]).to(dtype=dtype, device=device),
            affine=torch.stack(affine) if affine else torch.zeros(0, AFFINE_DIM, dtype=dtype, device=device),
        )

    def select_pairs(self) -> list[tuple[int, int]]:
        """(A, B) keyframe ids whose views overlap by at least ``min_pair_overlap`` (at the window's median
        depth), plus every consecutive pair, in both directions."""
        kfs = self.keyframes
        poses = torch.stack([k.T_wc for k in kfs])  # (F, 4, 4) float64
        depth = float(torch.tensor([k.median_depth() for k in kfs]).median())
        ov = view_overlap(poses, kfs[0].view.camera, depth)  # (F, F)
        out = []
        for a in range(len(kfs)):
            for b in range(len(kfs)):
                if a != b and (abs(a - b) == 1 or float(ov[a, b]) >= self.cfg.min_pair_overlap):
                    out.append((kfs[a].id, kfs[b].id))
        return out

    def _positions(self) -> dict[int, int]:
        return {k.id: i for i, k in enumerate(self.keyframes)}

    def _positioned_prior(self, scale: float = 1.0, dtype: torch.dtype | None = None) -> LinearPrior | None:
        """The prior with its blocks at window positions, its information scaled by ``scale`` and H, b in
        ``dtype`` (default: the solver's; :meth:`LinearPrior.add_to` needs the dtype of the normal equations)."""
        if self.prior is None:
            return None
        pos = self._positions()
        solver_dtype, device = self._tensors()
        dtype = dtype or solver_dtype
        return LinearPrior(
            blocks=[BlockId(b.kind, pos[b.index]) for b in self.prior.blocks],
            H=(scale * self.prior.H).to(dtype=dtype, device=device),
            b=(scale * self.prior.b).to(dtype=dtype, device=device),
            x0=[x.to(dtype=solver_dtype, device=device) for x in self.prior.x0],
        )

    def _pair_terms(self, ids: set[int] | None = None) -> list[DecodedReprojectionTerm]:
        """Reprojection residuals of the matched keypoints of every keyframe pair in the window (only pairs that
        involve ``ids`` when given), frames at window positions."""
        if self.sparse is None or self.cfg.reprojection_weight <= 0:
            return []
        pos = self._positions()
        sp = self.sparse
        terms = []
        for (ia, ib), (kp_a, kp_b) in self.matches.items():
            if ia not in pos or ib not in pos or (ids is not None and not ({ia, ib} & ids)) or len(kp_a) == 0:
                continue
            A, B = self.keyframes[pos[ia]], self.keyframes[pos[ib]]
            fa, fb = A.sparse.features, B.sparse.features
            sigma = sp.sigma * sp.octave_scale ** fb.octave[kp_b].astype(np.float64)
            terms.append(keyframe_pair_term(
                pos[ia], pos[ib], torch.from_numpy(fa.uv[kp_a]), torch.from_numpy(fb.uv[kp_b]),
                torch.from_numpy(sigma), A.view.decoder.levels[0], A.view.decoder.avg_depth, sp.camera,
                A.view.camera, self.cfg.reprojection_weight))
        return terms

    def _fixed(self) -> list[BlockId]:
        """The gauge: the oldest pose while no prior anchors the window."""
        return [BlockId(POSE, 0)] if self.prior is None else []

    # ---- optimisation ---------------------------------------------------------------------------------------
    def problem(self) -> tuple[list[tuple[int, int]], torch.Tensor, SfMState, VariableLayout]:
        """What a solve optimises: the keyframe id pairs with residuals, the same pairs at window positions (P, 2),
        the state (poses, codes, affine of each pair) and the layout of its free blocks."""
        _, device = self._tensors()
        id_pairs = self.select_pairs()
        pos = self._positions()
        pairs = torch.tensor([[pos[a], pos[b]] for a, b in id_pairs], device=device)
        state = self._state(id_pairs)
        F_, C = state.codes.shape
        return id_pairs, pairs, state, VariableLayout.for_sfm(F_, C, len(id_pairs), self.cfg.sfm.affine_brightness,
                                                             self._fixed())

    def sparse_terms(self) -> list:
        """The solve's terms that do not depend on the pyramid level, built once per solve: the matched keypoints
        between keyframes and the consecutive keyframes' velocity prior."""
        terms = [StackedReprojectionTerm(self._pair_terms(), self.cfg.free_scale)]
        if self.cfg.motion_prior_acceleration > 0:
            terms.append(VelocityPrior.consecutive([k.timestamp for k in self.keyframes],
                                                   self.cfg.motion_prior_acceleration))
        return terms

    def level_terms(self, level: LevelData, sparse_terms: list, prior_scale: float = 1.0) -> list:
        """Every term of a solve at ``level`` beside the pair residuals and the code and affine priors (those are
        :class:`~codeslam.sfm.solver.PairProblem`'s own): the marginal prior (its information times
        ``prior_scale``), ``sparse_terms`` (:meth:`sparse_terms`) and the scale priors."""
        prior = self._positioned_prior(prior_scale)
        terms = ([] if prior is None else [prior]) + sparse_terms
        frames = list(range(len(self.keyframes)))
        if self.cfg.depth_scale_sigma > 0:  # each keyframe's scale near the network's prediction
            terms.append(DepthScalePrior(level, frames, self.cfg.depth_scale_sigma))
        if self.cfg.window_scale_sigma > 0:  # the window's scale as a whole near the network's
            terms.append(WindowScalePrior(level, frames, self.cfg.window_scale_sigma))
        return terms

    def optimise(self, interrupted: Callable[[], bool] | None = None) -> WindowReport:
        """Jointly optimise the codes and poses of the window's keyframes (paper Sec. 4.1/4.3), coarse to fine,
        from their current values; writes the results back into the keyframes. ``interrupted()`` is asked before
        every iteration: when it turns true the solve ends there, keeping what it has reached (as ORB-SLAM's
        local mapping stops its bundle adjustment when a new keyframe arrives)."""
        return self.apply(self.solve(interrupted))

    def levels_to_visit(self) -> list[tuple[int, int]]:
        """The (pyramid level, iterations) of the next solve, coarse to fine: every level of ``cfg.sfm``, or
        without the coarsest when ``coarsest_level`` is 'unsettled' and the window is full and settled (its last
        solve converged on every level and was kept)."""
        cfg: SfMConfig = self.cfg.sfm
        visit = list(zip(cfg.pyramid_levels, cfg.max_iterations))
        if self.cfg.coarsest_level == "unsettled" and len(visit) > 1 and self.is_full and not self.unsettled:
            return visit[1:]
        return visit

    def solve(self, interrupted: Callable[[], bool] | None = None) -> WindowSolution:
        """What :meth:`optimise` reaches, without writing it into the keyframes (:meth:`apply` does): the solve
        reads the window and changes nothing, so it can run on a copy elsewhere
        (:mod:`codeslam.slam.solve_process`)."""
        report = WindowReport()
        ids = [k.id for k in self.keyframes]
        if len(self.keyframes) < 2:
            return WindowSolution(ids, [], [], {}, report)
        cfg: SfMConfig = self.cfg.sfm
        dtype, device = self._tensors()
        id_pairs, pairs, state, layout = self.problem()
        visit = self.levels_to_visit()
        levels = build_levels([k.view for k in self.keyframes], [lvl for lvl, _ in visit], dtype, device)
        n_prior = levels[min(cfg.pyramid_levels)].uv.shape[0]
        sparse_terms = self.sparse_terms()

        def problem_at(lvl: int) -> PairProblem:
            # Coarser levels sum over fewer pixels: scale the prior alike so it keeps its weight against the data.
            scale = levels[lvl].uv.shape[0] / n_prior if self.cfg.scale_prior_with_level else 1.0
            return PairProblem(levels[lvl], pairs, cfg, self.level_terms(levels[lvl], sparse_terms, scale))

        # the tracker's stop reaches the finest level only (WindowConfig.interrupt_finest_only; the coarser ones
        # make at most coarse_iterations_after_stop more iterations after it, when that is set)
        cuttable = {min(cfg.pyramid_levels)} if self.cfg.interrupt_finest_only else None
        state, report.levels, _ = coarse_to_fine(problem_at, state, layout, cfg, visit,
                                                 interrupted=interrupted, interruptible_levels=cuttable,
                                                 after_stop=None if self.cfg.coarse_iterations_after_stop < 0
                                                 else self.cfg.coarse_iterations_after_stop)
        report.interrupted = bool(report.levels) and report.levels[-1][1].reason == "interrupted"
        report.pairs = id_pairs
        return WindowSolution(ids, [project_to_se3(state.poses[i]) for i in range(len(ids))],
                              [state.codes[i].detach().clone() for i in range(len(ids))],
                              {p: state.affine[i].detach().clone() for i, p in enumerate(id_pairs)}, report)

    def apply(self, solution: WindowSolution) -> WindowReport:
        """Write a :meth:`solve`'s poses, codes and affine estimates into the window (whose keyframes must be the
        ones it was solved for); returns its report."""
        if solution.ids != [k.id for k in self.keyframes]:
            raise ValueError(f"a solve of keyframes {solution.ids} applied to a window of "
                             f"{[k.id for k in self.keyframes]}")
        if not solution.poses:  # fewer than two keyframes: nothing was solved
            return solution.report
        # unsettled: a level stopped at its iteration cap, not at a tolerance (an interrupted level is not)
        self.unsettled = any(r.reason == "max iterations" for _, r in solution.report.levels)
        for kf, T_wc, code in zip(self.keyframes, solution.poses, solution.codes):
            kf.T_wc, kf.code = T_wc, code
        self._affine.update(solution.affine)
        self._pairs = solution.report.pairs
        return solution.report

    # ---- keeping the map -------------------------------------------------------------------------------------
    def snapshot(self) -> WindowSnapshot:
        """The window's poses, codes and affine estimates, to roll a solve back."""
        return WindowSnapshot({k.id: (k.T_wc.clone(), k.code.clone()) for k in self.keyframes},
                              {p: a.clone() for p, a in self._affine.items()}, list(self._pairs))

    def restore(self, snap: WindowSnapshot) -> None:
        """Put back the values of ``snap`` for the keyframes still in the window (a solve rolled back: the next one
        visits the coarsest level)."""
        self.unsettled = True
        for k in self.keyframes:
            if k.id in snap.values:
                k.T_wc, k.code = (v.clone() for v in snap.values[k.id])
        self._affine = {p: a.clone() for p, a in snap.affine.items()}
        self._pairs = [p for p in snap.pairs if all(i in self._positions() for i in p)]

    def check(self, before: WindowSnapshot, depth_before: dict[int, float]) -> str:
        """Why the solve that led from ``before`` to the current values must not be kept ('' if it may): a
        non-finite value, a relative pose between consecutive keyframes that turned or moved more than the
        tracking could have been wrong by, a keyframe whose median depth changed by more than
        ``max_depth_change`` (log), or one with more than ``max_runaway_share`` more of its pixels decoded to
        proximity at or past 0 or 1 (depth clamped to infinity or zero). Measured on the HoloLens walk before
        this check: solves that moved a keyframe by tens of degrees threw the map away and every later frame
        failed."""
        cfg = self.cfg
        for k in self.keyframes:
            if not (bool(torch.isfinite(k.T_wc).all()) and bool(torch.isfinite(k.code).all())):
                return f"keyframe {k.id}: non-finite pose or code"
        for a, b in zip(self.keyframes[:-1], self.keyframes[1:]):
            if a.id not in before.values or b.id not in before.values:
                continue
            rel0 = se3_inverse(before.values[a.id][0]) @ before.values[b.id][0]
            rel1 = se3_inverse(a.T_wc) @ b.T_wc
            D = se3_inverse(rel0) @ rel1
            rot = math.degrees(so3_angle_host(D[:3, :3]))
            shift = float(D[:3, 3].norm())
            scale = max(float(rel0[:3, 3].norm()), 1e-9)
            if rot > cfg.max_rotation_change_deg:
                return f"keyframes {a.id}-{b.id}: relative rotation changed by {rot:.1f} deg"
            if shift > cfg.max_translation_change * max(scale, cfg.min_translation_scale * depth_before[a.id]):
                return f"keyframes {a.id}-{b.id}: relative translation changed by {shift:.3f} (baseline {scale:.3f})"
        for k in self.keyframes:
            if k.id in depth_before:
                change = abs(math.log(k.median_depth() / depth_before[k.id]))
                if change > cfg.max_depth_change:
                    return f"keyframe {k.id}: median depth changed by a factor {math.exp(change):.2f}"
            if k.id in before.values and cfg.max_runaway_share < 1.0:
                share = k.runaway_share() - k.runaway_share(before.values[k.id][1])
                if share > cfg.max_runaway_share:
                    return f"keyframe {k.id}: {100 * share:.1f}% of its depth ran off to infinity or zero"
        return ""

    def move(self, G: torch.Tensor) -> None:
        """Move the window rigidly by ``G`` (4, 4; ``T_wc <- G T_wc``): its keyframes and its linear prior
        (:meth:`~codeslam.sfm.variables.LinearPrior.moved`). The pairs' photometric and reprojection terms and the
        velocity and scale priors see relative poses and depths only, and do not change."""
        G = G.to(torch.float64)
        for k in self.keyframes:
            k.T_wc = G @ k.T_wc
        if self.prior is not None:
            self.prior = self.prior.moved(G)

    def reset(self) -> list[MapKeyframe]:
        """Freeze every keyframe and empty the window (a new map segment, or a relocalised restart); returns
        the keyframes that left."""
        left = list(self.keyframes)
        for k in left:
            k.freeze()
        self.keyframes, self.prior, self._affine, self._pairs, self.matches = [], None, {}, [], {}
        self.unsettled = True
        return left

    # ---- marginalisation ------------------------------------------------------------------------------------
    def marginal_prior(self) -> LinearPrior | None:
        """The linear prior on the remaining keyframes left by marginalising the oldest one at the current
        state (module docstring). Blocks by keyframe id; the linearisation point ``x0`` is the current state.
        None when the leaving keyframe constrained none of the others."""
        cfg: SfMConfig = self.cfg.sfm
        dtype, device = self._tensors()
        kfs = self.keyframes
        F_, C = len(kfs), kfs[0].code.shape[0]
        old_id = kfs[0].id
        pos = self._positions()
        id_pairs = [p for p in self._pairs if old_id in p and p[0] in pos and p[1] in pos]
        state = self._state(id_pairs)
        marg = ([] if self.prior is None else [(BlockId(POSE, 0), POSE_DIM)]) + [(BlockId(CODE, 0), C)]
        if cfg.affine_brightness:
            marg += [(BlockId(AFFINE, p), AFFINE_DIM) for p in range(len(id_pairs))]
        keep = [(BlockId(POSE, i), POSE_DIM) for i in range(1, F_)] + [(BlockId(CODE, i), C) for i in range(1, F_)]
        layout = VariableLayout(marg + keep)
        H = torch.zeros(layout.dim, layout.dim, dtype=torch.float64, device=device)
        g = torch.zeros(layout.dim, dtype=torch.float64, device=device)
        if id_pairs:  # residuals of the pairs that involve the leaving keyframe
            lvl = self.prior_level
            level = build_levels([k.view for k in kfs], [lvl], dtype, device)[lvl]
            pairs = torch.tensor([[pos[a], pos[b]] for a, b in id_pairs], device=device)
            ev = evaluate_pairs(level, pairs, state.poses, state.codes, state.affine if cfg.affine_brightness
                                else None, cfg)
            level.refresh_scale_column(state.codes)
            terms = pair_jacobians(level, pairs, ev, with_code_b=True)
            H_d, g_d = assemble(terms, pairs, state.poses, level, layout)
            H += H_d.to(torch.float64)
            g += g_d.to(torch.float64)
        # matched keypoints of the pairs that involve it
        StackedReprojectionTerm(self._pair_terms({old_id}), self.cfg.free_scale).add_to(H, g, layout, state)
        if self.cfg.motion_prior_acceleration > 0:  # the velocity prior of the triple that starts with it
            VelocityPrior.consecutive([k.timestamp for k in kfs[:3]],
                                      self.cfg.motion_prior_acceleration).add_to(H, g, layout, state)
        if self.cfg.depth_scale_sigma > 0:  # the leaving keyframe's scale prior
            lvl = self.prior_level
            level = build_levels([k.view for k in kfs[:1]], [lvl], dtype, device)[lvl]
            DepthScalePrior(level, [0], self.cfg.depth_scale_sigma).add_to(H, g, layout, state)
        CodePrior(cfg.code_prior_weight, [0]).add_to(H, g, layout, state)  # the leaving keyframe's (VAE prior)
        if cfg.affine_brightness:  # the leaving pairs' affine prior
            AffinePrior(cfg.affine_prior_sigma).add_to(H, g, layout, state)
        old_prior = self._positioned_prior(dtype=torch.float64)
        if old_prior is not None:  # the previous prior involves the leaving keyframe: it is marginalised too
            old_prior.add_to(H, g, layout, state)
        n_marg = sum(s for _, s in marg)
        idx = torch.arange(layout.dim, device=device)
        H_r, b_r = schur_complement(H, g, idx[:n_marg], idx[n_marg:])
        H_r, b_r = bounded_quadratic(H_r, b_r)
        # Keep only the blocks the prior actually constrains.
        kept, sel, o = [], [], 0
        for b, s in keep:
            block = H_r[o:o + s]
            if bool((block.abs() > 1e-12 * H_r.abs().max()).any()):
                kept.append(b)
                sel.extend(range(o, o + s))
            o += s
        if not kept:  # nothing of the remaining keyframes was constrained by the leaving one
            return None
        sel_t = torch.tensor(sel, dtype=torch.long, device=device)
        ids = [kfs[b.index].id for b in kept]
        x0 = [state.block(b).detach().clone() for b in kept]
        return LinearPrior(
            blocks=[BlockId(b.kind, i) for b, i in zip(kept, ids)],
            H=H_r[sel_t[:, None], sel_t[None, :]],
            b=b_r[sel_t],
            x0=x0,
        )

    def remove_oldest(self, marginal: Callable[[SlidingWindow], LinearPrior | None] | None = None) -> MapKeyframe:
        """Take the oldest keyframe out of the window: marginalise it into the prior (``cfg.marginalise``) or
        drop its terms, and freeze it (final depth kept, decoder released). ``marginal``: what computes the
        prior from the window (default :meth:`marginal_prior`, here; :mod:`codeslam.slam.solve_process` computes
        it on a copy)."""
        if self.cfg.marginalise and len(self.keyframes) > 1:
            self.prior = self.marginal_prior() if marginal is None else marginal(self)
        else:
            self.prior = None
        old = self.keyframes.pop(0)
        self._affine = {p: a for p, a in self._affine.items() if old.id not in p}
        self.matches = {p: m for p, m in self.matches.items() if old.id not in p}
        self._pairs = [p for p in self._pairs if old.id not in p]
        old.freeze()
        return old

