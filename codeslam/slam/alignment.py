"""The tracker's alignment problem written for its two free blocks (paper Sec. 4.2): the frame's pose (6, left
increment of ``T_kf`` as everywhere in :mod:`codeslam.sfm`) and the pair's affine brightness (2).

It is the cost the generic two-frame :class:`~codeslam.sfm.solver.PairProblem` gives for a keyframe A at the
identity with its depth fixed and a frame B without depth, photometric residuals only (Eq. 13 with the affine
brightness of Sec. 5.2), with the same loss functions: (i) the masks, (ii) the sigma, (iii) Huber, (iv) the slant
weight; (v) compares the warped point with B's decoded surface, which a tracked frame has not (the generic path
reads B's proximity as the invalid sentinel and never down-weights), so its weight is 1 here too; plus the affine
prior and the extra terms (reprojection, motion prior). What makes it fast is what the generic problem cannot know:

* everything of the keyframe is fixed while frames are tracked against it: per level the points ``pi^-1(u,
  D_A[u])`` (depth decoded at the code), the intensities, the slant weights and the masks are computed once
  (:class:`TrackingReference`) and reused for every frame;
* the frame's pyramid is built alone (:class:`FramePyramid`), its grey image, Sobel gradients and real-pixel mask
  stacked for one bilinear lookup;
* per-pixel quantities are stored (channels, N), the layout in which the small products and the elementwise
  operations are fast on a CPU, and the normal equations are one ``J (w J^T)`` product of the (8, M) Jacobian of
  the M valid pixels, mapped from the relative pose to the frame's pose by the adjoint (8x8), instead of the
  generic block assembly;
* the matched keypoints' reprojection residuals (:class:`KeypointTerm`) are evaluated in the same layout with the
  same relative pose;
* the eight variables, the 8x8 normal equations, the priors and the retraction live on the host in float64 NumPy
  (:class:`TrackingState`; the exponential and logarithm in scalar arithmetic,
  :func:`~codeslam.geometry.lie.se3_exp_floats`): tensor operations are spent on the pixels only.

Measured while writing it (TUM fr1/rpy frames 1-9 against frame 0, three times, one thread; the generic solver
70-80 ms per frame): the keyframe cached with the generic evaluation's operations, 33 ms; the (channels, N)
layout and masks as products instead of ``torch.where``, 24 ms; the retraction on the host instead of
``se3_exp``'s ~60 tensor operations, 12 ms. With 300 matched keypoints the generic ``ReprojectionTerm`` costs
~0.5 ms per evaluation and ~1.4 ms per linearisation on the loaded machine, :class:`KeypointTerm` ~0.15 ms each.

:class:`TrackingProblem` has the ``evaluate`` / ``linearize`` interface of
:func:`~codeslam.sfm.solver.levenberg_marquardt` and :class:`TrackingState` its ``retract``, so the damped
Gauss-Newton steps, their acceptance and the stopping rules are the mapping's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from codeslam.clock import NO_CLOCK, Clock
from codeslam.constants import BILINEAR_ALL_VALID, MIN_DEPTH, MIN_KEYPOINT_DEPTH
from codeslam.geometry.camera import PinholeCamera, unproject_jac_depth
from codeslam.geometry.image import (
    grid_scale,
    image_gradients,
    image_pyramid,
    pixels_to_grid,
    pyramid_cameras,
    rgb_to_gray,
)
from codeslam.geometry.lie import se3_exp_floats, se3_inverse, se3_log_floats, se3_log_host
from codeslam.geometry.proximity import prox_to_depth
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder
from codeslam.sfm.keyframes import Keyframe, build_levels, real_pixels
from codeslam.sfm.residuals import (
    huber_cost_and_weight,
    interpolant_gradient,
    masked_mean_cost,
    slant_weight,
    step_cost_change,
)
from codeslam.sfm.variables import AFFINE_DIM, POSE, POSE_DIM, BlockId, SfMState, VariableLayout
from codeslam.sfm.warp import cross_columns
from codeslam.slam.reprojection import ReprojectionTerm


def fixed_depth_decoder(decoder: LinearDecoder, code: torch.Tensor) -> LinearDecoder:
    """The decoder's proximity at ``code`` on every level as a decoder of code size 1 with a zero Jacobian:
    tracking holds the keyframe's depth fixed, so this keeps the per-iteration decoding (``prox0 + J c``, a
    (C, H, W) contraction) out of the solver's loop."""
    code = code.to(dtype=decoder.levels[0].jac.dtype, device=decoder.levels[0].jac.device)
    levels = tuple(
        DecoderLevel(decoder.prox(code, k), torch.zeros((1, *lvl.prox0.shape), dtype=lvl.jac.dtype,
                                                          device=lvl.jac.device), lvl.uncertainty)
        for k, lvl in enumerate(decoder.levels)
    )
    return LinearDecoder(levels, decoder.avg_depth)


