"""Gauss-Newton normal equations ``H = J^T W J``, ``g = J^T W r`` of pair residuals, assembled from the compact
Jacobians of :mod:`codeslam.sfm.residuals` without forming the dense Jacobian.

Structure used (paper Sec. 4.1, linear decoder): per pixel, the Jacobian w.r.t. the code of A is a scalar times
a row of the precomputed ``J_A = dP_A/dc_A``, ``d r / d c_A = s_A J_A[u]``, so

* ``H_{c_A c_A} = J_A^T diag(sum_pairs sum_types w s_A^2) J_A``: the per-pixel weights of every pair with the same
  A (and both residual types) are summed first, then ONE (C x N)(N x C) product per frame;
* ``H_{c_A, pose/affine} = J_A^T (w s_A J_dense)``, ``g_{c_A} = J_A^T (w s_A r)``;
* the geometric residual also depends on the code of B through ``J_B[v]`` (sampled at the warped pixels):
  ``H_{c_B c_B} = J_B[v]^T diag(w) J_B[v]``, ``H_{c_A c_B} = J_A^T diag(w s_A s_B) J_B[v]``;
* the relative-pose Jacobian maps to the absolute poses by the adjoint (see :mod:`codeslam.sfm.warp`), so the pose
  blocks are ``Q^T (J_rel^T W J_rel) Q`` with the 8x14 map Q of each pair: the pixel sums are done once in the
  8 local dimensions (relative pose + affine); with the rolling-shutter model the readout rotations of A and B
  add 6 local columns that map to themselves (14x20).
"""

from __future__ import annotations

import torch

from codeslam.clock import NO_CLOCK, Clock
from codeslam.sfm.keyframes import LevelData
from codeslam.sfm.residuals import GEOMETRIC, PairTerms
from codeslam.sfm.variables import AFFINE, CODE, POSE, RS, BlockId, VariableLayout
from codeslam.sfm.warp import relative_pose_jacobians


