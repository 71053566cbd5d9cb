"""Damped Gauss-Newton (Levenberg-Marquardt) over codes, poses and affine brightness (paper Sec. 4.1), and the
N-frame structure-from-motion entry point :func:`sfm`.

The solver drives any *problem* with two methods (duck-typed, see :class:`PairProblem`):

* ``evaluate(state) -> (cost: float, cache)``: the total cost at ``state``;
* ``linearize(state, cache, layout, clock) -> (H, g)``: normal equations over ``layout``'s free blocks at the
  state ``cache`` was evaluated at, with ``g`` the gradient of the cost and ``H`` its Gauss-Newton Hessian: tensors,
  or float64 NumPy arrays for a problem of a few variables that keeps its state on the host (the tracker's 8,
  where each tensor operation on an 8x8 matrix costs more than the arithmetic), solved there too;

so the SLAM back-end (pairs of the window + a :class:`~codeslam.sfm.variables.LinearPrior` from
marginalisation) and the tracker (photometric pairs, only the current pose free) reuse it unchanged.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Container, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from codeslam.clock import NO_CLOCK, Clock
from codeslam.constants import MIN_LM_DAMPING
from codeslam.errors import CodeSLAMError
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import Keyframe, LevelData, build_levels
from codeslam.sfm.normal_equations import assemble
from codeslam.sfm.priors import AffinePrior, CodePrior, ReadoutPrior
from codeslam.sfm.residuals import PairEvaluation, evaluate_pairs, pair_jacobians, robust_weights, step_cost_change
from codeslam.sfm.scale_prior import DepthScalePrior
from codeslam.sfm.variables import CODE, RS_DIM, BlockId, LinearPrior, SfMState, VariableLayout


class PairProblem:
    """The cost of one pyramid level: robust pair residuals + the VAE code prior ``0.5 w |c|^2`` + the affine
    prior (+ the readout-rotation prior with ``cfg.rolling_shutter``) + optional linear priors.

    level: stacked keyframes; pairs (P, 2) long (A, B); cfg: residual/loss settings and prior weights. With
    ``cfg.weights_per_level`` the fixed weights and sigmas of the problem's first evaluation are held for every
    later one (the coarse-to-fine loop builds one problem per level).
    """

    def __init__(
        self, level: LevelData, pairs: torch.Tensor, cfg: SfMConfig, priors: Sequence[LinearPrior] = ()
    ) -> None:
        if bool((pairs[:, 0] == pairs[:, 1]).any()):
            raise CodeSLAMError("a frame pair must join two different frames")
        self.level, self.pairs, self.cfg, self.priors = level, pairs, cfg, list(priors)
        self.pair_b = sorted({int(b) for b in pairs[:, 1].tolist()})
        self._held: tuple[torch.Tensor, torch.Tensor] | None = None  # cfg.weights_per_level: (fixed_weight, sigma)
        # The cost's own priors, then the extra terms (:mod:`codeslam.sfm.priors`). The state has readout
        # rotations only with cfg.rolling_shutter (see sfm).
        self.fixed_priors = [CodePrior(cfg.code_prior_weight)]  # VAE prior N(0, I) (Sec. 2.1)
        if cfg.affine_brightness:
            self.fixed_priors.append(AffinePrior(cfg.affine_prior_sigma))
        if cfg.rolling_shutter:
            self.fixed_priors.append(ReadoutPrior(cfg.rolling_shutter_sigma))

    def _prior_cost(self, state: SfMState) -> torch.Tensor:
        code, *others = self.fixed_priors
        cost = code.cost(state)
        for prior in others:
            cost = cost + prior.cost(state)
        for prior in self.priors:
            cost = cost + prior.cost(state).to(cost.dtype)
        return cost

    def evaluate(self, state: SfMState) -> tuple[float, PairEvaluation]:
        affine = state.affine if self.cfg.affine_brightness else None
        # cfg.weights_per_level: the first evaluation's weights priced at every later one, which does not form them
        ev = evaluate_pairs(self.level, self.pairs, state.poses, state.codes, affine, self.cfg, rs=state.rs,
                            weights=self._held)
        if self.cfg.weights_per_level and self._held is None:
            self._held = (ev.fixed_weight, ev.sigma)
        _, ev.cost = robust_weights(ev, self.cfg.masked_rows)
        return float(ev.cost.sum() + self._prior_cost(state)), ev

    def cost_change(self, old: PairEvaluation, new: PairEvaluation, old_cost: float, new_cost: float) -> float:
        """What a step changed the cost by (:func:`~codeslam.sfm.residuals.step_cost_change`)."""
        return step_cost_change(self.cfg.masked_rows, old, new, old_cost, new_cost)

    def linearize(
        self, state: SfMState, cache: PairEvaluation, layout: VariableLayout, clock: Clock = NO_CLOCK
    ) -> tuple[torch.Tensor, torch.Tensor]:
        self.level.refresh_scale_column(state.codes)
        code_b_free = any(BlockId(CODE, b) in layout for b in self.pair_b)
        terms = pair_jacobians(self.level, self.pairs, cache, with_code_b=code_b_free)
        H, g = assemble(terms, self.pairs, state.poses, self.level, layout, clock)
        for prior in (*self.fixed_priors, *self.priors):
            prior.add_to(H, g, layout, state)
        return H, g


@dataclass
class LMReport:
    """What one Levenberg-Marquardt run did. costs: the initial cost and the cost after every accepted step
    (each accepted step lowered it, or with ``masked_rows: common`` lowered it over the rows valid before and
    after, ``problem.cost_change``, so the cost itself may rise a little where a step brings rows into view)."""

    costs: list[float] = field(default_factory=list)
    iterations: int = 0
    accepted: int = 0
    rejected: int = 0
    damping: float = 0.0
    reason: str = ""


def solve_damped(H: torch.Tensor | np.ndarray, g: torch.Tensor | np.ndarray, damping: float, min_diagonal: float,
                 weights: torch.Tensor | None = None) -> torch.Tensor | np.ndarray | None:
    """Solve ``(H + damping diag(H) M) delta = -g`` by Cholesky in float64 (the system is small; float64 keeps
    ill-conditioned code blocks exact), ``M = diag(weights)`` (None: the identity, Marquardt's damping). Returns
    None when the damped matrix is not positive definite. NumPy ``H``, ``g`` (a host problem's, see the module)
    give a NumPy ``delta``."""
    if isinstance(H, np.ndarray):
        return _solve_damped_host(H, g, damping, min_diagonal, None if weights is None else weights.numpy())
    Hd, gd = H.to(torch.float64), g.to(torch.float64)
    diag = Hd.diagonal().clamp_min(min_diagonal)
    if weights is not None:
        diag = diag * weights.to(device=diag.device, dtype=diag.dtype)
    L, info = torch.linalg.cholesky_ex(Hd + torch.diag(damping * diag))
    if int(info) != 0:
        return None
    return -torch.cholesky_solve(gd.unsqueeze(-1), L).squeeze(-1)


def _solve_damped_host(H: np.ndarray, g: np.ndarray, damping: float, min_diagonal: float,
                       weights: np.ndarray | None) -> np.ndarray | None:
    """:func:`solve_damped` in NumPy: the Cholesky factor tests the damped matrix, the two triangular systems
    give the step (``np.linalg.solve`` on a triangular matrix: NumPy has no triangular solver)."""
    diag = np.maximum(np.diagonal(H), min_diagonal)
    if weights is not None:
        diag = diag * weights
    try:
        L = np.linalg.cholesky(H + np.diag(damping * diag))
    except np.linalg.LinAlgError:
        return None
    return -np.linalg.solve(L.T, np.linalg.solve(L, g))


def _all_finite(x: torch.Tensor | np.ndarray) -> bool:
    return bool(np.isfinite(x).all()) if isinstance(x, np.ndarray) else bool(torch.isfinite(x).all())


def _norm(x: torch.Tensor | np.ndarray) -> float:
    return float(np.linalg.norm(x)) if isinstance(x, np.ndarray) else float(x.norm())


def damping_weights(layout: VariableLayout, cfg: SfMConfig) -> torch.Tensor | None:
    """(D,) the damping's weight of every free entry of ``layout``: ``cfg.code_damping`` on the code blocks, 1
    elsewhere; None when that is all ones (no code block free, or ``code_damping`` 1)."""
    codes = [sl for b, sl in layout.slices() if b.kind == CODE]
    if cfg.code_damping == 1.0 or not codes:
        return None
    w = torch.ones(layout.dim, dtype=torch.float64)
    for sl in codes:
        w[sl] = cfg.code_damping
    return w


def levenberg_marquardt(
    problem, state: SfMState, layout: VariableLayout, cfg: SfMConfig, max_iterations: int,
    clock: Clock = NO_CLOCK, interrupted: Callable[[], bool] | None = None,
) -> tuple[SfMState, LMReport]:
    """Minimise ``problem``'s cost over ``layout``'s free blocks from ``state``.

    ``problem`` gives ``evaluate(state) -> (cost, cache)``, ``linearize(state, cache, layout, clock) -> (H,
    g)`` and ``cost_change(old_cache, new_cache, old_cost, new_cost)`` (the change a step is judged on,
    :attr:`SfMConfig.masked_rows`). Each iteration solves the damped normal equations (Marquardt's damping, the
    code entries' share weighted by :attr:`SfMConfig.code_damping`, :func:`damping_weights`); a step is accepted
    only if the new cost is finite and its change negative, then the damping shrinks; otherwise (cost increase,
    NaN/inf, non-PD system) the damping grows and the state is kept. Stops after ``max_iterations``, when an
    accepted step lowers the cost by less than ``relative_cost_tolerance`` or is shorter than ``step_tolerance``,
    when the quadratic model itself predicts less than that relative decrease (converged as far as the
    linearisation can tell; this also ends the run of rejections that approximate image gradients cause near the
    optimum), at a rejected step that promised less than ``rejection_stop_decrease`` of the cost, when the damping
    exceeds ``max_damping``, or when ``interrupted()`` turns true before an iteration (reason 'interrupted'; the
    state is the last accepted one, as after any stop). ``clock`` times every iteration as the stage 'iteration' and is
    handed to ``linearize`` (:mod:`codeslam.clock`; the runner's, if it wants the times).
    """
    report = LMReport(damping=cfg.initial_damping)
    cost, cache = problem.evaluate(state)
    report.costs.append(cost)
    if not math.isfinite(cost):
        report.reason = "non-finite initial cost"
        return state, report
    if layout.dim == 0:
        report.reason = "no free variables"
        return state, report
    lam = cfg.initial_damping
    weights = damping_weights(layout, cfg)
    H = g = None
    report.reason = "max iterations"
    for _ in range(max_iterations):
        if interrupted is not None and interrupted():
            report.reason = "interrupted"
            break
        with clock("iteration"):  # the runner's stopwatch, if it passed one (codeslam.clock)
            if H is None:
                H, g = problem.linearize(state, cache, layout, clock)
            delta = solve_damped(H, g, lam, cfg.min_diagonal, weights)
            accepted, predicted = False, math.inf  # no promise without a finite step
            if delta is not None and _all_finite(delta):
                d = delta if isinstance(delta, np.ndarray) else delta.to(H.dtype)
                predicted = -float(g @ d + 0.5 * d @ (H @ d))  # decrease the quadratic model promises
                if predicted < cfg.relative_cost_tolerance * abs(cost):
                    report.reason = "predicted decrease below tolerance"
                    break
                new_state = state.retract(layout, delta)
                new_cost, new_cache = problem.evaluate(new_state)
                if math.isfinite(new_cost):
                    change = problem.cost_change(cache, new_cache, cost, new_cost)
                    accepted = change < 0
            report.iterations += 1
            if accepted:
                rel = -change / max(abs(cost), sys.float_info.min)
                state, cost, cache = new_state, new_cost, new_cache
                H = g = None
                lam = max(lam * cfg.damping_decrease, MIN_LM_DAMPING)
                report.accepted += 1
                report.costs.append(cost)
            else:
                lam *= cfg.damping_increase
                report.rejected += 1
        if not accepted and predicted < cfg.rejection_stop_decrease * abs(cost):
            report.reason = "rejected a step the model promised little"
            break
        if accepted and rel < cfg.relative_cost_tolerance:
            report.reason = "relative cost decrease below tolerance"
            break
        if accepted and _norm(delta) < cfg.step_tolerance:
            report.reason = "step below tolerance"
            break
        if lam > cfg.max_damping:
            report.reason = "damping above maximum"
            break
    report.damping = lam
    return state, report


def coarse_to_fine(
    problem_at: Callable[[int], Any], state, layout: VariableLayout, cfg: SfMConfig,
    levels: Iterable[tuple[int, int]], clock: Clock = NO_CLOCK, interrupted: Callable[[], bool] | None = None,
    interruptible_levels: Container[int] | None = None, after_stop: int | None = None,
) -> tuple[Any, list[tuple[int, LMReport]], Any]:
    """Levenberg-Marquardt at each pyramid level in ``levels`` ((level, iterations), coarse to fine), each level
    starting from the one before (paper Sec. 4.1 and 4.2: the coarse levels widen the basin, the fine ones
    sharpen the estimate). ``problem_at(level)`` builds that level's problem (any problem
    :func:`levenberg_marquardt` drives); the N-frame SfM, the window and the tracker all run this one loop.
    Stops early when a level was interrupted (see :func:`levenberg_marquardt`); ``interrupted`` is asked only at
    the pyramid levels in ``interruptible_levels`` (None: at every level). The others run whole, or, with
    ``after_stop``, at most that many more iterations each once ``interrupted()`` has turned true, and the loop
    goes on to the next level (so that a stopped solve still passes every level on its way to the cut one).

    Returns the final state, one (level, :class:`LMReport`) per visited level, and the last level's problem (None
    when ``levels`` is empty)."""
    reports: list[tuple[int, LMReport]] = []
    problem = None
    for lvl, iters in levels:
        problem = problem_at(lvl)
        cuttable = interruptible_levels is None or lvl in interruptible_levels
        if cuttable or interrupted is None:
            cut = interrupted
        else:
            cut = None if after_stop is None else _after(interrupted, after_stop)
        state, rep = levenberg_marquardt(problem, state, layout, cfg, iters, clock, cut)
        reports.append((lvl, rep))
        if rep.reason == "interrupted" and cuttable:
            break
    return state, reports, problem


def _after(interrupted: Callable[[], bool], n: int) -> Callable[[], bool]:
    """``interrupted`` held back by ``n`` asks: true from the (n + 1)-th time it is asked once it has been true."""
    seen = 0

    def cut() -> bool:
        nonlocal seen
        if seen or interrupted():
            seen += 1
        return seen > n

    return cut


@dataclass
class SfMResult:
    """Result of :func:`sfm`. poses (F, 4, 4) T_wc; codes (F, C); affine (P, 2) (log-gain, bias) per pair;
    rs (F, 3) readout rotations (None without ``rolling_shutter``); pairs (P, 2); levels: one :class:`LMReport`
    per visited pyramid level (coarse to fine); iterations: accepted and rejected steps over all levels."""

    poses: torch.Tensor
    codes: torch.Tensor
    affine: torch.Tensor
    pairs: torch.Tensor
    levels: list[tuple[int, LMReport]]
    iterations: int
    rs: torch.Tensor | None = None

    @property
    def costs(self) -> list[float]:
        """Costs of the finest level's accepted steps (initial first)."""
        return self.levels[-1][1].costs

    def depths(self, keyframes: Sequence[Keyframe], level: int = 0) -> list[torch.Tensor | None]:
        """Decoded depth (H_l, W_l) of every keyframe at its optimised code (None for frames without decoder)."""
        return [None if kf.decoder is None else kf.decoder.depth(self.codes[i].to(kf.decoder.levels[0].jac.dtype),
                                                                 level)
                for i, kf in enumerate(keyframes)]


def _as_pairs(pairs, num_frames: int, device) -> torch.Tensor:
    t = torch.as_tensor(pairs, dtype=torch.long, device=device).reshape(-1, 2)
    if t.numel() == 0:
        raise CodeSLAMError("SfM needs at least one frame pair")
    if bool(((t < 0) | (t >= num_frames)).any()) or bool((t[:, 0] == t[:, 1]).any()):
        raise CodeSLAMError(f"SfM pairs must be (A, B) with distinct frame indices in [0, {num_frames})")
    return t


def sfm(
    keyframes: Sequence[Keyframe],
    pairs,
    config: SfMConfig | None = None,
    poses_init: torch.Tensor | None = None,
    codes_init: torch.Tensor | None = None,
    fixed: Sequence[BlockId] = (BlockId("pose", 0),),
    priors: Sequence[LinearPrior] = (),
    clock: Clock = NO_CLOCK,
) -> SfMResult:
    """Joint optimisation of the codes and poses of ``keyframes`` (paper Sec. 4.1).

    pairs: (P, 2) frame indices (A, B) whose residuals warp A into B (see :mod:`codeslam.sfm.pairs`).
    poses_init (F, 4, 4) T_wc (identity when None), codes_init (F, C) (zero when None, the paper's start).
    fixed: blocks held constant; the default fixes the first pose (the gauge); codes of frames without decoder
    are always fixed. priors: extra linear priors (e.g. from marginalisation), on free blocks only.
    Coarse to fine over ``config.pyramid_levels``, each level with ``config.max_iterations`` LM iterations.
    ``clock`` times the iterations (stage 'iteration') and their J^T W J products ('gemm'), :mod:`codeslam.clock`.
    """
    cfg = config or SfMConfig()
    levels = build_levels(keyframes, cfg.pyramid_levels)
    lv0 = levels[cfg.pyramid_levels[0]]
    dtype, device = lv0.jac.dtype, lv0.jac.device
    F_, C = lv0.num_frames, lv0.code_size
    pair_t = _as_pairs(pairs, F_, device)
    poses = torch.eye(4, dtype=dtype, device=device).repeat(F_, 1, 1) if poses_init is None else poses_init
    codes = torch.zeros(F_, C, dtype=dtype, device=device) if codes_init is None else codes_init
    if poses.shape != (F_, 4, 4) or codes.shape != (F_, C):
        raise CodeSLAMError(f"initial poses/codes must be ({F_}, 4, 4) and ({F_}, {C})")
    state = SfMState(poses.to(dtype=dtype, device=device).clone(), codes.to(dtype=dtype, device=device).clone(),
                     torch.zeros(pair_t.shape[0], 2, dtype=dtype, device=device),
                     torch.zeros(F_, RS_DIM, dtype=dtype, device=device) if cfg.rolling_shutter else None)
    no_depth = [BlockId(CODE, i) for i, kf in enumerate(keyframes) if kf.decoder is None]  # codes with no effect
    layout = VariableLayout.for_sfm(F_, C, pair_t.shape[0], cfg.affine_brightness, [*fixed, *no_depth],
                                    rolling_shutter=cfg.rolling_shutter)
    with_depth = [i for i, kf in enumerate(keyframes) if kf.decoder is not None]

    def problem_at(lvl: int) -> PairProblem:
        terms = list(priors)
        if cfg.depth_scale_sigma > 0 and with_depth:  # each frame's scale near the network's prediction
            terms.append(DepthScalePrior(levels[lvl], with_depth, cfg.depth_scale_sigma))
        return PairProblem(levels[lvl], pair_t, cfg, terms)

    state, reports, _ = coarse_to_fine(problem_at, state, layout, cfg, zip(cfg.pyramid_levels, cfg.max_iterations),
                                       clock)
    return SfMResult(
        poses=state.poses, codes=state.codes, affine=state.affine, pairs=pair_t, levels=reports,
        iterations=sum(r.iterations for _, r in reports), rs=state.rs,
    )
