"""Reprojection residuals of matched keypoints, a cost term beside the photometric pairs (DeepFactors' sparse
geometric factor; not in the CodeSLAM paper).

A keypoint of frame A with 3D point ``X_A`` (from A's decoded depth, held fixed) is matched to the keypoint
``u_B`` of frame B. Its residual is the reprojection error in B's (feature) camera::

    r = pi(T_BA X_A) - u_B,        T_BA = T_wB^-1 T_wA                      (the paper's Eq. 5 with known depth)

with a Huber loss of ``sigma`` pixels (scaled by ORB's pyramid scale of the keypoint). Poses are perturbed on
the left as everywhere in the solver (:mod:`codeslam.sfm.warp`), so with ``x = T_BA X_A``::

    dr/d xi_BA = dpi/dx [I, -x^],   d xi_BA / d xi_A = Ad_{T_Bw},   d xi_BA / d xi_B = -Ad_{T_Bw}

The term has the interface of :class:`~codeslam.sfm.variables.LinearPrior` (``cost(state)`` and
``add_to(H, g, layout, state)``), so a :class:`~codeslam.sfm.solver.PairProblem` takes it among its extra terms
and the Levenberg-Marquardt loop needs no change.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from codeslam.geometry.camera import PinholeCamera, project, project_jac
from codeslam.geometry.lie import hat, se3_act
from codeslam.sfm.residuals import huber_cost_and_weight
from codeslam.sfm.variables import POSE, BlockId, SfMState, VariableLayout
from codeslam.sfm.warp import relative_pose, relative_pose_jacobians


@dataclass
class ReprojectionTerm:
    """Matched keypoints between frame ``a`` (3D points) and frame ``b`` (pixels) of a state.

    Attributes:
        a, b: frame indices in the state (``state.poses[a]``, ``state.poses[b]``).
        xyz_a: (N, 3) points in A's camera frame.
        uv_b: (N, 2) their observed pixels in B's camera.
        sigma: (N,) pixel noise of each observation.
        camera: B's camera (the feature camera).
        huber: Huber threshold in sigmas.
        weight: overall weight of the term (1 = the observations' own noise).
    """

    a: int
    b: int
    xyz_a: torch.Tensor
    uv_b: torch.Tensor
    sigma: torch.Tensor
    camera: PinholeCamera
    huber: float = 1.345
    weight: float = 1.0

    def __len__(self) -> int:
        return int(self.xyz_a.shape[0])

    def residuals(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> r (N, 2) pixels, x (N, 3) the points in B, T_BA (4, 4), all in the state's dtype."""
        dtype, device = state.poses.dtype, state.poses.device
        T_BA = relative_pose(state.poses[self.a], state.poses[self.b])
        x = se3_act(T_BA, self.xyz_a.to(dtype=dtype, device=device))  # x = T_BA X_A
        params = self.camera.params(dtype, device)
        r = project(x, params) - self.uv_b.to(dtype=dtype, device=device)  # r = pi(x) - u_B
        return r, x, T_BA

    def _robust(self, r: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """-> per-point cost (N,) ``weight rho(|r| / sigma)`` and IRLS weight (N,) ``weight rho'(s)/s / sigma^2``;
        points behind B cost ``rho(huber)`` and get no weight."""
        sigma = self.sigma.to(dtype=r.dtype, device=r.device)
        s = r.norm(dim=-1) / sigma
        front = x[:, 2] > 1e-6
        rho, w = huber_cost_and_weight(s, self.huber)
        k = self.huber
        cost = torch.where(front, rho, torch.full_like(rho, 0.5 * k * k))
        irls = torch.where(front, w / sigma**2, torch.zeros_like(w))
        return self.weight * cost, self.weight * irls

    def cost(self, state: SfMState) -> torch.Tensor:
        if len(self) == 0:
            return state.poses.new_zeros(())
        r, x, _ = self.residuals(state)
        return self._robust(r, x)[0].sum()

    def jacobians(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> r (N, 2), J_A (N, 2, 6), J_B (N, 2, 6) (left perturbations of T_wA and T_wB), IRLS weights (N,)."""
        r, x, _ = self.residuals(state)
        dpi = project_jac(x, self.camera.params(x.dtype, x.device))  # (N, 2, 3)
        eye = torch.eye(3, dtype=x.dtype, device=x.device).expand(x.shape[0], 3, 3)
        dx_dxi = torch.cat([eye, -hat(x)], dim=-1)  # (N, 3, 6): d(exp(xi) T_BA X)/d xi = [I, -x^]
        J_rel = dpi @ dx_dxi  # (N, 2, 6)
        dA, dB = relative_pose_jacobians(state.poses[self.b])  # Ad_{T_Bw}, -Ad_{T_Bw}
        _, w = self._robust(r, x)
        return r, J_rel @ dA, J_rel @ dB, w

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        """Add ``J^T W J`` and ``J^T W r`` of the free poses (a and/or b) in place (IRLS, Gauss-Newton)."""
        if len(self) == 0:
            return
        r, J_A, J_B, w = self.jacobians(state)
        blocks = [(BlockId(POSE, self.a), J_A), (BlockId(POSE, self.b), J_B)]
        free = [(layout.slice(b), J) for b, J in blocks if b in layout]
        for si, Ji in free:
            Jw = Ji * w[:, None, None]  # (N, 2, 6)
            g[si] += torch.einsum("nki,nk->i", Jw, r).to(g.dtype)
            for sj, Jj in free:
                H[si, sj] += torch.einsum("nki,nkj->ij", Jw, Jj).to(H.dtype)

