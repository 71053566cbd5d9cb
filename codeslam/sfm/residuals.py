"""Photometric and geometric residuals of frame pairs (paper Sec. 4.1), their loss functions and their analytic
Jacobians, vectorised over pixels and batched over pairs.

For a pair (A, B) and every pixel u of A, with ``v = w(u, c_A, T_BA)`` and ``x`` the point in B (Sec. 3):

* photometric (Eq. 13 with the per-pair affine brightness of Sec. 5.2): ``r_pho = I_A[u] - (exp(a) I_B[v] + b)``;
* geometric (Eq. 14): ``r_geo = f(x_z) - f(D_B[v])``, the depth of the warped point in B against B's decoded
  depth at v, both mapped by ``f`` (``SfMConfig.geometric_space``): ``f = log`` by default, or ``f = prox``
  (p = a / (d + a)). The paper writes the plain depth difference; any such difference changes when every depth
  and translation is scaled together, which the photometric term cannot see, so the geometric term alone would
  pull the scene's scale -- towards zero for depth, towards larger depths beyond ``a`` for proximity -- and only
  the code prior would hold it. The log-depth difference is the one scale-free choice: the scale stays where the
  network's prior puts it. Measured when it became the default: equal on generator rooms, better on 3 of 4
  HoloLens masters, demo SLAM ATE 0.026 -> 0.022 m (Sim(3) scale 1.14 -> 1.10).

Loss functions (Sec. 4.1): (i) invalid correspondences (outside B with ``border``, behind B, invalid depth of A,
and for the geometric term a lookup touching a hole of B's proximity) are masked and priced at the Huber
threshold so that pushing pixels out of view does not lower the cost; (ii) the
residuals are divided by their sigma (``sigma_photometric`` / ``sigma_geometric``, optionally widened by the
network's b); (iii) Huber on the normalised residual, applied as iteratively re-weighted least squares;
(iv) residuals of pixels whose surface in A is strongly slanted to the viewing ray are down-weighted;
(v) photometric residuals of pixels whose warped point lies clearly behind B's decoded surface are down-weighted
(the geometric ones too with ``occlusion_geometric``, see :class:`~codeslam.sfm.config.SfMConfig`).
The weights of (iv) and (v) and the masks are evaluated at the current state and held fixed in the Jacobians.

Jacobians are returned in compact form (:class:`PairTerms`): per pixel and residual type a row w.r.t. the
relative pose (6) and the affine parameters (2), a scalar ``s_A`` with ``d r / d c_A = s_A J_A[u]`` and a scalar
``s_B`` with ``d r / d c_B = s_B J_B[v]``; :mod:`codeslam.sfm.normal_equations` turns them into the normal
equations without ever forming the dense Jacobian.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from codeslam.constants import BILINEAR_ALL_VALID, MIN_DEPTH
from codeslam.geometry.camera import project_jac
from codeslam.geometry.image import bilinear_sample, image_gradients, inside_image, slant_cosine
from codeslam.geometry.lie import so3_act
from codeslam.geometry.proximity import d_depth_d_prox, d_prox_d_depth, depth_to_prox, prox_to_depth
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import LevelData
from codeslam.sfm.variables import AFFINE_DIM, POSE_DIM, RS_DIM
from codeslam.sfm.warp import pose_columns, relative_pose, rolling_shutter_rows, warp, warp_rolling_shutter

PHOTOMETRIC, GEOMETRIC = "photometric", "geometric"


@dataclass
class PairEvaluation:
    """Residuals of P pairs with T residual types over N pixels, and what their Jacobians reuse.

    r, valid, sigma, fixed_weight: (P, T, N); huber: (T,) thresholds in sigmas. The rest (P, N, ...) are the
    warp's intermediates: T_BA (P, 4, 4), x_B (P, N, 3), ray_A (P, N, 3), dd_dprox_A (P, N) = d D_A / d P_A at u,
    gain (P, 1) = exp(a), gray_B (P, N) = I_B[v], grad_gray_B / grad_prox_B (P, N, 2) (None unless requested),
    dgeo_dz (P, N) = d f(x_z) / d x_z, dgeo_dprox_B (P, N) = d f(D_B(P_B)) / d P_B at v (f: the geometric
    residual's space), v (P, N, 2). row_cost (P, T, N): each valid row's robust cost (0 where masked), set by
    :func:`robust_weights`, which :func:`common_cost_change` compares between two evaluations; cost (P,): the
    pairs' robust cost as the solver priced it (:meth:`~codeslam.sfm.solver.PairProblem.evaluate`).
    geo_pose_scale (P, N): the factor on the geometric rows' pose derivatives (:func:`blank_view_scale` per pair,
    :func:`blank_region_scale` per cell), None for 1.
    """

    types: tuple[str, ...]
    r: torch.Tensor
    valid: torch.Tensor
    sigma: torch.Tensor
    fixed_weight: torch.Tensor
    huber: torch.Tensor
    T_BA: torch.Tensor
    x_B: torch.Tensor
    ray_A: torch.Tensor
    dd_dprox_A: torch.Tensor
    gain: torch.Tensor
    gray_B: torch.Tensor
    grad_gray_B: torch.Tensor | None
    grad_prox_B: torch.Tensor | None
    dgeo_dz: torch.Tensor
    dgeo_dprox_B: torch.Tensor
    v: torch.Tensor
    rs: RollingShutterWarp | None = None
    row_cost: torch.Tensor | None = None
    cost: torch.Tensor | None = None
    geo_pose_scale: torch.Tensor | None = None


@dataclass
class RollingShutterWarp:
    """What the rolling-shutter rows of :func:`pair_jacobians` reuse (see
    :func:`~codeslam.sfm.warp.warp_rolling_shutter`): x_c (P, N, 3) the point in B's mid-readout frame, ray0
    (P, N, 3) A's unrotated ray, depth_A (P, N), omega_B (P, 1, 3), s_A, s_B (P, N) readout fractions."""

    x_c: torch.Tensor
    ray0: torch.Tensor
    depth_A: torch.Tensor
    omega_B: torch.Tensor
    s_A: torch.Tensor
    s_B: torch.Tensor