# ---- the keyframe's side: fixed for every frame tracked against it ---------------------------------------------


@dataclass(frozen=True)
class ReferenceLevel:
    """The keyframe at one pyramid level, as tracking reads it. N = H W pixels, row-major.

    Attributes:
        gray: (N,) intensities I_A[u].
        xyz: (3, N) points ``pi^-1(u, D_A[u])`` in A's camera frame (depth decoded at the code), one row per axis.
        ok: (N,) bool, valid depth and a real image pixel (loss (i) on A's side).
        slant: (N,) loss (iv) weight.
    """

    gray: torch.Tensor
    xyz: torch.Tensor
    ok: torch.Tensor
    slant: torch.Tensor


class TrackingReference:
    """What tracking needs of a keyframe whose depth is decoded at ``code`` (C,), per pyramid level in ``levels``,
    built once and reused for every frame tracked against it (``cfg`` gives the slant threshold). ``matches``
    tells whether it still describes a keyframe and code (the window replaces a keyframe's code after each
    solve)."""

    def __init__(self, keyframe: Keyframe, code: torch.Tensor, levels: Sequence[int], cfg: SfMConfig,
                 dtype: torch.dtype, device: torch.device) -> None:
        self.keyframe = keyframe
        self.code = code.detach().to(dtype=dtype, device=device).clone()
        self.dtype, self.device = dtype, device
        fixed = Keyframe(keyframe.image, keyframe.camera, fixed_depth_decoder(keyframe.decoder, self.code),
                         keyframe.valid)
        self.levels: dict[int, ReferenceLevel] = {}
        for lvl, data in build_levels([fixed], sorted(set(levels)), dtype, device).items():
            depth = prox_to_depth(data.prox0, data.avg_depth[:, None, None, None])  # (1, 1, H, W), Eq. 4 inverted
            d_A = depth.reshape(-1)  # (N,) D_A[u]
            ok = d_A > 0
            if data.gray_valid is not None:
                ok = ok & (data.gray_valid.reshape(-1) > 0.5)  # (i): real pixels of A only
            ray = unproject_jac_depth(data.uv, data.params[0])  # (N, 3)
            self.levels[lvl] = ReferenceLevel(
                gray=data.gray.reshape(-1),
                xyz=(ray * d_A.unsqueeze(-1)).T.contiguous(),  # pi^-1(u, D_A[u]) (Eq. 5), (3, N)
                ok=ok,
                slant=slant_weight(depth, data.params, cfg.slant_cos_min).reshape(-1),  # (iv)
            )

    def matches(self, keyframe: Keyframe, code: torch.Tensor) -> bool:
        """Whether this reference was built for ``keyframe`` (the same object) at the same code values."""
        return keyframe is self.keyframe and torch.equal(code.to(dtype=self.dtype, device=self.device), self.code)


# ---- the frame's side: built once per frame -------------------------------------------------------------------


@dataclass(frozen=True)
class FrameLevel:
    """The frame at one pyramid level. stack: (1, K, H, W) what one bilinear lookup reads: grey, its Sobel
    gradients d/du and d/dv and, when the frame has a validity mask, its real-pixel mask (K = 3 or 4); params: (4,)
    intrinsics (fx, fy, cx, cy) at this level. ``intrinsics`` (the four as 0-dim tensors) and ``grid_scale``
    (:func:`~codeslam.geometry.image.grid_scale`, what ``pixels_to_grid`` multiplies by) are made once here, not at
    every evaluation: the alignment is bound by the count of its small tensor operations, not by their size (about
    1,700 torch calls a frame on TUM fr1/rpy; docs/results/slam_table.md, fifty-fourth session)."""

    stack: torch.Tensor
    params: torch.Tensor
    intrinsics: tuple[torch.Tensor, ...] = field(init=False, repr=False, compare=False)
    grid_scale: torch.Tensor = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        H, W = self.stack.shape[-2:]
        object.__setattr__(self, "intrinsics", tuple(self.params.unbind()))
        object.__setattr__(self, "grid_scale", grid_scale(H, W, self.params))

    @property
    def height(self) -> int:
        return self.stack.shape[-2]

    @property
    def width(self) -> int:
        return self.stack.shape[-1]


