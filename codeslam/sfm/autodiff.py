"""The same normal equations by automatic differentiation: a reference for the analytic Jacobians (tests) and the
baseline of ``benchmarks/bench_sfm_gn.py`` (what an autograd implementation of CodeSLAM does).

The residuals are those of :func:`codeslam.sfm.residuals.evaluate_pairs` at the state moved by an increment
``delta`` (:meth:`SfMState.retract`, written with differentiable ops here); the dense Jacobian of the weighted
residuals w.r.t. ``delta`` at 0 is taken with ``torch.func.jacfwd`` (D forward passes, D = number of free
variables, far fewer than the P T N residuals), then ``H = J^T J``. ``grid_sample`` has no forward-mode
derivative in torch, so the lookups here use :func:`bilinear_sample_gather`, the same interpolation written with
``gather`` (reverse mode, ``jacrev``, would need one backward pass per residual: far slower). Masks and weights
are held at the current state, as in the analytic path. Autograd through the bilinear lookup differentiates the
bilinear interpolant, so this matches the analytic Jacobians with ``gradient_mode='interpolant'`` exactly.
"""

from __future__ import annotations

import torch

from codeslam.clock import NO_CLOCK, Clock
from codeslam.geometry.image import inside_image
from codeslam.geometry.lie import se3_exp
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import LevelData
from codeslam.sfm.residuals import evaluate_pairs, robust_weights
from codeslam.sfm.variables import AFFINE, CODE, POSE, RS, BlockId, SfMState, VariableLayout


def bilinear_sample_gather(img: torch.Tensor, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear lookup with the semantics of :func:`codeslam.geometry.image.bilinear_sample` (zero padding,
    pixel-centre coordinates) built from ``gather``, which supports forward-mode autograd (``grid_sample`` does
    not). img (B, C, H, W), uv (B, N, 2) -> values (B, C, N), valid (B, N)."""
    B, C, H, W = img.shape
    u, v = uv.unbind(-1)  # (B, N)
    u0, v0 = torch.floor(u).detach(), torch.floor(v).detach()
    fu, fv = u - u0, v - v0
    flat = img.reshape(B, C, H * W)
    out = torch.zeros((), dtype=img.dtype, device=img.device)
    for du, dv, wgt in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        x, y = u0 + du, v0 + dv
        inside = (x >= 0) & (x <= W - 1) & (y >= 0) & (y <= H - 1)
        idx = (y.clamp(0, H - 1) * W + x.clamp(0, W - 1)).long()  # (B, N)
        vals = flat.gather(2, idx.unsqueeze(1).expand(B, C, idx.shape[-1]))  # (B, C, N)
        out = out + vals * (wgt * inside).unsqueeze(1)
    return out, inside_image(uv, H, W)


def _shifted(values: torch.Tensor | None, kind: str, layout: VariableLayout, delta: torch.Tensor):
    """The rows of an additive block kind (codes, affine, rs) moved by their slices of ``delta``, without in-place
    writes; rows whose block is not free, and an empty or absent tensor, stay as they are."""
    if values is None or values.shape[0] == 0:
        return values
    rows = []
    for i in range(values.shape[0]):
        sl = layout.slice(BlockId(kind, i))
        rows.append(values[i] if sl is None else values[i] + delta[sl])
    return torch.stack(rows)


def retract_differentiable(state: SfMState, layout: VariableLayout, delta: torch.Tensor) -> SfMState:
    """:meth:`SfMState.retract` without in-place writes (so it can be differentiated and vmapped)."""
    poses = []
    dt = state.poses.dtype
    for i in range(state.poses.shape[0]):
        sl = layout.slice(BlockId(POSE, i))
        # exp in float64: torch's forward-mode AD through lie.se3_exp returns float64 tangents for float32
        # inputs (seen with torch 2.13), which then clash with the float32 pose.
        poses.append(state.poses[i] if sl is None else se3_exp(delta[sl].double()).to(dt) @ state.poses[i])
    return SfMState(torch.stack(poses), _shifted(state.codes, CODE, layout, delta),
                    _shifted(state.affine, AFFINE, layout, delta), _shifted(state.rs, RS, layout, delta))


def _evaluate(level: LevelData, pairs: torch.Tensor, state: SfMState, cfg: SfMConfig):
    affine = state.affine if cfg.affine_brightness else None
    return evaluate_pairs(level, pairs, state.poses, state.codes, affine, cfg, False, bilinear_sample_gather,
                          rs=state.rs)


def weighted_residual_fn(
    level: LevelData, pairs: torch.Tensor, state: SfMState, layout: VariableLayout, cfg: SfMConfig
):
    """-> (f, r0, w0): ``f(delta)`` = ``sqrt(w0) * r(state + delta)`` flattened (P T N,), with the IRLS weights
    w0 (P, T, N) and residuals r0 of the current state."""
    ev0 = _evaluate(level, pairs, state, cfg)
    w0, _ = robust_weights(ev0)
    sw = w0.sqrt()

    def f(delta: torch.Tensor) -> torch.Tensor:
        st = retract_differentiable(state, layout, delta)
        ev = _evaluate(level, pairs, st, cfg)
        return (sw * ev.r).reshape(-1)

    return f, ev0.r, w0


def _jacfwd(f, dim: int, like: torch.Tensor, chunk_size: int | None) -> torch.Tensor:
    """``torch.func.jacfwd(f)(0)`` as a vmap of JVPs over the basis vectors, ``chunk_size`` at a time (bounds the
    memory of the batched forward passes): -> (M, dim) for f: (dim,) -> (M,)."""
    zero = torch.zeros(dim, dtype=like.dtype, device=like.device)
    basis = torch.eye(dim, dtype=like.dtype, device=like.device)

    def column(t: torch.Tensor) -> torch.Tensor:
        return torch.func.jvp(f, (zero,), (t,))[1]

    return torch.func.vmap(column, chunk_size=chunk_size)(basis).transpose(0, 1)


def autodiff_jacobian(
    level: LevelData, pairs: torch.Tensor, state: SfMState, layout: VariableLayout, cfg: SfMConfig,
    chunk_size: int | None = None,
) -> torch.Tensor:
    """Jacobian (P T N, D) of the UNweighted residuals w.r.t. the free blocks, by forward-mode autograd."""

    def r(delta):
        return _evaluate(level, pairs, retract_differentiable(state, layout, delta), cfg).r.reshape(-1)

    return _jacfwd(r, layout.dim, state.codes, chunk_size)


def autodiff_normal_equations(
    level: LevelData, pairs: torch.Tensor, state: SfMState, layout: VariableLayout, cfg: SfMConfig,
    clock: Clock = NO_CLOCK, chunk_size: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> H (D, D) = J^T W J and g (D,) = J^T W r with J by forward-mode autograd (the baseline).
    ``clock`` times the final J^T J product as the stage 'gemm' (:mod:`codeslam.clock`)."""
    f, r0, w0 = weighted_residual_fn(level, pairs, state, layout, cfg)
    J = _jacfwd(f, layout.dim, state.codes, chunk_size)  # (P T N, D), rows already scaled by sqrt(w)
    with clock("gemm"):
        H = J.transpose(0, 1) @ J
    g = J.transpose(0, 1) @ (w0.sqrt() * r0).reshape(-1)
    return H, g