@dataclass
class PairTerms:
    """Weighted residuals and compact Jacobians of P pairs, T types, N pixels (rows are zero where masked).

    r, w: (P, T, N) residuals and IRLS weights (``fixed * huber / sigma^2``, 0 where masked); cost: (P,) robust
    cost of each pair. J_local (P, L, T, N): the derivatives by the pair's local variables, L = 8 columns
    ``[xi_BA, a, b]`` or, with the rolling-shutter model, 14 ``[xi_BA, a, b, omega_A, omega_B]``, stored column by
    column (a column's pixels contiguous: the weighting and the sums over types in
    :func:`~codeslam.sfm.normal_equations.assemble` then run along whole rows; see :func:`pair_jacobians`); its
    views J_rel (P, T, N, 6) d r / d xi_BA (left perturbation of T_BA), J_aff (P, T, N, 2) d r / d (a, b) and J_rs
    (P, T, N, 6) d r / d (omega_A, omega_B), the readout rotations (None without that model).
    s_A (P, T, N): d r / d c_A = s_A J_A[u]. s_B (P, T, N): d r / d c_B = s_B JB_w^T.
    JB_w: per pair a (C, M_p) J_B sampled at v at the pixels ``JB_idx[p]`` (M_p,) where the geometric residual has
    weight (elsewhere its code-B row is zero: masked or zero-weight pixels, a third of them in a SLAM window, cost
    nothing in the C x N x C products of :func:`~codeslam.sfm.normal_equations.assemble`); both None without
    geometric residuals or when no code of B is free.
    """

    types: tuple[str, ...]
    r: torch.Tensor
    w: torch.Tensor
    cost: torch.Tensor
    J_local: torch.Tensor
    s_A: torch.Tensor
    s_B: torch.Tensor
    JB_w: list[torch.Tensor] | None
    JB_idx: list[torch.Tensor] | None = None

    @property
    def J_rows(self) -> torch.Tensor:
        """(P, T, N, L): J_local as one row per residual (a view)."""
        return self.J_local.permute(0, 2, 3, 1)

    @property
    def J_rel(self) -> torch.Tensor:
        return self.J_rows[..., :POSE_DIM]

    @property
    def J_aff(self) -> torch.Tensor:
        return self.J_rows[..., POSE_DIM:POSE_DIM + AFFINE_DIM]

    @property
    def J_rs(self) -> torch.Tensor | None:
        return self.J_rows[..., POSE_DIM + AFFINE_DIM:] if self.J_local.shape[1] > POSE_DIM + AFFINE_DIM else None