class FramePyramid:
    """The pyramid levels ``levels`` of a frame to be tracked: ``image`` (1, H, W) grey or (3, H, W) RGB seen by
    ``camera``, ``valid`` (H, W) bool its real pixels (None: all), or ``real`` their masks per level computed
    before ((1, 1, H_l, W_l): 1 where the pyramid pixel comes from real pixels only, else 0). The same pyramid,
    gradients and mask as :func:`~codeslam.sfm.keyframes.build_levels`, for the one image. ``real`` (attribute):
    the real-pixel masks used (None without ``valid``), for the caller to keep for the next frame with the same
    mask (a reader that masks a fixed border gives every frame the same one)."""

    def __init__(self, image: torch.Tensor, camera: PinholeCamera, valid: torch.Tensor | None,
                 levels: Sequence[int], dtype: torch.dtype, device: torch.device,
                 real: dict[int, torch.Tensor] | None = None) -> None:
        img = image.to(dtype=dtype, device=device)
        img = img if img.dim() == 3 else img[None]
        gray = (rgb_to_gray(img[None]) if img.shape[0] == 3 else img[None]).contiguous()  # (1, 1, H, W)
        n_levels = max(levels) + 1
        if real is None and valid is not None:
            # The mask's pyramid in the same call as the image's (a second channel; the pyramid filters each
            # channel alone, so both are bit for bit what two calls give): one call instead of two, 0.56 against
            # 0.81 ms at 128x96 and 4 levels, on every frame whose mask the tracker has not seen (a rolling-shutter
            # rectification gives each frame its own).
            stacked = image_pyramid(torch.cat([gray, valid.to(dtype=dtype, device=device)[None, None]], 1), n_levels)
            pyr = [p[:, :1] for p in stacked]
            real = {lvl: real_pixels(stacked[lvl][:, 1:]) for lvl in sorted(set(levels))}
        else:
            pyr = image_pyramid(gray, n_levels)
        self.real = real
        cams = pyramid_cameras(camera, n_levels)
        self.levels: dict[int, FrameLevel] = {}
        for lvl in sorted(set(levels)):
            g = pyr[lvl].contiguous()
            chans = [g, image_gradients(g)[:, 0]]  # (1, 1 + 2, H, W)
            if real is not None:
                chans.append(real[lvl])
            self.levels[lvl] = FrameLevel(torch.cat(chans, dim=1), cams[lvl].params(dtype, device))


# ---- residuals and Jacobian -------------------------------------------------------------------------------------


@dataclass
class AlignmentEvaluation:
    """The photometric residuals of one level at a state, and what their Jacobian reuses (N pixels).

    r: (N,) residuals (0 where masked); valid: (N,) bool; w: (N,) IRLS weights ``slant rho'(s)/s / sigma^2`` (0
    where masked); sigma: () the photometric sigma; x: (3, N) the points in B; gray_B: (N,) I_B[v]; grad_B: (2, N)
    gradient of I_B at v (d/du, d/dv); gain: () exp(a); cost: () the robust photometric cost (masked rows priced as
    ``cfg.masked_rows`` says, loss (i)); keypoints: what :meth:`KeypointTerm.evaluate` gave at the same pose (None
    without keypoints); prior_deltas: each pose prior's ``d`` at the same pose (:meth:`PosePrior.delta_of`);
    row_cost: (N,) each valid pixel's robust cost (0 where masked), for
    :func:`~codeslam.sfm.residuals.step_cost_change`.
    """

    r: torch.Tensor
    valid: torch.Tensor
    w: torch.Tensor
    sigma: torch.Tensor
    x: torch.Tensor
    gray_B: torch.Tensor
    grad_B: torch.Tensor
    gain: torch.Tensor
    cost: torch.Tensor
    keypoints: tuple[torch.Tensor, ...] | None = None
    prior_deltas: list[np.ndarray] | None = None
    row_cost: torch.Tensor | None = None


@dataclass(frozen=True)
class PhotometricConstants:
    """The 0-dim tensors of the photometric cost's settings, made once per problem rather than at every
    evaluation: the sigma (ii), the Huber threshold k (iii), ``sigma**2`` and the price ``0.5 k k`` of a masked row."""

    zero: torch.Tensor
    sigma: torch.Tensor
    k: torch.Tensor
    sigma2: torch.Tensor
    half_kk: torch.Tensor

    @classmethod
    def of(cls, cfg: SfMConfig, dtype: torch.dtype, device: torch.device) -> PhotometricConstants:
        zero = torch.zeros((), dtype=dtype, device=device)
        sigma = torch.full_like(zero, cfg.sigma_photometric)
        k = torch.full_like(zero, cfg.huber_photometric)
        return cls(zero, sigma, k, sigma**2, 0.5 * k * k)


