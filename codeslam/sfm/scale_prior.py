"""A prior on each keyframe's depth scale: the mean log depth of its decoded depth stays near the network's
zero-code prediction (not in the paper; a cost term beside the code prior).

Why. Photometric and log-depth residuals do not change when every depth and every translation is scaled
together, so monocular scale is held only by the code prior ``0.5 |c|^2``, which is cheap in the far field:
proximity ``p = a / (d + a)`` changes little while the depth runs away. Measured on the HoloLens walk (oracle
depth, window of four keyframes): without this term the window's solves moved keyframes' median depths to
0.57-1.44 of the truth and then blew the trajectory up by a factor of several hundred; the network's zero code
predicts the scale of a single view, so each keyframe's scale is tied to it, loosely (``sigma`` in log depth).

For keyframe k with decoded proximity ``p(c) = p0 + J c`` over its M valid pixels::

    m(c) = (1 / M) sum_i log D(p_i(c)),        r = (m(c) - m(0)) / sigma
    dr/dc = (1 / (M sigma)) sum_i (dD/dp / D)_i J_i                       (first order in c)

The term has the interface of :class:`~codeslam.sfm.variables.LinearPrior` (``cost``, ``add_to``), so
:class:`~codeslam.sfm.solver.PairProblem` takes it among its extra terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from codeslam.geometry.proximity import d_depth_d_prox, prox_to_depth
from codeslam.sfm.keyframes import LevelData
from codeslam.sfm.normal_equations import batched_mv
from codeslam.sfm.variables import CODE, BlockId, SfMState, VariableLayout


@dataclass
class DepthScalePrior:
    """``0.5 ((m_k(c_k) - m_k(0)) / sigma)^2`` for each frame k in ``frames`` of one pyramid level.

    Attributes:
        level: the stacked keyframes at the level the solver is on.
        frames: the frames (indices into the level) the prior holds.
        sigma: allowed change of the mean log depth (0.1 = 10% of scale).
    """

    level: LevelData
    frames: list[int]
    sigma: float

    def __post_init__(self) -> None:
        self._idx = idx = torch.tensor(self.frames, dtype=torch.long, device=self.level.prox0.device)
        prox0 = self.level.prox0[idx, 0].flatten(1)  # (K, N)
        self._valid = torch.isfinite(prox0) & (prox0 > 0)  # (K, N)
        self._count = self._valid.sum(-1).clamp_min(1)  # (K,) M of each frame
        # Every frame at once over all N pixels, the invalid ones zeroed and left out of the means (one frame at
        # a time, ~15 tensor operations each, the prior took 2-3 ms of every window linearisation and cost).
        # No copy of the level's Jacobian (12.6 MB at C = 64, 4 x 128x96; the two scale priors' copies took ~6 ms
        # of every TUM window solve) where the prior covers every frame in order and every pixel is valid.
        every = self.frames == list(range(self.level.num_frames))
        all_valid = bool(self._valid.all())
        self._p0 = prox0 if all_valid else torch.where(self._valid, prox0, 0.0)
        jac = self.level.jac.flatten(2) if every else self.level.jac[idx].flatten(2)  # (K, C, N)
        self._scaled = self.level.scale_entry  # the codes' last entry is a log scale: m = s + mean log D(c)
        if self._scaled:
            jac = jac[:, :-1]
        self._jac = jac if all_valid else torch.where(self._valid[:, None], jac, 0.0)
        self._a = self.level.avg_depth[idx].to(prox0.dtype)[:, None]  # (K, 1)
        self._target = self._mean_log_depth(self._p0)  # (K,) m(0)

    def _mean_log_depth(self, prox: torch.Tensor) -> torch.Tensor:
        """(K, N) proximities -> (K,) mean log depth over each frame's valid pixels."""
        logd = torch.log(prox_to_depth(prox, self._a).clamp_min(1e-6))
        return torch.where(self._valid, logd, 0.0).sum(-1) / self._count

    def _prox(self, state: SfMState) -> torch.Tensor:
        """(K, N) proximity ``p0 + J c`` of the prior's frames at the state's codes."""
        codes = state.codes[self._idx].to(self._jac.dtype)  # (K, C)
        if self._scaled:
            codes = codes[:, :-1]
        return self._p0 + (codes[:, None, :] @ self._jac).squeeze(1)

    def _log_scale(self, state: SfMState) -> torch.Tensor | float:
        return state.codes[self._idx, -1].to(self._jac.dtype) if self._scaled else 0.0

    def _residuals(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor]:
        """-> r (K,) and dr/dc (K, C) of the prior's frames, in their order."""
        prox = self._prox(state)
        m = self._mean_log_depth(prox)
        d = prox_to_depth(prox, self._a).clamp_min(1e-6)
        dlog = torch.where(self._valid, d_depth_d_prox(prox, self._a) / d, 0.0)  # (K, N) d log D / dp
        grad = batched_mv(self._jac, dlog) / self._count[:, None]  # (K, C) dm/dc
        if self._scaled:  # m = s + mean log D(c): dm/ds = 1
            grad = torch.cat([grad, torch.ones_like(grad[:, :1])], dim=1)
        return (m + self._log_scale(state) - self._target) / self.sigma, grad / self.sigma

    def cost(self, state: SfMState) -> torch.Tensor:
        r = (self._mean_log_depth(self._prox(state)) + self._log_scale(state) - self._target) / self.sigma
        return 0.5 * r.to(state.codes.dtype).square().sum()

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        r, J = self._residuals(state)
        r, J = r.to(g.dtype), J.to(H.dtype)
        for i, k in enumerate(self.frames):
            sl = layout.slice(BlockId(CODE, k))
            if sl is not None:
                H[sl, sl] += torch.outer(J[i], J[i])
                g[sl] += J[i] * r[i]


@dataclass
class WindowScalePrior(DepthScalePrior):
    """``0.5 ((1 / K) sum_k (m_k(c_k) - m_k(0)) / sigma)^2`` over the K frames in ``frames``: the scale of the
    frames taken together held near the network's, their scales relative to each other left to the data and to
    each frame's :class:`DepthScalePrior`.

    Why. The data terms do not see the scale, and on the generator's walks the window's first solve ends at half
    the network's scale (walk 42, frames 0 and 5: median depth 0.51 of the truth, while the zero code is at
    1.02-1.08 and the tracked baseline at 1.00; converged, 28 iterations), its codes no larger than those that
    fit the true depth at the true scale (norm 9 against 8-9). A common shrink of every keyframe costs each
    per-frame prior little; this term prices the common mode alone.
    """

    def cost(self, state: SfMState) -> torch.Tensor:
        r = (self._mean_log_depth(self._prox(state)) + self._log_scale(state) - self._target).mean() / self.sigma
        return 0.5 * r.to(state.codes.dtype).square()

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        r, J = self._residuals(state)  # per frame, each / sigma
        K = len(self.frames)
        R, J = (r.sum() / K).to(g.dtype), (J / K).to(H.dtype)  # one residual, its gradient per frame's code
        slices = [layout.slice(BlockId(CODE, k)) for k in self.frames]
        for i, si in enumerate(slices):
            if si is None:
                continue
            g[si] += J[i] * R
            for j, sj in enumerate(slices):
                if sj is not None:
                    H[si, sj] += torch.outer(J[i], J[j])