def interpolant_gradient(img: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Exact derivative of the bilinear interpolant of ``img`` (what autograd through
    :func:`~codeslam.geometry.image.bilinear_sample` gives): img (B, C, H, W), uv (B, N, 2) -> (B, C, 2, N).

    Inside the cell [u0, u0 + 1] with u0 = floor(u) the interpolant is linear in u, so d/du is the forward
    difference ``I[., u0 + 1] - I[., u0]`` interpolated linearly in v (and likewise d/dv). Written by hand
    because neither torch nor kornia returns the slope of a bilinear lookup.
    """
    H, W = img.shape[-2:]
    du = img[..., :, 1:] - img[..., :, :-1]  # (B, C, H, W - 1), forward difference along u
    dv = img[..., 1:, :] - img[..., :-1, :]  # (B, C, H - 1, W)
    u, v = uv.unbind(-1)  # (B, N) each
    u0 = torch.floor(u).clamp(0, W - 2)
    v0 = torch.floor(v).clamp(0, H - 2)
    gu, _ = bilinear_sample(du, torch.stack([u0, v], dim=-1))  # (B, C, N)
    gv, _ = bilinear_sample(dv, torch.stack([u, v0], dim=-1))
    return torch.stack([gu, gv], dim=2)


def sample_by_frame(img: torch.Tensor, frame_of: list[int], uv: list[torch.Tensor]) -> list[torch.Tensor]:
    """Bilinear lookup of many-channel frame images without copying them per pair: img (F, C, H, W), frame_of
    (P,) frame index of each pair, uv P point sets (N_p, 2) -> P views (C, N_p). The values of
    :func:`~codeslam.geometry.image.bilinear_sample` (zeros outside the image), up to rounding.

    Written by hand for a measured reason: a lookup is a weighted sum of four pixel rows of the channels-last
    images, which one ``embedding_bag`` forms for every pair's points at once, each point's C values read from
    four contiguous rows. ``grid_sample``'s CPU kernel walks the C channel planes of every point, parallelises
    over the batch only and needs one call per frame. Measured on the SfM benchmark's 4-frame problem (6 pairs,
    C = 64, 2 threads, medians of 7 alternating rounds in one process): 6.0 -> 3.8 ms at 128x96 (59,000
    lookups), 2.0 -> 1.2 ms at 64x48, 0.54 -> 0.56 ms at 32x24. Every point's row is summed by one thread in a
    fixed order, so the values do not depend on the thread count."""
    if not uv:
        return []
    F_, C, H, W = img.shape
    rows = img.permute(0, 2, 3, 1).reshape(F_ * H * W, C)  # a view when img is channels-last
    sizes = [p.shape[0] for p in uv]
    pts = torch.cat(uv).to(img.dtype)  # (n, 2)
    first = torch.repeat_interleave(torch.tensor(frame_of, device=img.device) * (H * W),
                                    torch.tensor(sizes, device=img.device))  # (n,) the first row of each frame
    u, v = pts.unbind(-1)  # (n,) each. The four neighbours from 1-D vectors: the (n, 2, 2) broadcasts over
    u0, v0 = u.floor(), v.floor()  # corners took 8 of 16 ms of a 12-pair 128x96 lookup (2 threads); same values
    u1, v1 = u0 + 1, v0 + 1
    fu, fv = u - u0, v - v0
    wu0, wu1 = (1 - fu) * ((u0 >= 0) & (u0 <= W - 1)), fu * ((u1 >= 0) & (u1 <= W - 1))  # outside adds zero
    wv0, wv1 = (1 - fv) * ((v0 >= 0) & (v0 <= H - 1)), fv * ((v1 >= 0) & (v1 <= H - 1))
    cu0, cu1 = u0.clamp(0, W - 1).long(), u1.clamp(0, W - 1).long()
    rv0, rv1 = v0.clamp(0, H - 1).long() * W + first, v1.clamp(0, H - 1).long() * W + first
    index = torch.stack([rv0 + cu0, rv0 + cu1, rv1 + cu0, rv1 + cu1], dim=1)  # (n, 4) v-major
    weight = torch.stack([wv0 * wu0, wv0 * wu1, wv1 * wu0, wv1 * wu1], dim=1)
    vals = torch.nn.functional.embedding_bag(index, rows, per_sample_weights=weight, mode="sum")  # (n, C)
    return [part.T for part in vals.split(sizes, dim=0)]  # (C, N_p) views


def huber_cost_and_weight(s: torch.Tensor, k: torch.Tensor | float) -> tuple[torch.Tensor, torch.Tensor]:
    """Huber function of normalised residuals s (...) with threshold k: cost ``rho(s)`` (0.5 s^2 inside,
    ``k |s| - 0.5 k^2`` outside) and IRLS weight ``rho'(s) / s`` (1 inside, ``k / |s|`` outside). Loss (iii)."""
    a = s.abs()
    a_k = torch.clamp(a, max=k)  # min(|s|, k): the same rounding as each branch, without two torch.where
    cost = a_k * a - 0.5 * a_k * a_k  # 0.5 s^2 inside, k |s| - 0.5 k^2 outside
    weight = (k / a).clamp(max=1.0)  # 1 inside (also at s = 0, where k / 0 = inf), k / |s| outside
    return cost, weight


def slant_weight(depth: torch.Tensor, params: torch.Tensor, cos_min: float) -> torch.Tensor:
    """Loss (iv): depth (F, 1, H, W), params (F, 4) -> (F, 1, H, W) weight ``min(1, cos / cos_min)`` where cos is
    the angle between the surface normal (from the decoded depth) and the viewing ray
    (:func:`~codeslam.geometry.image.slant_cosine`)."""
    return (slant_cosine(depth, params) / cos_min).clamp(max=1.0)