def photometric_residuals(ref: ReferenceLevel, frame: FrameLevel, R_BA: torch.Tensor, t_BA: torch.Tensor,
                          affine: torch.Tensor | None, cfg: SfMConfig,
                          constants: PhotometricConstants | None = None) -> AlignmentEvaluation:
    """The keyframe's pixels warped into the frame by ``(R_BA, t_BA)`` ((3, 3), (3,): maps A's points into B),
    with ``affine`` (2,) (log-gain, bias), or None for no brightness correction: residuals, masks, IRLS weights
    and robust cost, as :func:`~codeslam.sfm.residuals.evaluate_pairs` and
    :func:`~codeslam.sfm.residuals.robust_weights` give them for the pair (keyframe, frame), with the same
    arithmetic for the pixel positions (the masks at the border depend on their last bit: from the identity a
    pixel lands exactly on it). Differentiable in the pose and ``affine`` (masks and weights are not).
    ``constants``: ``cfg``'s constants made before (None: made here)."""
    N = ref.gray.shape[0]
    H, W = frame.height, frame.width
    c = constants if constants is not None else PhotometricConstants.of(cfg, ref.gray.dtype, ref.gray.device)
    zero = c.zero
    x = torch.addmm(t_BA.unsqueeze(-1), R_BA, ref.xyz)  # Eq. 11: x = R pi^-1(u, d) + t, (3, N)
    z = x[2]
    fx, fy, cx, cy = frame.intrinsics
    u = fx * x[0] / z + cx  # Eq. 5: v = pi(x), as codeslam.geometry.camera.project
    v = fy * x[1] / z + cy
    # (i) masks: inside B (minus the border), in front of B, valid depth and real pixels of A (inside_image's
    # test as a clamp; NaN fails it, so a non-finite v is masked too).
    b = cfg.border
    valid = (u == u.clamp(b, W - 1 - b)) & (v == v.clamp(b, H - 1 - b)) & (z > MIN_DEPTH) & ref.ok
    uv = torch.stack([u, v], dim=-1)  # (N, 2)
    # The lookup of codeslam.geometry.image.bilinear_sample at v (the paper's square brackets); masked points are
    # moved into the image (finite) and their values never used.
    grid = pixels_to_grid(uv, H, W, frame.grid_scale).clamp(-2.0, 2.0).nan_to_num(0.0)
    sampled = F.grid_sample(frame.stack, grid.view(1, 1, N, 2), mode="bilinear", padding_mode="zeros",
                            align_corners=True).view(-1, N)  # (K, N)
    gray_B, grad_B = sampled[0], sampled[1:3]
    if sampled.shape[0] > 3:
        valid = valid & (sampled[3] > BILINEAR_ALL_VALID)  # (i): all four bilinear neighbours real pixels
    if cfg.gradient_mode == "interpolant":  # the exact slope of the lookup instead of the Sobel image's value
        uv_safe = torch.where(valid.unsqueeze(-1), uv, torch.zeros_like(uv))
        grad_B = interpolant_gradient(frame.stack[:, :1], uv_safe.unsqueeze(0))[0, 0]  # (2, N)
    vf = valid.to(ref.gray.dtype)
    if affine is None:
        gain, bias = torch.ones_like(zero), zero
    else:
        gain, bias = torch.exp(affine[0]), affine[1]
    r = (ref.gray - (gain * gray_B + bias)) * vf  # Eq. 13 with affine brightness (Sec. 5.2), 0 where masked
    sigma, k = c.sigma, c.k  # (ii), (iii)
    rho, irls = huber_cost_and_weight(r / sigma, k)  # (iii); masked rows have r = 0, so rho = 0
    w = ref.slant * irls * vf / c.sigma2  # (iv), the IRLS weight
    rows = ref.slant * rho  # masked rows have rho = 0
    if cfg.masked_rows == "threshold":
        cost = rows.sum() + c.half_kk * (N - vf.sum())  # masked rows cost rho(k) (loss (i))
    else:
        cost = masked_mean_cost(rows.sum(), vf.sum(), N, k)  # masked rows at the valid rows' mean (loss (i))
    return AlignmentEvaluation(r, valid, w, sigma, x, gray_B, grad_B, gain, cost, row_cost=rows)


