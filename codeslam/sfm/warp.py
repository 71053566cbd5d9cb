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
from codeslam.geometry.lie import hat, se3_act, se3_adjoint, se3_inverse, so3_act


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


def readout_fraction(rows: torch.Tensor, height: int) -> torch.Tensor:
    """The time at which a row was exposed, as a fraction of the readout from the middle row: ``s(y) = (y - (H -
    1) / 2) / H`` in [-0.5, 0.5] (the same at every pyramid level)."""
    return (rows - 0.5 * (height - 1)) / height


def warp_rolling_shutter(
    uv: torch.Tensor, depth_A: torch.Tensor, T_BA: torch.Tensor, params_A: torch.Tensor, params_B: torch.Tensor,
    omega_A: torch.Tensor, omega_B: torch.Tensor, height: int,
) -> tuple[torch.Tensor, ...]:
    """Eq. 5 for rolling-shutter cameras: the camera that exposed row y of frame k is its pose turned by
    ``s(y) omega_k`` (:func:`readout_fraction`; omega_k is the rotation over the whole readout in k's frame, a few
    degrees at most, so the rotation is taken to first order, ``R(s) = I + s [omega]_x``; the translation during
    the readout is neglected).

    A's pixel u (row y_A) is the point ``X = d (ray + s_A omega_A x ray)`` in A's mid-readout frame, ``x_c =
    T_BA X`` in B's; B sees it in the row it projects to, ``s_B`` taken from the global-shutter projection of
    ``x_c`` (held fixed: one fixed-point step, the row moves by a fraction of a pixel), turned back by that row's
    rotation: ``x_B = x_c - s_B omega_B x x_c``, ``v = pi(x_B)``.

    uv (P, N, 2), depth_A (P, N), T_BA (P, 4, 4), params (P, 1, 4), omega_A / omega_B (P, 1, 3), height: rows of
    both images -> v (P, N, 2), x_B, x_c, ray (the rotated ray, d x_c / d d = R ray), ray0 (A's unrotated ray),
    (P, N, 3) each, and s_A, s_B (P, N).
    """
    ray0 = unproject_jac_depth(uv, params_A)  # (P, N, 3)
    s_A = readout_fraction(uv[..., 1], height)
    turn_A = cross_columns(omega_A.transpose(-1, -2), ray0.transpose(-1, -2)).transpose(-1, -2)  # omega_A x ray0
    ray = ray0 + s_A.unsqueeze(-1) * turn_A
    x_c = se3_act(T_BA, ray * depth_A.unsqueeze(-1))
    s_B = readout_fraction(project(x_c, params_B)[..., 1], height).detach()
    x_B = x_c - s_B.unsqueeze(-1) * cross_columns(omega_B.transpose(-1, -2), x_c.transpose(-1, -2)).transpose(-1, -2)
    return project(x_B, params_B), x_B, x_c, ray, ray0, s_A, s_B