def evaluate_pairs(
    level: LevelData,
    pairs: torch.Tensor,
    poses: torch.Tensor,
    codes: torch.Tensor,
    affine: torch.Tensor | None,
    cfg: SfMConfig,
    with_gradients: bool = True,
    sampler: Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]] = bilinear_sample,
    rs: torch.Tensor | None = None,
    weights: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> PairEvaluation:
    """Residuals of every pair (differentiable in poses, codes and affine; masks and weights are detached).

    level: the stacked keyframes; pairs (P, 2) long (A, B) frame indices; poses (F, 4, 4) T_wc; codes (F, C);
    affine (P, 2) (log-gain, bias) or None for no brightness correction. ``with_gradients`` also samples the
    image/proximity gradients of B at v (needed by :func:`pair_jacobians`). ``sampler`` is the bilinear lookup
    (img (B, C, H, W), uv (B, N, 2)) -> (values (B, C, N), valid), by default
    :func:`~codeslam.geometry.image.bilinear_sample`. ``rs`` (F, 3): every frame's rotation over its readout, for
    the rolling-shutter warp (:func:`~codeslam.sfm.warp.warp_rolling_shutter`); None for global shutters.
    ``weights``: the fixed weights and sigmas (P, T, N) of an earlier evaluation to use instead of computing them
    (:attr:`SfMConfig.weights_per_level`; the slant weight's normals are then not formed).
    """
    types = cfg.residual_types
    P = pairs.shape[0]
    H, W = level.height, level.width
    iA, iB = pairs[:, 0], pairs[:, 1]
    prox = level.prox(codes)  # (F, 1, H, W), prox0 + J c
    a = level.avg_depth_at(codes)  # (F,)
    depth = prox_to_depth(prox, a[:, None, None, None])  # (F, 1, H, W), Eq. 4 inverted
    T_BA = relative_pose(poses[iA], poses[iB])  # (P, 4, 4)
    d_A = depth[iA].reshape(P, -1)  # (P, N), D_A[u]
    prox_A = prox[iA].reshape(P, -1)
    uv = level.uv.expand(P, -1, -1)  # (P, N, 2)
    rs_warp = None
    if rs is None:
        v, x_B, ray_A = warp(uv, d_A, T_BA, level.params[iA][:, None], level.params[iB][:, None])  # Eq. 5
    else:
        omega_A, omega_B = rs[iA][:, None].to(prox.dtype), rs[iB][:, None].to(prox.dtype)  # (P, 1, 3)
        v, x_B, x_c, ray_A, ray0, s_A, s_B = warp_rolling_shutter(
            uv, d_A, T_BA, level.params[iA][:, None], level.params[iB][:, None], omega_A, omega_B, H)
        rs_warp = RollingShutterWarp(x_c, ray0, d_A, omega_B, s_A, s_B)
    z = x_B[..., 2]

    # (i) masks: inside B (minus the border), in front of B, valid depth of A.
    valid = (
        inside_image(v, H, W, margin=-cfg.border) & (z > MIN_DEPTH) & (d_A > 0) & torch.isfinite(v).all(-1)
    ).detach()
    v_safe = torch.where(valid[..., None], v, torch.zeros_like(v))  # keeps NaN/inf out of the lookups

    # One lookup for every channel of B: grey, proximity, proximity validity, [Sobel gradients], [uncertainty].
    prox_ok = (torch.isfinite(prox) & (prox != 0)).to(prox.dtype).detach()  # 0 = invalid sentinel (holes)
    gray_ok = torch.ones_like(prox_ok) if level.gray_valid is None else level.gray_valid  # real image pixels
    chans = [level.gray, prox, prox_ok, gray_ok]
    sobel = with_gradients and cfg.gradient_mode == "sobel"
    if sobel:
        chans += [level.gray_grad[:, 0], image_gradients(prox)[:, 0]]  # (F, 2, H, W) each
    if cfg.use_uncertainty and level.uncertainty is not None:
        chans.append(level.uncertainty)
    stack = torch.cat(chans, dim=1)[iB]  # (P, ch, H, W)
    sampled, _ = sampler(stack, v_safe)  # (P, ch, N), the paper's square brackets at v
    gray_B, prox_B = sampled[:, 0], sampled[:, 1]
    grad_gray_B = grad_prox_B = None
    if sobel:
        grad_gray_B = sampled[:, 4:6].transpose(1, 2)  # (P, N, 2)
        grad_prox_B = sampled[:, 6:8].transpose(1, 2)
    elif with_gradients:
        g = interpolant_gradient(torch.cat([level.gray, prox], dim=1)[iB], v_safe)  # (P, 2, 2, N)
        grad_gray_B, grad_prox_B = g[:, 0].transpose(1, 2), g[:, 1].transpose(1, 2)

    if affine is None:
        log_gain = torch.zeros(P, 1, dtype=prox.dtype, device=prox.device)
        bias = torch.zeros_like(log_gain)
    else:
        log_gain, bias = affine[:, :1], affine[:, 1:]
    gain = torch.exp(log_gain)  # (P, 1)
    a_B = a[iB][:, None]  # (P, 1)
    z_safe = torch.where(valid, z, torch.ones_like(z))
    depth_B = prox_to_depth(prox_B, a_B)  # B's decoded depth at v (0 where B has no depth)
    depth_B_at_v = depth_B.detach()
    if cfg.geometric_space == "log_depth":
        depth_B_safe = torch.where(depth_B_at_v > 0, depth_B, torch.ones_like(depth_B))
        geo_x, geo_B = torch.log(z_safe), torch.log(depth_B_safe)
        dgeo_dz = 1.0 / z_safe
        dgeo_dprox_B = d_depth_d_prox(prox_B, a_B) / depth_B_safe  # d log D / d P = (dD/dP) / D
    else:
        geo_x, geo_B = depth_to_prox(z_safe, a_B), prox_B  # proximity of the warped point's depth (Eq. 4)
        dgeo_dz = d_prox_d_depth(z_safe, a_B)
        dgeo_dprox_B = torch.ones_like(prox_B)

    rs, sigmas, fixed, valids, hubers = [], [], [], [], []
    ones = torch.ones_like(d_A)
    prox_B_ok = sampled[:, 2].detach() > BILINEAR_ALL_VALID  # all four bilinear neighbours of B's proximity valid
    if weights is None:
        w_slant = slant_weight(depth.detach(), level.params, cfg.slant_cos_min)[iA].reshape(P, -1)  # (iv)
        occluded = (z > depth_B_at_v * (1.0 + cfg.occlusion_margin)) & prox_B_ok  # (v): behind B's surface
        w_occ = torch.where(occluded.detach(), cfg.occlusion_weight * ones, ones)
    for t in types:
        if t == PHOTOMETRIC:
            gray_A = level.gray[iA]  # (P, 1, H, W), also the blank-view gate's below
            r = gray_A.reshape(P, -1) - (gain * gray_B + bias)  # Eq. 13 with affine brightness (Sec. 5.2)
            if weights is None:
                fixed.append(w_slant * w_occ)
                sigmas.append(cfg.sigma_photometric * ones)
            # (i): only real image pixels, at u in A and in all four bilinear neighbours of v in B.
            gray_A_ok = gray_ok[iA].reshape(P, -1) > 0.5
            valids.append(valid & gray_A_ok & (sampled[:, 3].detach() > BILINEAR_ALL_VALID))
            hubers.append(cfg.huber_photometric)
        else:
            r = geo_x - geo_B  # Eq. 14 in the space f (log depth or proximity)
            valid_geo = valid & prox_B_ok  # no lookup mixing B's proximity with holes (loss (i))
            stride = max(1, cfg.geometric_stride >> level.level)
            if stride > 1:  # a grid of every stride-th pixel, each standing for stride^2 (SfMConfig)
                n = torch.arange(H * W, device=prox.device)
                valid_geo = valid_geo & ((n // W) % stride == 0) & ((n % W) % stride == 0)
            if weights is None:
                sig2 = cfg.sigma_geometric**2 * ones
                if cfg.use_uncertainty and level.uncertainty is not None:
                    # Laplace b (proximity units): variance 2 b^2 per view, carried into f's units at first order.
                    b_A = level.uncertainty[iA].reshape(P, -1)
                    b_B = sampled[:, -1]
                    if cfg.geometric_space == "log_depth":
                        d_A_safe = torch.where(d_A > 0, d_A, torch.ones_like(d_A))
                        b_A = b_A * d_depth_d_prox(prox_A, a[iA][:, None]).abs() / d_A_safe
                        b_B = b_B * dgeo_dprox_B.abs()
                    sig2 = sig2 + 2.0 * b_A**2 + 2.0 * b_B**2
                sigmas.append(sig2.sqrt().detach())
                occ_w = w_slant * w_occ if cfg.occlusion_geometric else w_slant
                fixed.append(occ_w * float(stride * stride) if stride > 1 else occ_w)
            valids.append(valid_geo)
            hubers.append(cfg.huber_geometric)
        rs.append(r)
    valid_t = torch.stack(valids, dim=1)  # (P, T, N)
    r_t = torch.where(valid_t, torch.stack(rs, dim=1), torch.zeros((), dtype=prox.dtype, device=prox.device))
    geo_pose_scale = None
    if cfg.geometric_pose_min_std > 0 and cfg.photometric and cfg.geometric:
        seen = valids[types.index(PHOTOMETRIC)]  # A's pixels the photometric term compares with B
        if cfg.geometric_pose_regions > 1:
            geo_pose_scale = blank_region_scale(gray_A[:, 0], seen.reshape(P, *gray_A.shape[-2:]),
                                                cfg.geometric_pose_min_std, cfg.geometric_pose_regions)
        else:  # one factor per pair, on each of its pixels
            geo_pose_scale = blank_view_scale(gray_A.reshape(P, -1), seen, cfg.geometric_pose_min_std)
            geo_pose_scale = geo_pose_scale[:, None].expand(-1, seen.shape[1])
    return PairEvaluation(
        types=types,
        r=r_t,
        valid=valid_t,
        sigma=torch.stack(sigmas, dim=1) if weights is None else weights[1],
        fixed_weight=torch.stack(fixed, dim=1).detach() if weights is None else weights[0],
        huber=torch.tensor(hubers, dtype=prox.dtype, device=prox.device),
        T_BA=T_BA,
        x_B=x_B,
        ray_A=ray_A,
        dd_dprox_A=d_depth_d_prox(prox_A, a[iA][:, None]),
        gain=gain,
        gray_B=gray_B,
        grad_gray_B=grad_gray_B,
        grad_prox_B=grad_prox_B,
        dgeo_dz=dgeo_dz,
        dgeo_dprox_B=dgeo_dprox_B,
        v=v_safe,
        rs=rs_warp,
        geo_pose_scale=geo_pose_scale,
    )


def blank_view_scale(gray_A: torch.Tensor, seen: torch.Tensor, min_std: float) -> torch.Tensor:
    """(P,) ``min(1, std / min_std)^2`` with ``std`` the standard deviation of each pair's ``gray_A`` (P, N) over its
    pixels ``seen`` (P, N) bool (0 where none): how far the geometric residuals may move a pair's poses
    (:attr:`~codeslam.sfm.config.SfMConfig.geometric_pose_min_std`)."""
    m = seen.to(gray_A.dtype)
    count = m.sum(1).clamp_min(1.0)
    mean = (gray_A * m).sum(1) / count
    std = (((gray_A - mean[:, None]) ** 2 * m).sum(1) / count).sqrt()
    return (std / min_std).clamp(max=1.0).square().detach()


def blank_region_scale(gray_A: torch.Tensor, seen: torch.Tensor, min_std: float, regions: int) -> torch.Tensor:
    """(P, N) the factor of :func:`blank_view_scale` per pixel, with the standard deviation of ``gray_A``
    (P, H, W) taken over the pixels ``seen`` (P, H, W) bool of the pixel's cell: the image cut into ``regions``
    cells a side (the last row and column of cells smaller where the size does not divide;
    :attr:`~codeslam.sfm.config.SfMConfig.geometric_pose_regions`)."""
    P, H, W = gray_A.shape
    kh, kw = -(-H // regions), -(-W // regions)

    def cell_sums(x: torch.Tensor) -> torch.Tensor:  # (P, H, W) -> (P, cells_y, cells_x)
        return F.avg_pool2d(x[:, None], (kh, kw), ceil_mode=True, divisor_override=1)[:, 0]

    def per_pixel(x: torch.Tensor) -> torch.Tensor:  # (P, cells_y, cells_x) -> (P, H, W)
        return x.repeat_interleave(kh, dim=1).repeat_interleave(kw, dim=2)[:, :H, :W]

    m = seen.to(gray_A.dtype)
    count = cell_sums(m).clamp_min(1.0)
    mean = per_pixel(cell_sums(gray_A * m) / count)
    std = (cell_sums((gray_A - mean) ** 2 * m) / count).sqrt()
    return per_pixel((std / min_std).clamp(max=1.0).square()).reshape(P, H * W).detach()


def robust_weights(ev: PairEvaluation, masked_rows: str = "threshold") -> tuple[torch.Tensor, torch.Tensor]:
    """-> IRLS weights (P, T, N) ``fixed * rho'(s)/s / sigma^2`` (0 where masked) and the robust cost (P,): per
    pair ``sum fixed * rho(r / sigma)`` over the valid rows plus, per masked row (loss (i); ``masked_rows``, as
    :attr:`SfMConfig.masked_rows`), ``rho(k) = k^2 / 2`` ('threshold') or the mean of its type's valid rows
    ('common', :func:`masked_mean_cost`). Sets ``ev.row_cost``."""
    k = ev.huber[None, :, None]  # (1, T, 1)
    rho, irls = huber_cost_and_weight(ev.r / ev.sigma, k)
    zero = torch.zeros((), dtype=ev.r.dtype, device=ev.r.device)
    w = torch.where(ev.valid, ev.fixed_weight * irls / ev.sigma**2, zero)
    ev.row_cost = torch.where(ev.valid, ev.fixed_weight * rho, zero)
    if masked_rows == "threshold":
        return w, torch.where(ev.valid, ev.row_cost, 0.5 * k * k).sum(dim=(1, 2))
    return w, pair_cost(ev)


def masked_mean_cost(cost_valid: torch.Tensor, n_valid: torch.Tensor, n: int, k: torch.Tensor) -> torch.Tensor:
    """Loss (i) in the cost: ``cost_valid`` (...) summed over the ``n_valid`` (...) valid of ``n`` rows -> the
    cost of all ``n`` rows, a masked row priced at the valid rows' mean (``rho(k) = k^2 / 2``, the Huber
    threshold, where none is valid).

    The rows a pose leaves inside the image change with the pose, so a masked row must have a price, and a fixed
    one makes the cost count pixels: priced at ``rho(k)`` (``masked_rows: threshold``), a step that moves keyframe
    pixels out of view raises the cost by ``rho(k)`` each whatever the images say, and where the residuals are
    near zero (a blank wall, the dataset's depth) Levenberg-Marquardt rejected every step towards the true pose
    of a turning camera: on the generator's fast turn (seed 14, frame 92 against keyframe 91) the alignment
    stayed at the motion model's prediction, 1.1 deg from the truth, whose cost was higher by the pixels it
    rotated out of view (``docs/results/slam_table.md``, session of 2026-11-29). Priced at the mean, the cost is
    ``n`` times the mean over the valid rows, the quantity DSO's coarse tracker compares to accept a step (its
    energy over its number of terms), and no longer counts pixels. A mean still moves when a row with a cost
    above it leaves the view, so a step is accepted on :func:`common_cost_change` instead."""
    n_valid = n_valid.to(cost_valid.dtype)
    return torch.where(n_valid > 0, cost_valid * (n / n_valid.clamp(min=1.0)), 0.5 * k * k * n)


def pair_cost(ev: PairEvaluation) -> torch.Tensor:
    """Each pair's robust cost (P,) with masked rows at the valid rows' mean (:func:`masked_mean_cost`), from an
    evaluation whose ``row_cost`` is set (:func:`robust_weights`)."""
    N = ev.r.shape[2]
    return masked_mean_cost(ev.row_cost.sum(dim=2), ev.valid.sum(dim=2), N, ev.huber[None, :]).sum(dim=1)


def common_cost_change(old_rows: torch.Tensor, old_valid: torch.Tensor, new_rows: torch.Tensor,
                       new_valid: torch.Tensor) -> torch.Tensor:
    """The change of the robust cost between two evaluations of the same rows, over the rows valid in both
    (``*_rows``: each row's cost, 0 where masked; ``*_valid`` its mask): what Levenberg-Marquardt accepts a step
    on (:func:`~codeslam.sfm.solver.levenberg_marquardt`).

    Whatever price a masked row has, comparing two states over different sets of rows judges the sets as well
    as the states: at the Huber threshold's price steps that turned pixels out of view were rejected although
    they lowered every residual (the blank wall of :func:`masked_mean_cost`); at the valid rows' mean alone,
    steps that moved rows costlier than the mean out of view would be accepted for it. Over the rows both see,
    pixels that leave or enter the view move neither side."""
    both = old_valid & new_valid
    return torch.where(both, new_rows - old_rows, torch.zeros((), dtype=new_rows.dtype, device=new_rows.device)).sum()


def step_cost_change(masked_rows: str, old, new, old_cost: float, new_cost: float) -> float:
    """What a step changed a problem's cost by, the change Levenberg-Marquardt accepts a step on, from the
    evaluations before and after it (``old``, ``new``: each with the data term's ``cost``, its ``row_cost`` and
    ``valid``, as :class:`PairEvaluation` and the tracker's alignment evaluation carry them) and the problem's
    whole costs: ``new_cost - old_cost`` with ``masked_rows`` 'threshold'; with 'common' the data term's change
    over the rows valid in both (:func:`common_cost_change`) plus the other terms' (priors') change."""
    if masked_rows == "threshold":
        return new_cost - old_cost
    others = (new_cost - float(new.cost.sum())) - (old_cost - float(old.cost.sum()))
    return others + float(common_cost_change(old.row_cost, old.valid, new.row_cost, new.valid))


def _row_times(a: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """(P, 2, N) rows times (P, 2, 3, N) matrices -> (P, 3, N), ``a @ m`` per point, channels first. Written out as
    the sum of two scaled rows: the broadcast product and sum over (P, N, 2, 3) took 5.4 ms for 12 x 12,288 points
    against 1.0 (2 threads), with the same values (a two-term sum in the same order)."""
    return a[:, 0:1] * m[:, 0] + a[:, 1:2] * m[:, 1]


def _dot3(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(P, 3, N) . (P, 3, N) -> (P, N), summed in the order of ``(a * b).sum(1)`` (the same values, half its
    time)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def pair_jacobians(level: LevelData, pairs: torch.Tensor, ev: PairEvaluation, with_code_b: bool = True) -> PairTerms:
    """Compact analytic Jacobians (Eqs. 7-9 and their geometric counterparts) of the residuals in ``ev``
    (evaluated with ``with_gradients=True``). ``with_code_b=False`` skips sampling J_B at v (its block is fixed)."""
    w, cost = robust_weights(ev)
    P, T, N = ev.r.shape
    dtype = ev.r.dtype
    iB = pairs[:, 1]
    # Points and their derivatives channels first, (P, 3, N): the warp's points already lie so in memory, and an
    # elementwise operation over (P, N, 3) rows of 3 runs a scalar loop (6 pairs x 2 types of 128x96 pixels, 2
    # threads, AMD Zen 3: the pose columns 1.0 -> 0.28 ms a type, d pi / d x 1.0 -> 0.4 ms; the same values).
    x_B = ev.x_B.transpose(1, 2)  # (P, 3, N)
    dpi = project_jac(x_B, level.params[iB][:, None], dim=-2)  # (P, 2, 3, N), d pi / d x
    dx_dd = so3_act(ev.T_BA[:, :3, :3], ev.ray_A).transpose(1, 2)  # Eq. 9: R d pi^-1 / d d, (P, 3, N)
    e_z = torch.tensor([[0.0], [0.0], [1.0]], dtype=dtype, device=ev.r.device)
    s_A, s_B = [], []
    x_pose = x_B if ev.rs is None else ev.rs.x_c.transpose(1, 2)  # the point the relative pose moves
    zeros = torch.zeros(P, N, dtype=dtype, device=ev.r.device)
    # Every type's columns written into one (P, L, T, N) tensor, masked once: stacking the types' blocks, masking
    # each and concatenating them for the normal equations copied it four times (~2 ms of a 6-pair 128x96
    # linearisation, 2 threads). Column by column, a pixel's L entries apart: the per-pixel weights of assemble
    # then multiply whole rows (measured on 6 pairs x 2 types of 128x96 pixels, 2 threads, AMD Zen 3: w * J 0.91
    # -> 0.20 ms, the sum over types of w s_A J 0.93 -> 0.21 ms, against the (P, T, N, L) rows of 8 entries).
    J_local = torch.empty(P, POSE_DIM + AFFINE_DIM + (2 * RS_DIM if ev.rs is not None else 0), T, N, dtype=dtype,
                          device=ev.r.device)
    for i, t in enumerate(ev.types):
        if t == PHOTOMETRIC:
            dr_dv = -ev.gain[..., None] * ev.grad_gray_B.transpose(1, 2)  # (P, 2, N): - alpha dI_B[v]/dv
            dr_dx = _row_times(dr_dv, dpi)  # Eqs. 7-9 common factor dI_B/dv dpi/dx, (P, 3, N)
            J_local[:, POSE_DIM, i] = -ev.gain * ev.gray_B  # d/d(a, b)
            J_local[:, POSE_DIM + 1, i] = -1.0
            s_B.append(zeros)
        else:
            # d/dx [f(x_z) - f(D_B(P_B[pi(x)]))] = df/dz e_z - df/dP dP_B/dv dpi/dx
            dr_dx = (ev.dgeo_dz[:, None] * e_z
                     - ev.dgeo_dprox_B[:, None] * _row_times(ev.grad_prox_B.transpose(1, 2), dpi))
            J_local[:, POSE_DIM:POSE_DIM + AFFINE_DIM, i] = 0.0
            s_B.append(-ev.dgeo_dprox_B)  # d r_geo / d c_B = -df/dP J_B[v]
        if ev.rs is not None:  # through B's readout rotation to x_c, and the rows of omega_A, omega_B
            rw = ev.rs
            dr_dx, dr_dwA, dr_dwB = rolling_shutter_rows(dr_dx, rw.x_c, rw.ray0, rw.depth_A, ev.T_BA, rw.omega_B,
                                                         rw.s_A, rw.s_B)
            J_local[:, POSE_DIM + AFFINE_DIM:POSE_DIM + AFFINE_DIM + RS_DIM, i] = dr_dwA
            J_local[:, POSE_DIM + AFFINE_DIM + RS_DIM:, i] = dr_dwB
        pose_columns(dr_dx, x_pose, out=J_local[:, :POSE_DIM, i])  # Eqs. 7-8 in SE(3) left form
        if t != PHOTOMETRIC and ev.geo_pose_scale is not None:  # a blank first view: the codes' term only
            J_local[:, :, i] *= ev.geo_pose_scale[:, None]  # its affine columns are 0
        s_A.append(_dot3(dr_dx, dx_dd) * ev.dd_dprox_A)  # Eq. 9 with dD_A/dc_A = dD/dP J_A[u]
    valid = ev.valid
    # masked rows are zero (their NaN/inf included): times the mask, then the NaN that 0 * NaN or 0 * inf left set
    # to 0 (masked_fill_ with the (P, 1, T, N) mask took 1.8 ms for 6 pairs x 2 types of 128x96 pixels, this
    # 0.3 ms, 2 threads). A masked entry becomes 0 or -0, the same in every sum.
    J_local.mul_(valid[:, None]).nan_to_num_(nan=0.0, posinf=float("inf"), neginf=float("-inf"))
    zero = torch.zeros((), dtype=dtype, device=ev.r.device)
    JB_w = JB_idx = None
    if GEOMETRIC in ev.types and with_code_b:  # J_B[v] where the geometric residual has weight
        tg = ev.types.index(GEOMETRIC)
        JB_idx = [k.nonzero().squeeze(-1) for k in w[:, tg] != 0]  # P x (M_p,); w is 0 where masked
        JB_w = sample_by_frame(level.jac_channels_last, pairs[:, 1].tolist(),
                               [ev.v[p, k] for p, k in enumerate(JB_idx)])
        if level.scale_entry:  # d r_geo / d s_B = -1 exactly (log depth): s_B J = -1 rather than the bilinear
            # lookup of the scale's column, which is not linear in the proximity it is read at
            for p, k in enumerate(JB_idx):
                JB_w[p][-1] = 1.0 / ev.dgeo_dprox_B[p, k]
    return PairTerms(
        types=ev.types,
        r=ev.r,
        w=w,
        cost=cost,
        J_local=J_local,
        s_A=torch.where(valid, torch.stack(s_A, dim=1), zero),
        s_B=torch.where(valid, torch.stack(s_B, dim=1), zero),
        JB_w=JB_w,
        JB_idx=JB_idx,
    )