def photometric_jacobian(x: torch.Tensor, grad_B: torch.Tensor, gray_B: torch.Tensor, gain: torch.Tensor,
                         params: torch.Tensor) -> torch.Tensor:
    """Jacobian of photometric residuals ``r = I_A[u] - (exp(a) I_B[v] + b)`` w.r.t. the left increment
    ``xi_BA = (rho, phi)`` of ``T_BA`` and the affine parameters (a, b).

    x: (3, M) the warped points in B; grad_B: (2, M) the image gradient of I_B at v (held fixed: the Sobel image's
    value, or the interpolant's slope); gray_B: (M,) I_B[v]; gain: () exp(a); params: (4,) B's intrinsics
    -> (8, M), one row per variable (rho, phi, a, b).
    """
    fx, fy = params[0], params[1]
    J = x.new_empty((POSE_DIM + AFFINE_DIM, x.shape[1]))  # each row written in place (no stack of 8 copies)
    inv_z = 1.0 / x[2]
    dr_dv = -gain * grad_B  # (2, M): - alpha dI_B[v]/dv
    # dr/dx = dr/dv dpi/dx with dpi/dx = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]: the factor of Eqs. 7-8.
    a_x = torch.mul(dr_dv[0] * fx, inv_z, out=J[0])  # Eq. 7: d/d t
    a_y = torch.mul(dr_dv[1] * fy, inv_z, out=J[1])
    a_z = torch.mul(-(a_x * x[0] + a_y * x[1]), inv_z, out=J[2])
    torch.sub(x[1] * a_z, x[2] * a_y, out=J[3])  # Eq. 8 in SE(3) left form: x x a
    torch.sub(x[2] * a_x, x[0] * a_z, out=J[4])
    torch.sub(x[0] * a_y, x[1] * a_x, out=J[5])
    torch.mul(-gain, gray_B, out=J[6])  # d/d(a, b)
    J[7] = -1.0
    return J


def frame_pose_map(R_BA: np.ndarray, t_BA: np.ndarray) -> np.ndarray:
    """(8, 8) ``d (xi_BA, a, b) / d (xi_B, a, b)``: with the keyframe at the origin ``T_BA = T_kf^-1`` moves by
    ``-Ad_{T_BA}`` of the frame's left increment (:func:`~codeslam.sfm.warp.relative_pose_jacobians`), ``Ad_T =
    [[R, t^ R], [0, R]]`` (:func:`~codeslam.geometry.lie.se3_adjoint`); the affine parameters map to themselves.
    On the host in float64, as the tracker's state (:class:`TrackingState`)."""
    tx, ty, tz = t_BA
    t_hat = np.array([[0.0, -tz, ty], [tz, 0.0, -tx], [-ty, tx, 0.0]])
    M = np.eye(POSE_DIM + AFFINE_DIM)
    M[:3, :3] = -R_BA
    M[:3, 3:6] = -(t_hat @ R_BA)
    M[3:6, 3:6] = -R_BA
    return M


# ---- matched keypoints --------------------------------------------------------------------------------------


