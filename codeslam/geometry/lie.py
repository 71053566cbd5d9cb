"""SO(3) and SE(3) as batched pure functions on rotation matrices and 4x4 transforms.

Conventions (used by the whole package):

* A tangent vector of SE(3) is ``xi = (rho, phi)``, shape (..., 6): translation part first, rotation part second.
* Perturbations are on the LEFT: an increment ``xi`` updates ``T <- exp(xi) T`` unless a function says otherwise
  (:func:`se3_act_jac_pose_right` is the one right-perturbation exception).
* ``exp((rho, phi)) = [[R, J_l(phi) rho], [0, 1]]`` with ``R = exp(phi^)`` and ``J_l`` the SO(3) left Jacobian, so
  ``d/d xi exp(xi) T p |_0 = [I, -(T p)^]``; the adjoint is ``Ad_T = [[R, t^ R], [0, R]]`` and satisfies
  ``T exp(xi) T^-1 = exp(Ad_T xi)``.
* ``T_ab`` maps points of frame b into frame a.

Angles below ``codeslam.constants.SMALL_ANGLE`` use Taylor expansions, and the two Jacobian coefficients that
cancel catastrophically use their series below ``SERIES_ANGLE``; each closed form is evaluated on a safe angle so
that autograd stays finite everywhere (autograd through ``so3_exp``/``se3_exp`` at any angle, 0 included, equals
the analytic Jacobians). Written by hand rather than taken from kornia/theseus because we need the (rho, phi)
order with left perturbations, plain tensors and batched Jacobians in one consistent place.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from codeslam.constants import SERIES_ANGLE, SMALL_ANGLE
from codeslam.geometry.quaternion import rotmat_to_quat_xyzw

# ---------------------------------------------------------------------------------------------------- so(3)


def hat(w: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) skew-symmetric matrix with ``hat(w) x = w x x``."""
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(w.shape + (3,))


def vee(W: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) skew-symmetric -> (..., 3), the inverse of :func:`hat` (uses the antisymmetric part)."""
    return 0.5 * torch.stack(
        [W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]], dim=-1
    )


def _angle(phi: torch.Tensor, threshold: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(..., 3) -> theta^2, series (bool: theta < threshold) and a safe theta (1 where series) for the closed
    forms, all (...). Evaluating the closed forms on the safe theta keeps autograd finite in the unused branch."""
    theta2 = (phi * phi).sum(-1)
    series = theta2 < threshold**2
    theta = torch.sqrt(torch.where(series, torch.ones_like(theta2), theta2))
    return theta2, series, theta


