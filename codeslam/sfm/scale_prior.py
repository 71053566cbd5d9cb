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
        prox0 = self.level.prox0[:, 0]  # (F, H, W)
        valid = torch.isfinite(prox0) & (prox0 > 0)
        # The valid pixels of each frame's proximity and code Jacobian, gathered once: (M,) and (C, M).
        self._p0 = {k: prox0[k][valid[k]] for k in self.frames}
        self._jac = {k: self.level.jac[k][:, valid[k]] for k in self.frames}
        self._target = [self._mean_log_depth(self._p0[k], self.level.avg_depth[k]) for k in self.frames]

    @staticmethod
    def _mean_log_depth(prox: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return torch.log(prox_to_depth(prox, a).clamp_min(1e-6)).mean()

    def _residual(self, state: SfMState, k: int, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """-> r (scalar) and dr/dc_k (C,) of frame k."""
        jac = self._jac[k]
        prox = self._p0[k] + state.codes[k].to(jac.dtype) @ jac  # (M,) p0 + J c
        a = self.level.avg_depth[k]
        m = self._mean_log_depth(prox, a)
        d = prox_to_depth(prox, a).clamp_min(1e-6)
        dlog = d_depth_d_prox(prox, a) / d  # (M,) d log D / dp
        grad = jac @ dlog / dlog.numel()  # (C,) dm/dc
        return (m - target) / self.sigma, grad / self.sigma

    def cost(self, state: SfMState) -> torch.Tensor:
        total = state.codes.new_zeros(())
        for k, target in zip(self.frames, self._target):
            r, _ = self._residual(state, k, target)
            total = total + 0.5 * r.to(total.dtype) ** 2
        return total

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        for k, target in zip(self.frames, self._target):
            sl = layout.slice(BlockId(CODE, k))
            if sl is None:
                continue
            r, J = self._residual(state, k, target)
            J = J.to(H.dtype)
            H[sl, sl] += torch.outer(J, J)
            g[sl] += J * r.to(g.dtype)