class KeypointTerm:
    """The reprojection residuals of a :class:`~codeslam.slam.reprojection.ReprojectionTerm` between the keyframe
    (frame 0, at the origin) and the tracked frame (frame 1), laid out (channels, M) for the tracker's loop; the same
    cost (``weight rho(|pi(T_BA X_A) - u_B| / sigma)``, points behind B priced at the Huber threshold) and IRLS
    weights. ``term`` must join frame 0 (points) and frame 1 (pixels) of the tracking state.

    Attributes: xyz (3, M) the points X_A in the keyframe; uv (2, M) their observed pixels in the frame's feature
    camera; sigma (M,) their pixel noise; params (4,) the feature camera's intrinsics; huber () the threshold in
    sigmas; weight.
    """

    def __init__(self, term: ReprojectionTerm, dtype: torch.dtype, device: torch.device) -> None:
        if (term.a, term.b) != (0, 1) or type(term) is not ReprojectionTerm:
            raise ValueError("KeypointTerm: a ReprojectionTerm from frame 0 (the keyframe) to frame 1 is needed")
        self.xyz = term.xyz_a.to(dtype=dtype, device=device).T.contiguous()
        self.uv = term.uv_b.to(dtype=dtype, device=device).T.contiguous()
        self.sigma = term.sigma.to(dtype=dtype, device=device)
        self.params = term.camera.params(dtype, device)
        self._intrinsics = tuple(self.params.unbind())  # fx, fy, cx, cy: unpacked once, not per evaluation
        self.huber = torch.tensor(float(term.huber), dtype=dtype, device=device)
        self.weight = float(term.weight)
        # Per evaluation only what depends on the pose: the constants of the robust cost computed once.
        self._irls_scale = self.weight / self.sigma**2  # (M,)
        self._behind_cost = 0.5 * self.huber * self.huber  # rho(k), the price of a point behind B

    def evaluate(self, R_BA: torch.Tensor, t_BA: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """-> cost (), residuals r (2, M) in pixels, the points x (3, M) in B and IRLS weights (M,) (0 behind B)."""
        x = torch.addmm(t_BA.unsqueeze(-1), R_BA, self.xyz)  # x = T_BA X_A (the paper's Eq. 5 with known depth)
        fx, fy, cx, cy = self._intrinsics
        r = torch.stack([fx * x[0] / x[2] + cx, fy * x[1] / x[2] + cy]) - self.uv  # r = pi(x) - u_B
        front = x[2] > MIN_KEYPOINT_DEPTH
        rho, irls = huber_cost_and_weight(torch.hypot(r[0], r[1]) / self.sigma, self.huber)  # |r| / sigma
        cost = torch.where(front, rho, self._behind_cost)
        w = torch.where(front, irls * self._irls_scale, torch.zeros_like(irls))
        return self.weight * cost.sum(), r, x, w

    @staticmethod
    def inliers(r: torch.Tensor, x: torch.Tensor, threshold_px: float) -> torch.Tensor:
        """r (2, M), x (3, M) of :meth:`evaluate` -> (M,) bool: within ``threshold_px`` and in front of B, the test of
        :meth:`~codeslam.slam.reprojection.ReprojectionTerm.inliers` in this layout."""
        return (torch.hypot(r[0], r[1]) <= threshold_px) & (x[2] > MIN_KEYPOINT_DEPTH)

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """x (3, M) the points in B -> (6, 2, M) ``d r / d xi_BA`` (left increment of T_BA): each residual row a
        (a row of d pi / d x) gives ``[a, x x a]`` (Eqs. 7-8, as :func:`~codeslam.sfm.warp.pose_columns`)."""
        fx, fy = self._intrinsics[:2]
        J = x.new_zeros((POSE_DIM, 2, x.shape[1]))  # written in place: no stacks of copies
        inv_z = 1.0 / x[2]
        torch.mul(fx, inv_z, out=J[0, 0])  # d u / d x = (fx/z, 0, -fx x/z^2)
        torch.mul(-fx * x[0] * inv_z, inv_z, out=J[2, 0])
        torch.mul(fy, inv_z, out=J[1, 1])  # d v / d x = (0, fy/z, -fy y/z^2)
        torch.mul(-fy * x[1] * inv_z, inv_z, out=J[2, 1])
        cross_columns(x.unsqueeze(0), J[:3].transpose(0, 1), out=J[3:].transpose(0, 1))  # x x a, per row u, v
        return J  # (6, 2, M)


def _host(x: torch.Tensor) -> np.ndarray:
    """A tensor as float64 NumPy on the host (the tracker's state and 8x8 algebra)."""
    return x.detach().to(device="cpu", dtype=torch.float64).numpy()


class PosePrior:
    """``0.5 d^T H d`` with ``d = log(T_i T0^-1)`` on one pose block: a :class:`~codeslam.sfm.variables.LinearPrior`
    without its gradient term. ``cost``/``add_to`` read the generic state (the generic solver's path);
    :class:`TrackingProblem` calls ``delta_of``, ``cost_of`` and ``add_delta``, which take the frame's pose and
    the normal equations on the host (float64 NumPy, :class:`TrackingState`) and the logarithm in scalar
    arithmetic (:func:`~codeslam.geometry.lie.se3_log_floats`): one logarithm per iteration, no tensor operations
    (written with tensors, the prior made tracking 40% slower, TUM fr1/rpy, 45 -> 63 ms median per frame)."""

    def __init__(self, index: int, H: torch.Tensor, T0: torch.Tensor) -> None:
        self.block, self.H, self.T0_inv = BlockId(POSE, index), H, se3_inverse(T0)
        self._H_host, self._T0_inv_host = _host(H), _host(self.T0_inv)

    def delta_of(self, T: np.ndarray) -> np.ndarray:
        """(4, 4) the block's pose (float64 NumPy) -> (6,) ``d = log(T T0^-1)``."""
        return np.array(se3_log_floats((T @ self._T0_inv_host).tolist()))

    def cost_of(self, d: np.ndarray) -> float:
        return 0.5 * float(d @ self._H_host @ d)

    def add_delta(self, H: np.ndarray, g: np.ndarray, sl: slice, d: np.ndarray) -> None:
        """Add the prior's Hessian and gradient ``H d`` (``d(d)/d(increment) ~ I``) at ``d`` to the block ``sl``."""
        H[sl, sl] += self._H_host
        g[sl] += self._H_host @ d

    def delta(self, state: SfMState) -> torch.Tensor:
        T = state.poses[self.block.index]
        return se3_log_host(T @ self.T0_inv.to(T.dtype)).to(self.H.dtype)

    def cost(self, state: SfMState) -> torch.Tensor:
        d = self.delta(state)
        return 0.5 * d @ self.H @ d

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        """Add the prior's Hessian and gradient in place (the generic problem's interface)."""
        sl, H_p = layout.slice(self.block), self.H.to(H.dtype)
        H[sl, sl] += H_p
        g[sl] += H_p @ self.delta(state).to(g.dtype)


# ---- the problem of levenberg_marquardt ---------------------------------------------------------------------


@dataclass
class TrackingState:
    """The free variables, on the host in float64 NumPy: T_kf (4, 4) the frame's pose in the keyframe, affine (2,)
    the pair's (log-gain, bias). ``retract`` is :meth:`~codeslam.sfm.variables.SfMState.retract` for the layout
    ``[pose 1, affine 0]``. Eight numbers whose every tensor operation costs more than its arithmetic: kept on the
    host, the tracker's solver spends its tensor operations on the pixels only (``docs/results/slam_table.md``,
    sixty-fifth session: 3,977 -> 2,755 operations a frame, the alignment 0.87-0.90x the time)."""

    T_kf: np.ndarray
    affine: np.ndarray

    @classmethod
    def from_sfm(cls, state: SfMState) -> TrackingState:
        return cls(_host(state.poses[1]), _host(state.affine[0]))

    def to_sfm(self, dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu") -> SfMState:
        """The generic state (the keyframe at the origin and the frame; codes unused, of size 1), what the extra
        terms read."""
        poses = torch.from_numpy(np.stack([np.eye(4), self.T_kf])).to(dtype=dtype, device=device)
        return SfMState(poses, poses.new_zeros(2, 1), torch.from_numpy(self.affine[None]).to(poses))

    def relative(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R_BA, t_BA)`` (3, 3), (3,) of ``T_BA = T_wB^-1 T_wA = T_kf^-1`` (the keyframe at the origin): what maps
        the keyframe's points into the frame."""
        R_BA = self.T_kf[:3, :3].T
        return R_BA, -(R_BA @ self.T_kf[:3, 3])

    def retract(self, layout: VariableLayout, delta: np.ndarray) -> TrackingState:
        """``T <- exp(xi) T`` (left increment) with ``xi = delta[:6]``, ``affine + delta[6:]`` (if present)."""
        affine = self.affine + delta[POSE_DIM:] if delta.shape[0] > POSE_DIM else self.affine
        return TrackingState(np.array(se3_exp_floats(delta[:POSE_DIM].tolist())) @ self.T_kf, affine)


class TrackingProblem:
    """One pyramid level of the tracking cost for :func:`~codeslam.sfm.solver.levenberg_marquardt` over a
    :class:`TrackingState` and the layout ``[pose 1, affine 0]`` (``[pose 1]`` without affine brightness) of the
    generic problem (pose 0 the keyframe at the origin, pose 1 the frame, affine 0 the pair).

    ref, frame: the level of the keyframe and of the frame; cfg: the photometric settings and the affine prior;
    keypoints: the matched keypoints' reprojection residuals (None: none); terms: other costs with ``cost(state)``
    and ``add_to(H, g, layout, state)`` on the generic state (the motion prior).

    The pixels' residuals and Jacobians are tensors of the keyframe's dtype and device; the state, the 8x8 normal
    equations and the priors are float64 NumPy on the host (``linearize`` returns them so, and the solver solves
    them there).
    """

    def __init__(self, ref: ReferenceLevel, frame: FrameLevel, cfg: SfMConfig, keypoints: KeypointTerm | None = None,
                 terms: Sequence = ()) -> None:
        self.ref, self.frame, self.cfg, self.keypoints = ref, frame, cfg, keypoints
        # Priors on the frame's pose (the motion model) read the pose itself; other terms the generic state.
        self.pose_priors: list[PosePrior] = []
        self.terms: list = []
        for t in terms:
            (self.pose_priors if type(t) is PosePrior and t.block.index == 1 else self.terms).append(t)
        self._affine_inv_var = 1.0 / np.asarray(cfg.affine_prior_sigma, dtype=np.float64) ** 2  # (2,)
        self._constants = PhotometricConstants.of(cfg, ref.gray.dtype, ref.gray.device)
        self._evaluated: list[tuple[TrackingState, float, AlignmentEvaluation]] = []

    def evaluate(self, state: TrackingState) -> tuple[float, AlignmentEvaluation]:
        R_BA, t_BA = state.relative()
        rel = torch.from_numpy(np.concatenate([R_BA, t_BA[:, None]], axis=1)).to(self.ref.gray)  # (3, 4)
        R_BA_t, t_BA_t = rel[:, :3], rel[:, 3]
        affine = torch.from_numpy(state.affine).to(self.ref.gray) if self.cfg.affine_brightness else None
        ev = photometric_residuals(self.ref, self.frame, R_BA_t, t_BA_t, affine, self.cfg, self._constants)
        cost = ev.cost
        if self.keypoints is not None:
            ev.keypoints = self.keypoints.evaluate(R_BA_t, t_BA_t)
            cost = cost + ev.keypoints[0]
        c = float(cost)
        if self.cfg.affine_brightness:  # Gaussian prior on (log-gain, bias)
            c += 0.5 * float(self._affine_inv_var @ (state.affine * state.affine))
        if self.pose_priors:
            ev.prior_deltas = [p.delta_of(state.T_kf) for p in self.pose_priors]
            for p, d in zip(self.pose_priors, ev.prior_deltas):
                c += p.cost_of(d)
        if self.terms:
            generic = state.to_sfm(self.ref.gray.dtype, self.ref.gray.device)
            for term in self.terms:
                c += float(term.cost(generic))
        self._evaluated.append((state, c, ev))
        return c, ev

    def cost_change(self, old: AlignmentEvaluation, new: AlignmentEvaluation, old_cost: float,
                    new_cost: float) -> float:
        """What a step changed the cost by (:func:`~codeslam.sfm.residuals.step_cost_change`)."""
        return step_cost_change(self.cfg.masked_rows, old, new, old_cost, new_cost)

    def evaluation(self, state: TrackingState) -> tuple[float, AlignmentEvaluation]:
        """The cost and evaluation at ``state`` (one this problem evaluated, e.g. the solver's result, reused)."""
        for s, c, ev in self._evaluated:
            if s is state:
                return c, ev
        return self.evaluate(state)

    def linearize(self, state: TrackingState, ev: AlignmentEvaluation, layout: VariableLayout,
                  clock: Clock = NO_CLOCK) -> tuple[np.ndarray, np.ndarray]:
        idx = ev.valid.nonzero().squeeze(-1)  # the M valid pixels; the others have no weight
        J = photometric_jacobian(ev.x.index_select(1, idx), ev.grad_B.index_select(1, idx),
                                 ev.gray_B.index_select(0, idx), ev.gain, self.frame.params)  # (8, M): xi_BA, a, b
        Jw = J * ev.w.index_select(0, idx)
        H_rel = Jw @ J.T  # (8, 8) J^T W J
        g_rel = Jw @ ev.r.index_select(0, idx)  # (8,) J^T W r
        if self.keypoints is not None:  # in the same relative coordinates, before the map to the frame's pose
            _, r, x, w = ev.keypoints
            Jk = self.keypoints.jacobian(x)  # (6, 2, M)
            Jkw = (Jk * w).reshape(POSE_DIM, -1)  # (6, 2 M), rows u then v, weighted
            H_rel[:POSE_DIM, :POSE_DIM].addmm_(Jkw, Jk.reshape(POSE_DIM, -1).T)
            g_rel[:POSE_DIM].addmv_(Jkw, r.reshape(-1))
        M = frame_pose_map(*state.relative())
        n = layout.dim  # the frame's pose, then (with affine brightness) the pair's affine parameters
        H = (M.T @ _host(H_rel) @ M)[:n, :n]
        g = (M.T @ _host(g_rel))[:n]
        if self.cfg.affine_brightness:
            H[POSE_DIM:, POSE_DIM:] += np.diag(self._affine_inv_var)
            g[POSE_DIM:] += self._affine_inv_var * state.affine
        for p, d in zip(self.pose_priors, ev.prior_deltas or ()):  # the deltas of the evaluation at this state
            p.add_delta(H, g, layout.slice(p.block), d)
        if self.terms:  # the terms add to tensors on the keyframe's device, then to the host's H and g
            like = self.ref.gray
            generic = state.to_sfm(like.dtype, like.device)
            H_t, g_t = like.new_zeros(H.shape), like.new_zeros(g.shape)
            for term in self.terms:
                term.add_to(H_t, g_t, layout, generic)
            H += _host(H_t)
            g += _host(g_t)
        return H, g