def _so3_coeffs(phi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(..., 3) -> A = sin(t)/t, B = (1 - cos t)/t^2, C = (t - sin t)/t^3, each (..., 1, 1)."""
    theta2, small, theta = _angle(phi, SMALL_ANGLE)
    half = torch.sin(0.5 * theta)
    A = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    B = torch.where(small, 0.5 - theta2 / 24.0, 2.0 * half * half / (theta * theta))  # 1 - cos = 2 sin^2(t/2)
    t2, series, t = _angle(phi, SERIES_ANGLE)
    C_series = 1 / 6 - t2 * (1 / 120 - t2 * (1 / 5040 - t2 * (1 / 362880 - t2 / 39916800)))
    C = torch.where(series, C_series, (t - torch.sin(t)) / (t * t * t))
    return A[..., None, None], B[..., None, None], C[..., None, None]


def _eye(like: torch.Tensor, n: int = 3) -> torch.Tensor:
    return torch.eye(n, dtype=like.dtype, device=like.device)


def so3_exp(phi: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula: (..., 3) rotation vector -> (..., 3, 3) rotation ``I + A phi^ + B phi^2``."""
    A, B, _ = _so3_coeffs(phi)
    W = hat(phi)
    return _eye(phi) + A * W + B * (W @ W)


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation -> (..., 3) rotation vector with angle in [0, pi].

    Goes through the unit quaternion (Shepperd's method, stable for every rotation), then
    ``phi = 2 atan2(|q_v|, q_w) q_v / |q_v|``, which stays accurate near 0 and near pi (where the
    trace/antisymmetric-part formula loses the axis).
    """
    q = rotmat_to_quat_xyzw(R)  # (..., 4), w >= 0
    qv, qw = q[..., :3], q[..., 3:]
    s2 = (qv * qv).sum(-1, keepdim=True)
    small = s2 < SMALL_ANGLE**2
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    # small: 2 atan(s/w)/s = (2/w)(1 - s^2/(3 w^2)) + O(s^4); qw ~ 1 there.
    w_safe = torch.where(small, qw, torch.ones_like(qw))
    scale = torch.where(small, 2.0 / w_safe * (1.0 - s2 / (3.0 * w_safe * w_safe)), 2.0 * torch.atan2(s, qw) / s)
    return scale * qv


def so3_left_jacobian(phi: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) left Jacobian ``J_l = I + B phi^ + C phi^2``: ``exp(phi + d) ~= exp(J_l d) exp(phi)``."""
    _, B, C = _so3_coeffs(phi)
    W = hat(phi)
    return _eye(phi) + B * W + C * (W @ W)


def so3_left_jacobian_inv(phi: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) ``J_l^-1 = I - phi^/2 + (1/t^2 - cot(t/2)/(2t)) phi^2`` (defined for t < 2 pi)."""
    t2, series, t = _angle(phi, SERIES_ANGLE)
    D_series = 1 / 12 + t2 * (1 / 720 + t2 * (1 / 30240 + t2 * (1 / 1209600 + t2 / 47900160)))
    D = torch.where(series, D_series, 1.0 / (t * t) - torch.cos(0.5 * t) / (2.0 * t * torch.sin(0.5 * t)))
    D = D[..., None, None]
    W = hat(phi)
    return _eye(phi) - 0.5 * W + D * (W @ W)


# ---------------------------------------------------------------------------------------------------- SE(3)


def _rt(T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(..., 4, 4) -> R (..., 3, 3), t (..., 3)."""
    return T[..., :3, :3], T[..., :3, 3]


def _batch_shape(a: torch.Size, b: torch.Size) -> torch.Size:
    """The broadcast of two batch shapes. Written out because ``torch.broadcast_shapes`` imports ``torch._refs`` on
    its first call (0.53 s of every command's start-up, measured) and takes 12 us a call; the SE(3) helpers run it
    a few dozen times per tracked frame."""
    if a == b:
        return a
    n = max(len(a), len(b))
    out = []
    for x, y in zip((1,) * (n - len(a)) + tuple(a), (1,) * (n - len(b)) + tuple(b)):
        if x != y and 1 not in (x, y):
            raise RuntimeError(f"shapes {tuple(a)} and {tuple(b)} do not broadcast")
        out.append(y if x == 1 else x)
    return torch.Size(out)


def se3_from_rt(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """R (..., 3, 3), t (..., 3) -> T (..., 4, 4); R and t broadcast against each other."""
    batch = _batch_shape(R.shape[:-2], t.shape[:-1])
    top = torch.cat([R.expand(batch + (3, 3)), t.expand(batch + (3,)).unsqueeze(-1)], dim=-1)  # (..., 3, 4)
    bottom = torch.zeros(batch + (1, 4), dtype=top.dtype, device=top.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """(..., 6) tangent ``(rho, phi)`` -> (..., 4, 4) transform ``[[exp(phi^), J_l(phi) rho], [0, 1]]``."""
    rho, phi = xi[..., :3], xi[..., 3:]
    A, B, C = _so3_coeffs(phi)
    W = hat(phi)
    W2 = W @ W
    R = _eye(xi) + A * W + B * W2
    V = _eye(xi) + B * W + C * W2  # = so3_left_jacobian(phi), sharing the coefficients
    return se3_from_rt(R, (V @ rho.unsqueeze(-1)).squeeze(-1))


def se3_exp_host(xi: torch.Tensor) -> torch.Tensor:
    """:func:`se3_exp` of ONE tangent vector (6,), evaluated on the host in float64 scalar arithmetic (the same
    closed forms, series and thresholds) and returned as a (4, 4) tensor of ``xi``'s dtype and device. For the
    retraction of a small solver, where ``se3_exp``'s ~60 tensor operations on six numbers cost about ten times
    more than this (one device-to-host copy of ``xi``, one host-to-device copy of the result)."""
    return torch.tensor(se3_exp_floats(xi.tolist()), dtype=xi.dtype, device=xi.device)


def se3_exp_floats(xi: Sequence[float]) -> list[list[float]]:
    """:func:`se3_exp_host`'s arithmetic on six Python floats ``(rho, phi)`` -> the 4x4 transform as rows of
    floats, for a solver that keeps its state on the host (:mod:`codeslam.slam.alignment`)."""
    r1, r2, r3, p1, p2, p3 = xi
    t2 = p1 * p1 + p2 * p2 + p3 * p3
    if t2 < SMALL_ANGLE**2:
        A, B = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        t = math.sqrt(t2)
        A, B = math.sin(t) / t, 2.0 * math.sin(0.5 * t) ** 2 / t2  # sin(t)/t, (1 - cos t)/t^2
    if t2 < SERIES_ANGLE**2:
        C = 1 / 6 - t2 * (1 / 120 - t2 * (1 / 5040 - t2 * (1 / 362880 - t2 / 39916800)))
    else:
        t = math.sqrt(t2)
        C = (t - math.sin(t)) / (t2 * t)  # (t - sin t)/t^3
    p, rho = (p1, p2, p3), (r1, r2, r3)
    W = ((0.0, -p3, p2), (p3, 0.0, -p1), (-p2, p1, 0.0))  # phi^
    W2 = [[p[i] * p[j] - (t2 if i == j else 0.0) for j in range(3)] for i in range(3)]  # phi^2 = phi phi^T - t^2 I
    R = [[float(i == j) + A * W[i][j] + B * W2[i][j] for j in range(3)] for i in range(3)]
    V = [[float(i == j) + B * W[i][j] + C * W2[i][j] for j in range(3)] for i in range(3)]  # J_l(phi)
    t_ = [V[i][0] * rho[0] + V[i][1] * rho[1] + V[i][2] * rho[2] for i in range(3)]
    return [[*R[i], t_[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def se3_log(T: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) transform -> (..., 6) tangent ``(rho, phi)`` with ``phi = log(R)``, ``rho = J_l(phi)^-1 t``."""
    R, t = _rt(T)
    phi = so3_log(R)
    rho = (so3_left_jacobian_inv(phi) @ t.unsqueeze(-1)).squeeze(-1)
    return torch.cat([rho, phi], dim=-1)


def so3_angle_host(R: torch.Tensor) -> float:
    """The rotation angle in radians, in [0, pi], of ONE rotation (3, 3): ``|so3_log(R)|`` in float64 scalar
    arithmetic on the host, for the per-frame checks of a tracker (so3_log's tensor operations on one matrix took
    0.36 ms a call, TUM fr1/rpy's tracker checks one per frame). ``atan2(|v|, tr(R) - 1)`` with ``v`` the vector
    of R's antisymmetric part: ``|v| = 2 sin t`` and ``tr(R) - 1 = 2 cos t``, so the angle stays accurate near 0
    (where acos of the trace would lose it) and near pi."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    return math.atan2(math.sqrt((r21 - r12) ** 2 + (r02 - r20) ** 2 + (r10 - r01) ** 2), r00 + r11 + r22 - 1.0)


def se3_log_host(T: torch.Tensor) -> torch.Tensor:
    """:func:`se3_log` of ONE transform (4, 4), evaluated on the host in float64 scalar arithmetic (the same
    quaternion route, series and thresholds) and returned as a (6,) tensor of ``T``'s dtype and device: for a
    prior on a pose inside a small solver, where ``se3_log``'s tensor operations on one 4x4 matrix cost more than
    the tracker's other work per iteration (a motion prior so written made tracking 40% slower, TUM fr1/rpy)."""
    return torch.tensor(se3_log_floats(T.tolist()), dtype=T.dtype, device=T.device)


def se3_log_floats(T: Sequence[Sequence[float]]) -> list[float]:
    """:func:`se3_log_host`'s arithmetic on a 4x4 transform given as rows of Python floats -> ``(rho, phi)`` as six
    floats, for a solver that keeps its state on the host (:mod:`codeslam.slam.alignment`)."""
    (r00, r01, r02, t0), (r10, r11, r12, t1), (r20, r21, r22, t2), _ = T
    tr = r00 + r11 + r22  # Shepperd's method: the quaternion from the largest of its four squared components
    if tr > 0.0:
        k = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * k, (r21 - r12) / k, (r02 - r20) / k, (r10 - r01) / k
    elif r00 > r11 and r00 > r22:
        k = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        w, x, y, z = (r21 - r12) / k, 0.25 * k, (r01 + r10) / k, (r02 + r20) / k
    elif r11 > r22:
        k = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        w, x, y, z = (r02 - r20) / k, (r01 + r10) / k, 0.25 * k, (r12 + r21) / k
    else:
        k = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        w, x, y, z = (r10 - r01) / k, (r02 + r20) / k, (r12 + r21) / k, 0.25 * k
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    w, x, y, z = w / n, x / n, y / n, z / n
    s2 = x * x + y * y + z * z
    if s2 < SMALL_ANGLE**2:
        scale = 2.0 / w * (1.0 - s2 / (3.0 * w * w))
    else:
        sn = math.sqrt(s2)
        scale = 2.0 * math.atan2(sn, w) / sn
    phi = (scale * x, scale * y, scale * z)
    a2 = phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2
    if a2 < SERIES_ANGLE**2:
        D = 1 / 12 + a2 * (1 / 720 + a2 * (1 / 30240 + a2 * (1 / 1209600 + a2 / 47900160)))
    else:
        a = math.sqrt(a2)
        D = 1.0 / a2 - math.cos(0.5 * a) / (2.0 * a * math.sin(0.5 * a))
    p1, p2, p3 = phi
    W = ((0.0, -p3, p2), (p3, 0.0, -p1), (-p2, p1, 0.0))
    W2 = [[phi[i] * phi[j] - (a2 if i == j else 0.0) for j in range(3)] for i in range(3)]
    Jinv = [[float(i == j) - 0.5 * W[i][j] + D * W2[i][j] for j in range(3)] for i in range(3)]  # J_l(phi)^-1
    t = (t0, t1, t2)
    rho = [Jinv[i][0] * t[0] + Jinv[i][1] * t[1] + Jinv[i][2] * t[2] for i in range(3)]
    return [*rho, *phi]


def se3_inverse(T: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) -> (..., 4, 4) ``[[R^T, -R^T t], [0, 1]]``."""
    R, t = _rt(T)
    Rt = R.transpose(-1, -2)
    return se3_from_rt(Rt, -(Rt @ t.unsqueeze(-1)).squeeze(-1))


def se3_compose(T_ab: torch.Tensor, T_bc: torch.Tensor) -> torch.Tensor:
    """T_ab (..., 4, 4), T_bc (..., 4, 4) -> T_ac = T_ab T_bc (batch dims broadcast)."""
    return T_ab @ T_bc


def _split_points(T: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Size]:
    """Match T's batch dims to p's leading dims. T (*b, 4, 4), p (*b', *P, 3) with len(b') = len(b) ->
    R (*B, 3, 3), t (*B, 3), p (*B, M, 3) with B = broadcast(b, b'), M = prod(P), and the output shape."""
    nb = T.dim() - 2
    if p.dim() - 1 < nb:
        raise ValueError(f"points {tuple(p.shape)} have fewer leading dims than the transforms {tuple(T.shape)}")
    batch = _batch_shape(T.shape[:-2], p.shape[:nb])
    pts = p.shape[nb:-1]
    R, t = _rt(T)
    p_flat = p.expand(batch + pts + (3,)).reshape(batch + (-1, 3))  # (*B, M, 3)
    return R.expand(batch + (3, 3)), t.expand(batch + (3,)), p_flat, batch + pts


def so3_act(R: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Rotate points: R (*B, 3, 3), p (*B, M, 3) -> (*B, M, 3) ``R p`` for every point, formed as ``(R P^T)^T`` with
    P the (M, 3) points. Written for a measured reason: torch's CPU bmm of (M, 3) by (3, 3), ``p @ R^T``, took 1.19 ms
    for 6 x 12,288 points against 0.34 ms this way (2 threads, AMD Zen 3), with the same values."""
    return (R @ p.transpose(-1, -2)).transpose(-1, -2)


def se3_act(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Transform points: ``T p = R p + t``.

    Broadcasting: T (*b, 4, 4) and p (*b, *P, 3): T's batch dims are matched (torch-broadcast) against the
    LEADING dims of p, and any further dims P of p are points sharing that transform. So T (4, 4) with p (N, 3),
    T (B, 4, 4) with p (B, 3) (one point per transform) and T (B, 4, 4) with p (B, N, 3) or (B, H, W, 3) all
    work. Returns (*b, *P, 3).
    """
    R, t, p_flat, out_shape = _split_points(T, p)
    out = so3_act(R, p_flat) + t.unsqueeze(-2)  # (*B, M, 3)
    return out.reshape(out_shape + (3,))


def se3_act_jac_point(T: torch.Tensor) -> torch.Tensor:
    """d (T p) / d p = R: (..., 4, 4) -> (..., 3, 3)."""
    return T[..., :3, :3]


def se3_act_jac_pose(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """LEFT perturbation: d (exp(xi) T p) / d xi at xi = 0 = ``[I, -(T p)^]``. Shapes as :func:`se3_act`;
    returns (*b, *P, 3, 6). (The paper's Eqs. 7-8 perturb R and t separately, R <- exp(phi) R, t <- t + rho,
    which gives ``[I, -(R p)^]``; the two differ only by the parametrisation of the increment.)"""
    x = se3_act(T, p)  # (*b, *P, 3)
    eye = _eye(x).expand(x.shape + (3,))
    return torch.cat([eye, -hat(x)], dim=-1)


def se3_act_jac_pose_right(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """RIGHT perturbation: d (T exp(xi) p) / d xi at xi = 0 = ``[R, -R p^]``. Shapes as :func:`se3_act`;
    returns (*b, *P, 3, 6)."""
    R, _, p_flat, out_shape = _split_points(T, p)
    R_ = R.unsqueeze(-3)  # (*B, 1, 3, 3) against the M points
    J = torch.cat([R_.expand(p_flat.shape + (3,)), -(R_ @ hat(p_flat))], dim=-1)  # (*B, M, 3, 6)
    return J.reshape(out_shape + (3, 6))


def se3_adjoint(T: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) -> (..., 6, 6) ``Ad_T = [[R, t^ R], [0, R]]`` for the (rho, phi) order:
    ``T exp(xi) T^-1 = exp(Ad_T xi)``."""
    R, t = _rt(T)
    top = torch.cat([R, hat(t) @ R], dim=-1)  # (..., 3, 6)
    bottom = torch.cat([torch.zeros_like(R), R], dim=-1)  # (..., 3, 6)
    return torch.cat([top, bottom], dim=-2)
