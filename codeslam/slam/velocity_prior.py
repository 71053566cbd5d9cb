"""A constant-velocity prior on the window's keyframe positions (not in the paper; a cost term beside the code
prior, as the tracker's motion prior is beside its alignment).

Why. The tracker follows a constant-velocity model, but the window solves the keyframes' poses from their images
alone. Where the images say little (a blank wall: photometric residuals that barely change with the pose, no
keypoints), the window's solves moved consecutive keyframes 73-168 mm apart while the camera moved 5-7 mm
(docs/results/slam_table.md, fast turn 14). This term keeps the velocity between consecutive keyframes near the
velocity before them unless the images say otherwise, as a visual-inertial window's motion terms do without the
inertial measurements.

For consecutive keyframes i, j, k (times t_i < t_j < t_k, camera centres p = t of T_wc), with the mean
velocities ``v1 = (p_j - p_i) / d1`` and ``v2 = (p_k - p_j) / d2`` (d1 = t_j - t_i, d2 = t_k - t_j)::

    r = (v2 - v1) / sigma,        sigma = a (d1 + d2) / 2

``a`` (m/s^2, in the map's units) is the acceleration the camera may hold over the time between the two
intervals' midpoints, the same reading as the tracker's ``motion_prior_acceleration``. Under the window's left
increments ``T <- exp(xi) T`` (xi = (rho, phi)) the camera centre moves by ``dp = rho - [p]_x phi`` to first
order, so ``dp / dxi = [I, -[p]_x]`` and::

    dr/dxi_i = P_i / (d1 sigma),   dr/dxi_j = -(1/d1 + 1/d2) P_j / sigma,   dr/dxi_k = P_k / (d2 sigma)

written by hand (three 3x6 blocks; ``P = [I, -[p]_x]`` is :func:`~codeslam.geometry.lie.se3_act_jac_pose` at the
origin) and checked against autograd in float64 (tests/slam/test_slam_velocity_prior.py).
The term has the interface of :class:`~codeslam.sfm.variables.LinearPrior` (``cost``, ``add_to``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from codeslam.geometry.lie import se3_act_jac_pose
from codeslam.sfm.variables import POSE, BlockId, SfMState, VariableLayout


@dataclass
class VelocityPrior:
    """``0.5 |r|^2`` over keyframe triples (module docstring).

    Attributes:
        triples: (i, j, k) state positions of consecutive keyframes, oldest first.
        gaps: (d1, d2) seconds between i and j and between j and k, each positive.
        acceleration: a in m/s^2 (> 0).
    """

    triples: list[tuple[int, int, int]]
    gaps: list[tuple[float, float]]
    acceleration: float

    @classmethod
    def consecutive(cls, timestamps: list[float], acceleration: float, first: int = 0) -> VelocityPrior:
        """Every triple of consecutive positions ``first, first + 1, ...`` of keyframes with these timestamps
        (seconds), skipping a triple whose times do not increase."""
        triples, gaps = [], []
        for n in range(len(timestamps) - 2):
            d1, d2 = timestamps[n + 1] - timestamps[n], timestamps[n + 2] - timestamps[n + 1]
            if d1 > 0 and d2 > 0:
                triples.append((first + n, first + n + 1, first + n + 2))
                gaps.append((d1, d2))
        return cls(triples, gaps, acceleration)

    def __len__(self) -> int:
        return len(self.triples)

    def _weights(self, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        """(T, 3) the position coefficients ``(1/d1, -(1/d1 + 1/d2), 1/d2) / sigma`` of each triple."""
        w = [(1.0 / d1, -(1.0 / d1 + 1.0 / d2), 1.0 / d2) for d1, d2 in self.gaps]
        sig = [self.acceleration * 0.5 * (d1 + d2) for d1, d2 in self.gaps]
        return torch.tensor(w, dtype=dtype, device=device) / torch.tensor(sig, dtype=dtype, device=device)[:, None]

    def _gather(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor]:
        """-> the triples' poses T_wc (T, 3 keyframes, 4, 4) and their coefficients (T, 3)."""
        idx = torch.tensor(self.triples, dtype=torch.long, device=state.poses.device)  # (T, 3)
        T = state.poses[idx]
        return T, self._weights(T.dtype, T.device)

    @staticmethod
    def _residuals(T: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """The triples' poses (T, 3, 4, 4) and coefficients (T, 3) -> (T, 3) ``r``."""
        return (w[..., None] * T[..., :3, 3]).sum(1)  # = (v2 - v1) / sigma

    def residuals(self, state: SfMState) -> torch.Tensor:
        """(T, 3) ``r`` of each triple."""
        return self._residuals(*self._gather(state))

    def cost(self, state: SfMState) -> torch.Tensor:
        if not self.triples:
            return state.poses.new_zeros(())
        return 0.5 * self.residuals(state).square().sum()

    def linearise(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor]:
        """-> ``r`` (T, 3) and ``dr / dxi`` (T, 3 keyframes, 3, 6) of each triple's keyframes, in the order of the
        triple. The camera centre is the image of the origin, ``p = T 0``: ``dp / dxi = [I, -p^]``."""
        T, w = self._gather(state)
        r = self._residuals(T, w)
        dp = se3_act_jac_pose(T, T.new_zeros(T.shape[:-2] + (3,)))  # (T, 3, 3, 6)
        return r, w[..., None, None] * dp

    def jacobians(self, state: SfMState) -> torch.Tensor:
        """(T, 3 keyframes, 3, 6) ``dr / dxi`` (:meth:`linearise`)."""
        return self.linearise(state)[1]

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        if not self.triples:
            return
        r, J = self.linearise(state)
        r, J = r.to(g.dtype), J.to(H.dtype)
        for t, triple in enumerate(self.triples):
            slices = [layout.slice(BlockId(POSE, i)) for i in triple]
            for a, sa in enumerate(slices):
                if sa is None:  # a fixed pose (the gauge)
                    continue
                g[sa] += J[t, a].T @ r[t]
                for b, sb in enumerate(slices):
                    if sb is not None:
                        H[sa, sb] += J[t, a].T @ J[t, b]