def rolling_shutter_rows(
    dr_dx: torch.Tensor, x_c: torch.Tensor, ray0: torch.Tensor, depth_A: torch.Tensor, T_BA: torch.Tensor,
    omega_B: torch.Tensor, s_A: torch.Tensor, s_B: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Chain rule through :func:`warp_rolling_shutter` for a scalar residual with ``dr_dx`` = d r / d x_B
    (P, 3, N), channels first -> d r / d x_c (P, 3, N) (what the pose and depth rows use), d r / d omega_A and
    d r / d omega_B (P, 3, N each). x_c, ray0 (P, N, 3) and omega_B (P, 1, 3) as the warp gives them.

    ``d x_B / d x_c = I - s_B [omega_B]_x`` gives the row ``a - s_B (a x omega_B)``; ``d x_B / d omega_B = s_B
    [x_c]_x`` gives ``s_B (a x x_c)``; ``d x_c / d omega_A = -d s_A R [ray0]_x`` gives ``-d s_A ((R^T a_c) x
    ray0)`` (for a row b, ``b [y]_x = (b x y)^T``). Channels first as the pair Jacobians are
    (:func:`~codeslam.sfm.residuals.pair_jacobians`; the same values as over (P, N, 3) rows).
    """
    sB, dsA = s_B.unsqueeze(-2), (depth_A * s_A).unsqueeze(-2)  # (P, 1, N): s_B and d s_A
    dr_dxc = dr_dx - sB * cross_columns(dr_dx, omega_B.transpose(-1, -2))
    dr_dwB = sB * cross_columns(dr_dx, x_c.transpose(-1, -2))
    aR = T_BA[..., :3, :3].transpose(-1, -2) @ dr_dxc  # the row a_c R = R^T a_c, (P, 3, N)
    dr_dwA = -dsA * cross_columns(aR, ray0.transpose(-1, -2))
    return dr_dxc, dr_dwA, dr_dwB


def cross_columns(a: torch.Tensor, b: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``a x b`` over dimension -2 of (..., 3, N) tensors (broadcasting, e.g. b (..., 3, 1)), each component
    ``a_j b_k - a_k b_j`` in one fused multiply-add (``addcmul``) as ``torch.linalg.cross`` rounds it on the CPU,
    into ``out`` when given. Written for a measured reason: ``linalg.cross`` over that dimension, or over (..., N, 3)
    rows of 3, runs a scalar loop (1.0 against 0.28 ms for 6 x 12,288 points, 2 threads, AMD Zen 3)."""
    a0, a1, a2 = a.unbind(-2)
    b0, b1, b2 = b.unbind(-2)
    if out is None:  # stacked, not written into: forward-mode autograd (sfm.autodiff) has no out= variants
        return torch.stack([torch.addcmul(-(a2 * b1), a1, b2), torch.addcmul(-(a0 * b2), a2, b0),
                            torch.addcmul(-(a1 * b0), a0, b1)], dim=-2)
    torch.addcmul(-(a2 * b1), a1, b2, out=out[..., 0, :])
    torch.addcmul(-(a0 * b2), a2, b0, out=out[..., 1, :])
    torch.addcmul(-(a1 * b0), a0, b1, out=out[..., 2, :])
    return out


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
    dx_dd = so3_act(T_BA[..., :3, :3], ray_A)  # Eq. 9: R d pi^-1(u, d) / d d, (P, N, 3)
    return dx_dxi, dx_dd


def pose_columns(dr_dx: torch.Tensor, x_B: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """``dr_dx @ (d x / d xi_BA)`` without forming the (P, N, 3, 6) Jacobian of :func:`point_jacobians`, channels
    first: dr_dx (..., 3, N) the derivative of a scalar residual w.r.t. the warped point x_B = R p + t (..., 3, N)
    -> its six pose columns written into ``out`` (..., 6, N) (and returned), e.g. the pose columns of a larger
    Jacobian: concatenating and then copying took 3.1 ms for 12 pairs of 128x96 pixels against 2.1 written in place
    (2 threads).

    For a row a: ``a^T (-y)^x = (y x a)^T``, so Eq. 7 gives ``a`` and Eq. 8 ``(R p) x a``; the SE(3) left increment
    adds ``t x a`` (see :func:`point_jacobians`), in total ``[a, x x a]``. The cross product by
    :func:`cross_columns`. One cross product with x itself: the two of (R p) x a + t x a, and R p = x - t, took
    1.0-2.3 ms against 0.5.
    """
    out[..., :3, :] = dr_dx
    cross_columns(x_B, dr_dx, out=out[..., 3:, :])  # x x a
    return out


def warp_jacobians(
    x_B: torch.Tensor, ray_A: torch.Tensor, T_BA: torch.Tensor, params_B: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Jacobians of ``v = w(u)``: ``d v / d xi_BA`` (P, N, 2, 6), ``d v / d d`` (P, N, 2) and the projection
    Jacobian ``d pi / d x`` (P, N, 2, 3) they share (the paper's Eqs. 7-9 without the image gradient)."""
    dpi = project_jac(x_B, params_B)  # (P, N, 2, 3)
    dx_dxi, dx_dd = point_jacobians(x_B, ray_A, T_BA)
    return dpi @ dx_dxi, (dpi @ dx_dd.unsqueeze(-1)).squeeze(-1), dpi
