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

from codeslam.constants import MIN_KEYPOINT_DEPTH
from codeslam.geometry.camera import PinholeCamera, project, project_jac
from codeslam.geometry.image import bilinear_sample
from codeslam.geometry.lie import hat, se3_act
from codeslam.geometry.proximity import d_depth_d_prox, prox_to_depth
from codeslam.sfm.decoder import ScaledDecoder
from codeslam.sfm.normal_equations import add_local_blocks, batched_mv
from codeslam.sfm.residuals import huber_cost_and_weight
from codeslam.sfm.variables import CODE, POSE, POSE_DIM, BlockId, SfMState, VariableLayout
from codeslam.sfm.warp import relative_pose, relative_pose_jacobians


def _robust(r: torch.Tensor, x: torch.Tensor, sigma: torch.Tensor, huber: float,
            weight: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Residuals r (N, 2) of points x (N, 3) in B -> per-point cost (N,) ``weight rho(|r| / sigma)`` and IRLS
    weight (N,) ``weight rho'(s)/s / sigma^2``; points behind B cost ``rho(huber)`` and get no weight."""
    sigma = sigma.to(dtype=r.dtype, device=r.device)
    rho, w = huber_cost_and_weight(r.norm(dim=-1) / sigma, huber)
    front = x[:, 2] > MIN_KEYPOINT_DEPTH
    cost = torch.where(front, rho, torch.full_like(rho, 0.5 * huber * huber))
    irls = torch.where(front, w / sigma**2, torch.zeros_like(w))
    return weight * cost, weight * irls


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

    def points(self, state: SfMState) -> torch.Tensor:
        """(N, 3) the points ``X_A`` in A's camera frame (fixed here; decoded from A's code in
        :class:`DecodedReprojectionTerm`)."""
        return self.xyz_a.to(dtype=state.poses.dtype, device=state.poses.device)

    def residuals(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> r (N, 2) pixels, x (N, 3) the points in B, T_BA (4, 4), all in the state's dtype."""
        dtype, device = state.poses.dtype, state.poses.device
        T_BA = relative_pose(state.poses[self.a], state.poses[self.b])
        x = se3_act(T_BA, self.points(state))  # x = T_BA X_A
        params = self.camera.params(dtype, device)
        r = project(x, params) - self.uv_b.to(dtype=dtype, device=device)  # r = pi(x) - u_B
        return r, x, T_BA

    def inliers(self, state: SfMState, threshold_px: float) -> torch.Tensor:
        """(N,) bool: matches whose reprojection error at ``state`` is within ``threshold_px``, in front of B."""
        if len(self) == 0:
            return torch.zeros(0, dtype=torch.bool)
        r, x, _ = self.residuals(state)
        return ((r.norm(dim=-1) <= threshold_px) & (x[:, 2] > MIN_KEYPOINT_DEPTH)).cpu()

    def _robust(self, r: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return _robust(r, x, self.sigma, self.huber, self.weight)

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

    def blocks(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, list[tuple[BlockId, torch.Tensor]]]:
        """-> r (N, 2), IRLS weights (N,) and the Jacobian of every block the residuals depend on."""
        r, J_A, J_B, w = self.jacobians(state)
        return r, w, [(BlockId(POSE, self.a), J_A), (BlockId(POSE, self.b), J_B)]

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        """Add ``J^T W J`` and ``J^T W r`` of the free blocks in place (IRLS, Gauss-Newton)."""
        if len(self) == 0:
            return
        r, w, blocks = self.blocks(state)
        free = [(layout.slice(b), J) for b, J in blocks if b in layout]
        for si, Ji in free:
            Jw = Ji * w[:, None, None]  # (N, 2, D_i)
            g[si] += torch.einsum("nki,nk->i", Jw, r).to(g.dtype)
            for sj, Jj in free:
                H[si, sj] += torch.einsum("nki,nkj->ij", Jw, Jj).to(H.dtype)


@dataclass
class DecodedReprojectionTerm(ReprojectionTerm):
    """Matched keypoints between two keyframes of the window, A's points decoded from A's code:
    ``X_A(c_A) = D(p0 + J c_A) ray`` at each keypoint (the linear decoder sampled bilinearly there), so the
    residuals constrain A's code as well as both poses::

        dr/dc_A = dpi/dx R_BA ray dD/dp J                                       (Eq. 4 and the paper's Eq. 9)

    Attributes (besides :class:`ReprojectionTerm`'s, whose ``xyz_a`` is unused):
        ray_a: (N, 3) rays ``((u - cx)/fx, (v - cy)/fy, 1)`` of A's keypoints.
        prox0: (N,) A's zero-code proximity at the keypoints; jac: (C, N) its code Jacobian there.
        avg_depth: A's decoder's average depth a.
    """

    ray_a: torch.Tensor = None
    prox0: torch.Tensor = None
    jac: torch.Tensor = None
    avg_depth: float = 1.0

    def __len__(self) -> int:
        return int(self.uv_b.shape[0])

    def _proximity(self, state: SfMState) -> torch.Tensor:
        code = state.codes[self.a].to(self.jac.dtype)
        return self.prox0 + code @ self.jac  # (N,) p0 + J c

    def points(self, state: SfMState) -> torch.Tensor:
        d = prox_to_depth(self._proximity(state), self.avg_depth)  # Eq. 4 inverted
        return (self.ray_a * d[:, None]).to(dtype=state.poses.dtype)

    def blocks(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, list[tuple[BlockId, torch.Tensor]]]:
        r, J_A, J_B, w = self.jacobians(state)
        _, x, T_BA = self.residuals(state)
        dpi = project_jac(x, self.camera.params(x.dtype, x.device))  # (N, 2, 3)
        dd_dp = d_depth_d_prox(self._proximity(state), self.avg_depth)  # (N,)
        dx_dd = self.ray_a.to(x.dtype) @ T_BA[:3, :3].T  # (N, 3): R_BA ray
        J_c = (dpi @ dx_dd[..., None]) * (dd_dp[:, None, None] * self.jac.T[:, None, :]).to(x.dtype)  # (N, 2, C)
        return r, w, [(BlockId(POSE, self.a), J_A), (BlockId(POSE, self.b), J_B), (BlockId(CODE, self.a), J_c)]


def keyframe_pair_term(
    a: int, b: int, uv_a: torch.Tensor, uv_b: torch.Tensor, sigma_b: torch.Tensor,
    decoder_level, avg_depth: float, feature_camera: PinholeCamera, depth_camera: PinholeCamera,
    weight: float = 1.0,
) -> DecodedReprojectionTerm:
    """The :class:`DecodedReprojectionTerm` of keypoints ``uv_a`` (M, 2) of keyframe a (feature camera) matched to
    ``uv_b`` (M, 2) in keyframe b, with a's decoder level 0 (``decoder_level``: prox0 (H, W), jac (C, H, W))
    sampled bilinearly at the keypoints (``depth_camera`` is the decoder's camera, same field of view)."""
    if not (len(uv_a) == len(uv_b) == len(sigma_b)):
        raise ValueError("keyframe_pair_term: matched arrays differ in length")
    dtype, device = decoder_level.jac.dtype, decoder_level.jac.device
    uv_a = uv_a.to(dtype=dtype, device=device)
    s = feature_camera.width / depth_camera.width
    uv_n = (uv_a + 0.5) / s - 0.5  # feature pixel -> decoder pixel (same field of view)
    stack = torch.cat([decoder_level.prox0[None], decoder_level.jac], 0)[None]  # (1, 1 + C, H, W)
    vals, _ = bilinear_sample(stack, uv_n[None], padding_mode="border")  # (1, 1 + C, M)
    prox0, jac = vals[0, 0], vals[0, 1:]
    ray = torch.stack([(uv_a[:, 0] - feature_camera.cx) / feature_camera.fx,
                       (uv_a[:, 1] - feature_camera.cy) / feature_camera.fy, torch.ones_like(uv_a[:, 0])], -1)
    d0 = prox_to_depth(prox0, avg_depth)
    return DecodedReprojectionTerm(
        a, b, ray * d0[:, None], uv_b.to(dtype=dtype, device=device), sigma_b.to(dtype=dtype, device=device),
        feature_camera, weight=weight, ray_a=ray, prox0=prox0, jac=jac, avg_depth=float(avg_depth),
    )


class StackedReprojectionTerm:
    """Several :class:`DecodedReprojectionTerm` of one state evaluated as one term: the matched keypoints of every
    keyframe pair of a window in one pass, with the same cost, gradient and Gauss-Newton blocks as the sum of
    the pair terms.

    Why (measured): the window linearises its keypoint pairs at every iteration of every pyramid level; one pair
    term costs ~40 small tensor operations (2.1 ms at 2 threads whatever its size), so the 5-12 pairs of a
    4-keyframe window took 11-25 ms of each linearisation, 120 ms of a 790 ms TUM window solve. Here the
    matches of all pairs are concatenated and each pair's ``J^T W J`` comes from one batched product over the
    pairs (matches padded to the longest pair), added to the normal equations by one indexed accumulation.

    The pairs must share the feature camera, Huber threshold and weight (a window's do).
    """

    def __init__(self, terms: list[DecodedReprojectionTerm], scaled: bool = False) -> None:
        self.scaled = scaled  # the codes' last entry is a log scale of A's depth (window.free_scale)
        terms = [t for t in terms if len(t) > 0]
        self.num_pairs = len(terms)
        if not terms:
            return
        first = terms[0]
        if any(t.camera != first.camera or t.huber != first.huber or t.weight != first.weight for t in terms):
            raise ValueError("StackedReprojectionTerm: the pair terms differ in camera, Huber threshold or weight")
        self.camera, self.huber, self.weight = first.camera, first.huber, first.weight
        counts = torch.tensor([len(t) for t in terms])
        self.a = torch.tensor([t.a for t in terms])  # (P,) frame of the points
        self.b = torch.tensor([t.b for t in terms])  # (P,) frame of the observations
        self.pid = torch.repeat_interleave(torch.arange(len(terms)), counts)  # (N,) pair of each match
        self.uv_b = torch.cat([t.uv_b for t in terms])  # (N, 2)
        self.sigma = torch.cat([t.sigma for t in terms])  # (N,)
        self.ray_a = torch.cat([t.ray_a for t in terms])  # (N, 3)
        self.prox0 = torch.cat([t.prox0 for t in terms])  # (N,)
        self.jac_t = torch.cat([t.jac for t in terms], dim=1).T.contiguous()  # (N, C)
        self.avg_depth = torch.cat([torch.full((len(t),), t.avg_depth, dtype=t.prox0.dtype, device=t.prox0.device)
                                    for t in terms])  # (N,)
        # Padded slot of every match: pair p's matches fill rows p * n_max ... p * n_max + n_p - 1.
        self.n_max = int(counts.max())
        starts = torch.cumsum(counts, 0) - counts
        self.slot = self.pid * self.n_max + torch.arange(len(self.pid)) - starts[self.pid]

    def __len__(self) -> int:
        return 0 if self.num_pairs == 0 else int(self.pid.shape[0])

    def _residuals(self, state: SfMState):
        """-> r (N, 2), x (N, 3) the points in B, R_BA (N, 3, 3), proximity (N,) and the average depth it is read
        with (a exp(s) with the scale entry), all matches at once."""
        dtype, device = state.poses.dtype, state.poses.device
        T_BA = relative_pose(state.poses[self.a], state.poses[self.b])[self.pid]  # (N, 4, 4) T_wB^-1 T_wA
        codes = state.codes[self.a][self.pid].to(self.jac_t.dtype)  # (N, C) c_A of each match
        k = codes.shape[1] - 1 if self.scaled else codes.shape[1]  # the scale entry is not linear in proximity
        prox = self.prox0 + (codes[:, :k] * self.jac_t[:, :k]).sum(-1)  # (N,) p0 + J c
        a = self.avg_depth * torch.exp(codes[:, -1]) if self.scaled else self.avg_depth  # a exp(s): D exp(s)
        X = (self.ray_a * prox_to_depth(prox, a)[:, None]).to(dtype)  # X_A = D ray (Eq. 4 inverted)
        R = T_BA[:, :3, :3]
        x = (R @ X[..., None]).squeeze(-1) + T_BA[:, :3, 3]  # x = T_BA X_A
        r = project(x, self.camera.params(dtype, device)) - self.uv_b.to(dtype=dtype, device=device)
        return r, x, R, prox, a

    def _robust(self, r: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return _robust(r, x, self.sigma, self.huber, self.weight)

    def cost(self, state: SfMState) -> torch.Tensor:
        if len(self) == 0:
            return state.poses.new_zeros(())
        r, x, *_ = self._residuals(state)
        return self._robust(r, x)[0].sum()

    def jacobians(self, state: SfMState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> r (N, 2), J (N, 2, 12 + C) over [pose A, pose B, code A] of each match's pair, IRLS weights (N,)."""
        r, x, R, prox, a = self._residuals(state)
        dpi = project_jac(x, self.camera.params(x.dtype, x.device))  # (N, 2, 3)
        eye = torch.eye(3, dtype=x.dtype, device=x.device).expand(x.shape[0], 3, 3)
        J_rel = dpi @ torch.cat([eye, -hat(x)], dim=-1)  # (N, 2, 6): dpi/dx [I, -x^]
        Ad, _ = relative_pose_jacobians(state.poses[self.b])  # (P, 6, 6): d xi_BA / d xi_A = Ad_{T_Bw} = -d/d xi_B
        J_A = J_rel @ Ad[self.pid]
        dd_dp = d_depth_d_prox(prox, a)  # (N,)
        dx_dd = (R @ self.ray_a.to(x.dtype)[..., None])  # (N, 3, 1): R_BA ray
        jac = self.jac_t
        if self.scaled:  # the scale's column at the current proximity
            jac = torch.cat([jac[:, :-1], ScaledDecoder.scale_column(prox)[:, None]], dim=1)
        J_c = (dpi @ dx_dd) * (dd_dp[:, None, None] * jac[:, None, :]).to(x.dtype)  # (N, 2, C)
        _, w = self._robust(r, x)
        return r, torch.cat([J_A, -J_A, J_c], dim=-1), w

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        """Add ``J^T W J`` and ``J^T W r`` of the free blocks in place (IRLS, Gauss-Newton)."""
        if len(self) == 0:
            return
        r, J, w = self.jacobians(state)
        P, D = self.num_pairs, J.shape[-1]
        Jw = J * w[:, None, None]
        pad = J.new_zeros(P * self.n_max, 2, D)
        pad_w = J.new_zeros(P * self.n_max, 2, D)
        pad_r = J.new_zeros(P * self.n_max, 2)
        pad[self.slot], pad_w[self.slot], pad_r[self.slot] = J, Jw, r
        pad, pad_w, pad_r = (t.reshape(P, 2 * self.n_max, -1) for t in (pad, pad_w, pad_r))
        H_p = pad_w.transpose(1, 2) @ pad  # (P, D, D) each pair's J^T W J
        g_p = batched_mv(pad_w.transpose(1, 2), pad_r.squeeze(-1))  # (P, D)
        blocks = [[(BlockId(POSE, a), 0, POSE_DIM), (BlockId(POSE, b), POSE_DIM, 2 * POSE_DIM),
                   (BlockId(CODE, a), 2 * POSE_DIM, D)] for a, b in zip(self.a.tolist(), self.b.tolist())]
        add_local_blocks(H, g, layout, blocks, H_p, g_p)