def batched_mv(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(B, M, K) matrices times (B, K) vectors -> (B, M), e.g. a gradient ``J^T W r`` per frame or pair.

    Formed as a (1, K) x (K, M) product per batch element: torch's CPU ``bmm`` of (M, K) by (K, 1), which
    ``A @ v[..., None]`` runs, took a path 10-17 times slower (measured, 2 threads: 4 x 64 x 12288 1.9 against
    0.11 ms, 11 x 8 x 24576 1.4 against 0.08 ms, 11 x 76 x 600 0.31 against 0.03 ms). The sums run in another
    order, so the result differs from that product in the last bits."""
    return (v.unsqueeze(-2) @ A.transpose(-1, -2)).squeeze(-2)


def local_to_absolute(poses: torch.Tensor, pairs: torch.Tensor, rolling_shutter: bool = False) -> torch.Tensor:
    """(F, 4, 4) T_wc, (P, 2) pairs -> Q (P, 8, 14): ``[xi_BA, a, b] = Q [xi_A, xi_B, a, b]`` (chain rule of
    :func:`codeslam.sfm.warp.relative_pose_jacobians`; the affine parameters map to themselves). With
    ``rolling_shutter`` (P, 14, 20): the readout rotations ``omega_A, omega_B`` are appended and map to
    themselves."""
    P = pairs.shape[0]
    dA, dB = relative_pose_jacobians(poses[pairs[:, 1]])  # (P, 6, 6) each
    n = 14 if rolling_shutter else 8
    Q = torch.zeros(P, n, n + 6, dtype=poses.dtype, device=poses.device)
    Q[:, :6, :6] = dA
    Q[:, :6, 6:12] = dB
    idx = torch.arange(6, n, device=poses.device)
    Q[:, idx, idx + 6] = 1.0
    return Q


def _local_blocks(a: int, b: int, p: int, rolling_shutter: bool) -> list[tuple[BlockId, int, int]]:
    """The blocks of pair p = (a, b) in the columns of :func:`local_to_absolute`'s Q, with their column ranges."""
    blocks = [(BlockId(POSE, a), 0, 6), (BlockId(POSE, b), 6, 12), (BlockId(AFFINE, p), 12, 14)]
    if rolling_shutter:
        blocks += [(BlockId(RS, a), 14, 17), (BlockId(RS, b), 17, 20)]
    return blocks


def add_local_blocks(
    H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, blocks: list[list[tuple[BlockId, int, int]]],
    H_local: torch.Tensor, g_local: torch.Tensor,
) -> None:
    """Add every pair's local normal equations into H (D, D) and g (D,) in place, by one indexed accumulation.

    blocks[p]: pair p's blocks with their local column ranges ``(block, i0, i1)``; H_local (P, Dl, Dl), g_local
    (P, Dl) over those columns. A block that is not free in ``layout``, and a local column no block names, go to
    one extra, discarded, index. (Adding block by block is a dozen small tensor operations per block pair.)"""
    P, Dl = g_local.shape
    trash = layout.dim
    cols = []
    for pair_blocks in blocks:
        c = [trash] * Dl
        for block, i0, i1 in pair_blocks:
            sl = layout.slice(block)
            if sl is not None:
                c[i0:i1] = range(sl.start, sl.stop)
        cols.append(c)
    idx = torch.tensor(cols, device=H.device)  # (P, Dl)
    # index_add_ rather than index_put_(accumulate=True): on the CPU with more than one thread the latter adds the
    # duplicates (a pose shared by several pairs) in an order that changes from run to run, and the window's
    # solves, hence the whole trajectory, differed between two runs of the same sequence (2 threads).
    n = trash + 1
    H_ext = H.new_zeros(n * n)
    g_ext = g.new_zeros(n)
    H_ext.index_add_(0, (idx[:, :, None] * n + idx[:, None, :]).reshape(-1), H_local.to(H.dtype).reshape(-1))
    g_ext.index_add_(0, idx.reshape(-1), g_local.to(g.dtype).reshape(-1))
    H += H_ext.view(n, n)[:trash, :trash]
    g += g_ext[:trash]


def assemble(
    terms: PairTerms,
    pairs: torch.Tensor,
    poses: torch.Tensor,
    level: LevelData,
    layout: VariableLayout,
    clock: Clock = NO_CLOCK,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> H (D, D), g (D,) over the free blocks of ``layout`` (D = layout.dim), in the dtype of the terms.

    terms from :func:`codeslam.sfm.residuals.pair_jacobians`; pairs (P, 2); poses (F, 4, 4) at which the terms were
    evaluated; ``level`` supplies J_A. Fixed blocks are constants: their products are skipped. ``clock`` times the
    J^T W J products as the stage 'gemm' (:mod:`codeslam.clock`).
    """
    dev, dtype = terms.r.device, terms.r.dtype
    P, T, N = terms.r.shape
    F_, C = level.num_frames, level.code_size
    H = torch.zeros(layout.dim, layout.dim, dtype=dtype, device=dev)
    g = torch.zeros(layout.dim, dtype=dtype, device=dev)
    iA = pairs[:, 0]
    pair_list = [(int(a), int(b)) for a, b in pairs.tolist()]  # host copy: one transfer, no per-pair syncs
    w, r = terms.w, terms.r  # (P, T, N)
    rs = terms.J_rs is not None
    # (P, L, T, N) dense columns [xi_BA, a, b] (L = 8), then [omega_A, omega_B] with a rolling shutter (L = 14)
    Jd = terms.J_local
    L = Jd.shape[1]
    # (F, N, C) J_A of every frame, a view of the channels-last copy: the pixel rows that the geometric term
    # picks for H_{c_A c_B} are gathered as whole rows (measured at C = 128, 8,000 of 12,288 pixels, one thread:
    # 2.3 ms for the columns of the (C, N) layout, 0.35 ms for the rows of this one)
    Gt = level.jac_channels_last.permute(0, 2, 3, 1).reshape(F_, N, C)

    with clock("gemm"):
        Jd_flat = Jd.reshape(P, L, T * N)
        H_dd = Jd_flat @ (w.reshape(P, 1, T * N) * Jd_flat).transpose(1, 2)  # (P, L, L)
    g_d = batched_mv(Jd_flat, (w * r).reshape(P, T * N))  # (P, L)
    Q = local_to_absolute(poses.to(dtype), pairs, rs)  # (P, L, L + 6)
    H_loc = Q.transpose(1, 2) @ H_dd @ Q  # (P, L + 6, L + 6) over [pose A, pose B, affine, (rs A, rs B)]
    g_loc = (Q.transpose(1, 2) @ g_d.unsqueeze(-1)).squeeze(-1)  # (P, L + 6)

    # ---- codes of A: one product per frame over all pairs in which it is A ---------------------------------
    K = Q.shape[-1]  # local columns [pose A, pose B, affine, (rs A, rs B)]
    code_A_free = [layout.slice(BlockId(CODE, f)) for f in range(F_)]
    frames = sorted({a for a, _ in pair_list if code_A_free[a] is not None})  # free codes that appear as A
    # Every pair's blocks go into one local matrix over [local columns, code A, code B], added to H by one
    # indexed accumulation below (block by block: ~40 small operations per pair; measured on captured 6-pair TUM
    # windows, 2 threads, the assembly 6.7 -> 5.8 ms at 32x24 and 35.3 -> 33.9 ms at 128x96).
    Dl = K + 2 * C
    Hl = H.new_zeros(P, Dl, Dl)
    gl = g.new_zeros(P, Dl)
    Hl[:, :K, :K] = H_loc
    gl[:, :K] = g_loc
    if frames:
        ws_A = w * terms.s_A  # (P, T, N)
        onehot = torch.nn.functional.one_hot(iA, F_).to(dtype).transpose(0, 1)  # (F, P): sums pairs per frame A
        q = onehot @ (ws_A * terms.s_A).sum(1)  # (F, N), sum over pairs and types of w s_A^2
        gr = onehot @ (ws_A * r).sum(1)  # (F, N), sum of w s_A r
        M = (ws_A.unsqueeze(1) * Jd).sum(2)  # (P, L, N), w s_A J_dense summed over types
        H_Ad = H.new_zeros(P, C, L)
        for f in frames:
            sl = code_A_free[f]
            with clock("gemm"):
                H[sl, sl] += Gt[f].T @ (Gt[f] * q[f].unsqueeze(-1))  # J_A^T diag(q) J_A, (C, C)
            g[sl] += Gt[f].T @ gr[f]
            at = torch.nonzero(iA == f).squeeze(1)  # the pairs in which f is A
            with clock("gemm"):  # J_A^T (w s_A J_dense), (C, L) per pair
                H_Ad[at] = (M[at].reshape(-1, N) @ Gt[f]).reshape(len(at), L, C).transpose(1, 2)
        H_Aloc = H_Ad @ Q  # (P, C, K)
        Hl[:, K:K + C, :K] = H_Aloc
        Hl[:, :K, K:K + C] = H_Aloc.transpose(1, 2)

    # ---- codes of B through the geometric residual's J_B[v] -------------------------------------------------
    if terms.JB_w is not None and GEOMETRIC in terms.types:
        tg = terms.types.index(GEOMETRIC)
        # (P, 4, N): w, s_A, s_B and r of the geometric rows, each pair's gathered at its weighted pixels in one
        # indexing (four of them took 0.06 ms each, 12 pairs, 2 threads)
        geo = torch.stack([w[:, tg], terms.s_A[:, tg], terms.s_B[:, tg], r[:, tg]], dim=1)
        for p, (a, b) in enumerate(pair_list):
            if layout.slice(BlockId(CODE, b)) is None:
                continue
            JB, k = terms.JB_w[p], terms.JB_idx[p]  # (C, M), J_B[v]^T at the M pixels with geometric weight
            wk, sAk, sBk, rk = geo[p][:, k]
            with clock("gemm"):
                Hl[p, K + C:, K + C:] = (JB * (wk * sBk * sBk)) @ JB.T  # J_B[v]^T diag(w s_B^2) J_B[v]
                H_Bloc = ((Jd[p, :, tg].index_select(1, k) * (wk * sBk)) @ JB.T).T @ Q[p]  # (C, K)
                if code_A_free[a] is not None:  # J_A^T diag(w s_A s_B) J_B[v]
                    GA = Gt[a].index_select(0, k).mul_((wk * sAk * sBk).unsqueeze(-1))  # (M, C)
                    H_AB = GA.T @ JB.T
                    Hl[p, K:K + C, K + C:] = H_AB
                    Hl[p, K + C:, K:K + C] = H_AB.T
            Hl[p, K + C:, :K] = H_Bloc
            Hl[p, :K, K + C:] = H_Bloc.T
            gl[p, K + C:] = JB @ (wk * sBk * rk)

    # ---- every pair's local matrix into H at once --------------------------------------------------------------
    add_local_blocks(H, g, layout, [_local_blocks(a, b, p, rs) + [(BlockId(CODE, a), K, K + C),
                                                                   (BlockId(CODE, b), K + C, K + 2 * C)]
                                    for p, (a, b) in enumerate(pair_list)], Hl, gl)
    return H, g


def dense_jacobian(terms: PairTerms, pairs: torch.Tensor, poses: torch.Tensor, level: LevelData,
                   layout: VariableLayout) -> torch.Tensor:
    """The full Jacobian (P T N, D) of the stacked residuals ``r.reshape(-1)`` w.r.t. the free blocks, expanded
    from the compact form. Memory-hungry: for tests and for comparing against autograd, never for solving."""
    P, T, N = terms.r.shape
    C = level.code_size
    J = torch.zeros(P, T, N, layout.dim, dtype=terms.r.dtype, device=terms.r.device)
    rs = terms.J_rs is not None
    Q = local_to_absolute(poses.to(terms.r.dtype), pairs, rs)
    J_loc = terms.J_rows @ Q.unsqueeze(1)
    G = level.jac.reshape(level.num_frames, C, N).transpose(1, 2)  # (F, N, C)
    for p, (a, b) in enumerate(pairs.tolist()):
        for bid, i0, i1 in _local_blocks(a, b, p, rs):
            sl = layout.slice(bid)
            if sl is not None:
                J[p, :, :, sl] += J_loc[p, :, :, i0:i1]
        sA, sB = layout.slice(BlockId(CODE, a)), layout.slice(BlockId(CODE, b))
        if sA is not None:
            J[p, :, :, sA] += terms.s_A[p].unsqueeze(-1) * G[a]
        if sB is not None and terms.JB_w is not None:
            k = terms.JB_idx[p]  # the geometric residual's rows with weight (its others are zero)
            J[p, :, k, sB] += terms.s_B[p][:, k].unsqueeze(-1) * terms.JB_w[p].T
    return J.reshape(P * T * N, layout.dim)
