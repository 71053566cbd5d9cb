"""Dense warping (paper Sec. 3): the correspondence w(u, c_A, T_BA) and its analytic Jacobians.

Shapes: P frame pairs, N pixels per pair. Transforms (P, 4, 4), pixels and points (P, N, 2|3), camera params
(P, 1, 4) or (4,) (fx, fy, cx, cy), depths (P, N).

Pose parametrisation. Absolute poses are ``T_wc`` (camera-to-world) perturbed on the LEFT, ``T_wc <- exp(xi)
T_wc`` with ``xi = (rho, phi)`` (world-frame increments). The relative pose of a pair (A, B) is ``T_BA =
T_wB^-1 T_wA`` (maps A's points into B), also perturbed on the left, ``T_BA <- exp(xi_BA) T_BA``. The chain
rule from absolute to relative increments uses the adjoint (``T exp(xi) T^-1 = exp(Ad_T xi)``):

* ``T_wB^-1 exp(xi_A) T_wA = (T_wB^-1 exp(xi_A) T_wB) T_BA = exp(Ad_{T_Bw} xi_A) T_BA``, so
  ``d xi_BA / d xi_A = Ad_{T_Bw}``;
* ``(exp(xi_B) T_wB)^-1 T_wA = T_wB^-1 exp(-xi_B) T_wA = exp(-Ad_{T_Bw} xi_B) T_BA``, so
  ``d xi_BA / d xi_B = -Ad_{T_Bw}``.
"""

from __future__ import annotations

import torch

from codeslam.geometry.camera import project, project_jac, unproject_jac_depth
from codeslam.geometry.lie import hat, se3_act, se3_adjoint, se3_inverse


def relative_pose(T_wA: torch.Tensor, T_wB: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) camera-to-world poses of A and B -> (..., 4, 4) ``T_BA = T_wB^-1 T_wA``."""
    return se3_inverse(T_wB) @ T_wA


def relative_pose_jacobians(T_wB: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(..., 4, 4) -> ``(d xi_BA / d xi_A, d xi_BA / d xi_B)``, each (..., 6, 6): ``Ad_{T_Bw}`` and
    ``-Ad_{T_Bw}`` for left perturbations of T_wA, T_wB and T_BA (derivation in the module docstring)."""
    Ad = se3_adjoint(se3_inverse(T_wB))
    return Ad, -Ad


def warp(
    uv: torch.Tensor, depth_A: torch.Tensor, T_BA: torch.Tensor, params_A: torch.Tensor, params_B: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The correspondence of the paper's Eq. 5, ``w(u, c_A, T_BA) = pi(R_BA pi^-1(u, D_A[u]) + t_BA)``.

    uv (P, N, 2) pixels of A, depth_A (P, N) = D_A[u], T_BA (P, 4, 4) -> ``v = w(u)`` (P, N, 2), the point in B
    ``x = R_BA pi^-1(u, d) + t_BA`` (P, N, 3) (Eq. 11) and the ray of u in A ``d pi^-1/d d`` (P, N, 3).
    """
    ray_A = unproject_jac_depth(uv, params_A)  # (P, N, 3), pi^-1(u, d) = d * ray
    x_B = se3_act(T_BA, ray_A * depth_A.unsqueeze(-1))  # Eq. 11: x = R pi^-1(u, d) + t
    return project(x_B, params_B), x_B, ray_A  # Eq. 5: v = pi(x)


def point_jacobians(x_B: torch.Tensor, ray_A: torch.Tensor, T_BA: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Jacobians of the warped point ``x = R_BA d ray + t_BA`` (P, N, 3).

    x_B (P, N, 3), ray_A (P, N, 3), T_BA (P, 4, 4) -> ``d x / d xi_BA`` (P, N, 3, 6) for the left perturbation
    of T_BA, and ``d x / d d`` (P, N, 3) for A's depth d at u.
    """
    t = T_BA[..., :3, 3].unsqueeze(-2)  # (P, 1, 3)
    Rp = x_B - t  # R pi^-1(u, d), (P, N, 3)
    dx_dt = torch.eye(3, dtype=x_B.dtype, device=x_B.device).expand(x_B.shape + (3,))  # Eq. 7 (after d pi/d x)
    dx_dR = hat(-Rp)  # Eq. 8: (-R pi^-1(u, d))^x, rotation R <- exp(phi) R about B's origin
    # The paper perturbs (R, t) separately; the SE(3) left increment exp(xi) T also moves the translation,
    # t <- t + rho + phi x t, which adds -t^ to the rotation column: d x / d phi = -(R p + t)^ = -x^.
    dx_dxi = torch.cat([dx_dt, dx_dR - hat(t).expand(dx_dR.shape)], dim=-1)  # (P, N, 3, 6)
    dx_dd = ray_A @ T_BA[..., :3, :3].transpose(-1, -2)  # Eq. 9: R d pi^-1(u, d) / d d, (P, N, 3)
    return dx_dxi, dx_dd


def pose_row(dr_dx: torch.Tensor, x_B: torch.Tensor, T_BA: torch.Tensor) -> torch.Tensor:
    """``dr_dx @ (d x / d xi_BA)`` without forming the (P, N, 3, 6) Jacobian of :func:`point_jacobians`.

    dr_dx (P, N, 3) the derivative of a scalar residual w.r.t. the warped point, x_B (P, N, 3), T_BA (P, 4, 4)
    -> (P, N, 6). For a row a: ``a^T (-y)^x = (y x a)^T``, so Eq. 7 gives ``a`` and Eq. 8 ``(R p) x a``; the SE(3)
    left increment adds ``t x a`` (see :func:`point_jacobians`), in total ``[a, x x a]``.
    """
    t = T_BA[..., :3, 3].unsqueeze(-2).expand_as(x_B)  # (P, N, 3)
    Rp = x_B - t  # R pi^-1(u, d)
    J_t = dr_dx  # Eq. 7
    J_R = torch.linalg.cross(Rp, dr_dx, dim=-1)  # Eq. 8: a^T (-R p)^x
    return torch.cat([J_t, J_R + torch.linalg.cross(t, dr_dx, dim=-1)], dim=-1)  # SE(3) left: [a, x x a]


def warp_jacobians(
    x_B: torch.Tensor, ray_A: torch.Tensor, T_BA: torch.Tensor, params_B: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Jacobians of ``v = w(u)``: ``d v / d xi_BA`` (P, N, 2, 6), ``d v / d d`` (P, N, 2) and the projection
    Jacobian ``d pi / d x`` (P, N, 2, 3) they share (the paper's Eqs. 7-9 without the image gradient)."""
    dpi = project_jac(x_B, params_B)  # (P, N, 2, 3)
    dx_dxi, dx_dd = point_jacobians(x_B, ray_A, T_BA)
    return dpi @ dx_dxi, (dpi @ dx_dd.unsqueeze(-1)).squeeze(-1), dpi
