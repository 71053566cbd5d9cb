"""The optimisation variables: their values (:class:`SfMState`), which of them are free and where they sit in
the normal equations (:class:`VariableLayout`), and a linear prior on a subset of them (:class:`LinearPrior`,
e.g. the result of marginalising old keyframes in a sliding window).

Blocks: ``pose`` i (6, left increment of T_wc i, ``T <- exp(xi) T``), ``code`` i (C, additive), ``affine``
p (2: log-gain and bias of pair p, additive) and, with a rolling-shutter model, ``rs`` i (3, additive: frame i's
rotation over its readout, see :mod:`codeslam.sfm.residuals`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.lie import se3_adjoint, se3_exp, se3_inverse, se3_log

POSE, CODE, AFFINE, RS = "pose", "code", "affine", "rs"
POSE_DIM, AFFINE_DIM, RS_DIM = 6, 2, 3


@dataclass(frozen=True, order=True)
class BlockId:
    """A variable block: ``kind`` in (pose, code, affine, rs) and the frame (pose, code, rs) or pair (affine)
    index."""

    kind: str
    index: int


@dataclass
class SfMState:
    """Values of all variables. poses (F, 4, 4) T_wc, codes (F, C), affine (P, 2) = (log-gain a, bias b) of the
    brightness model ``I_A ~ exp(a) I_B + b`` of each pair; rs (F, 3) each frame's rotation over its readout, or
    None without a rolling-shutter model."""

    poses: torch.Tensor
    codes: torch.Tensor
    affine: torch.Tensor
    rs: torch.Tensor | None = None

    def clone(self) -> SfMState:
        return SfMState(self.poses.clone(), self.codes.clone(), self.affine.clone(),
                        None if self.rs is None else self.rs.clone())

    def block(self, b: BlockId) -> torch.Tensor:
        """The value of one block: (4, 4) pose, (C,) code, (2,) affine or (3,) rs."""
        return {POSE: self.poses, CODE: self.codes, AFFINE: self.affine, RS: self.rs}[b.kind][b.index]

    def retract(self, layout: VariableLayout, delta: torch.Tensor) -> SfMState:
        """The state moved by ``delta`` (layout.dim,): ``T <- exp(xi) T`` for poses, ``+`` for the rest."""
        new = self.clone()
        for b, sl in layout.slices():
            d = delta[sl].to(self.poses.dtype)
            if b.kind == POSE:
                new.poses[b.index] = se3_exp(d) @ self.poses[b.index]
            elif b.kind == CODE:
                new.codes[b.index] = self.codes[b.index] + d
            elif b.kind == RS:
                new.rs[b.index] = self.rs[b.index] + d
            else:
                new.affine[b.index] = self.affine[b.index] + d
        return new

    def local_difference(self, b: BlockId, value0: torch.Tensor) -> torch.Tensor:
        """``x ominus x0`` of one block, inverse of :meth:`retract`: ``log(T T0^-1)`` for poses, ``x - x0``
        otherwise."""
        x = self.block(b)
        return se3_log(x @ se3_inverse(value0)) if b.kind == POSE else x - value0


class VariableLayout:
    """The free blocks, in order, and their offsets in the stacked increment vector."""

    def __init__(self, blocks: Sequence[tuple[BlockId, int]]) -> None:
        self.blocks = list(blocks)
        self._offset: dict[BlockId, tuple[int, int]] = {}
        o = 0
        for b, size in self.blocks:
            if b in self._offset:
                raise ValueError(f"block {b} appears twice in the layout")
            self._offset[b] = (o, size)
            o += size
        self.dim = o

    @classmethod
    def for_sfm(
        cls, num_frames: int, code_size: int, num_pairs: int, affine: bool, fixed: Iterable[BlockId] = (),
        rolling_shutter: bool = False,
    ) -> VariableLayout:
        """Poses and codes of every frame, affine parameters of every pair (if ``affine``) and every frame's
        readout rotation (if ``rolling_shutter``), minus ``fixed`` (e.g. ``[BlockId('pose', 0)]``, the gauge)."""
        fixed = set(fixed)
        blocks = [(BlockId(POSE, i), POSE_DIM) for i in range(num_frames)]
        blocks += [(BlockId(CODE, i), code_size) for i in range(num_frames)]
        if affine:
            blocks += [(BlockId(AFFINE, p), AFFINE_DIM) for p in range(num_pairs)]
        if rolling_shutter:
            blocks += [(BlockId(RS, i), RS_DIM) for i in range(num_frames)]
        return cls([(b, s) for b, s in blocks if b not in fixed])

    def __contains__(self, b: BlockId) -> bool:
        return b in self._offset

    def slice(self, b: BlockId) -> slice | None:
        """The block's slice of the increment vector, or None when the block is not free."""
        if b not in self._offset:
            return None
        o, s = self._offset[b]
        return slice(o, o + s)

    def slices(self) -> list[tuple[BlockId, slice]]:
        return [(b, self.slice(b)) for b, _ in self.blocks]

    def indices(self, blocks: Iterable[BlockId]) -> torch.Tensor:
        """Long tensor of the increment-vector indices of ``blocks`` (in the given order)."""
        idx = []
        for b in blocks:
            sl = self.slice(b)
            if sl is None:
                raise CodeSLAMError(f"variable block {b.kind} {b.index} is not free in this problem")
            idx.extend(range(sl.start, sl.stop))
        return torch.tensor(idx, dtype=torch.long)


@dataclass
class LinearPrior:
    """A quadratic prior ``0.5 d^T H d + b^T d`` on some blocks, ``d = x ominus x0`` stacked in ``blocks`` order
    (how a marginalised sliding window constrains the remaining keyframes).

    Attributes:
        blocks: the constrained blocks (all must be free in the layout the prior is used with).
        H: (k, k) symmetric positive semi-definite information matrix.
        b: (k,) gradient at the linearisation point.
        x0: the linearisation point of each block ((4, 4) pose, (C,) code, (2,) affine).
    """

    blocks: list[BlockId]
    H: torch.Tensor
    b: torch.Tensor
    x0: list[torch.Tensor]

    def delta(self, state: SfMState) -> torch.Tensor:
        """(k,) ``x ominus x0`` stacked. The pose blocks' logarithms are taken in one batch (one pose at a time,
        ``se3_log``'s ~40 tensor operations made this prior 2 ms of every window linearisation and cost)."""
        parts = [None if b.kind == POSE else state.local_difference(b, v0) for b, v0 in zip(self.blocks, self.x0)]
        at = [i for i, b in enumerate(self.blocks) if b.kind == POSE]
        if at:
            T = torch.stack([state.block(self.blocks[i]) for i in at])
            T0 = torch.stack([self.x0[i] for i in at])
            for i, xi in zip(at, se3_log(T @ se3_inverse(T0)).unbind(0)):  # log(T T0^-1), as local_difference
                parts[i] = xi
        return torch.cat(parts)

    def cost(self, state: SfMState) -> torch.Tensor:
        d = self.delta(state).to(self.H.dtype)
        return 0.5 * d @ self.H @ d + self.b @ d

    def moved(self, G: torch.Tensor) -> LinearPrior:
        """The same prior on a map moved rigidly by ``G`` (4, 4): every pose ``T <- G T``, the linearisation
        point's too. A pose block's difference ``log(T T0^-1)`` becomes ``log(G T T0^-1 G^-1) = Ad_G log(T
        T0^-1)``, exactly; so with ``A`` the block diagonal of ``Ad_G`` on the pose blocks and the identity on the
        others, ``H <- A^-T H A^-1`` and ``b <- A^-T b``, and the cost at every state moved alike is the cost
        before. Written by hand: SE(3)'s adjoint on a quadratic, nothing a library gives."""
        G = G.to(torch.float64)
        sizes = [6 if b.kind == POSE else int(x.numel()) for b, x in zip(self.blocks, self.x0)]
        Ad_inv = se3_adjoint(se3_inverse(G)).to(self.H.dtype)
        A_inv = torch.block_diag(*[Ad_inv if b.kind == POSE else torch.eye(n, dtype=self.H.dtype)
                                   for b, n in zip(self.blocks, sizes)]).to(self.H.device)
        x0 = [(G.to(dtype=x.dtype, device=x.device) @ x) if b.kind == POSE else x for b, x in zip(self.blocks, self.x0)]
        return LinearPrior(list(self.blocks), A_inv.T @ self.H @ A_inv, A_inv.T @ self.b, x0)

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        """Add the prior's Hessian and gradient (``b + H d``, with ``d(d)/d(increment) ~ I``) in place."""
        idx = layout.indices(self.blocks).to(H.device)
        d = self.delta(state).to(H.dtype)
        H_p = self.H.to(H.dtype)  # the prior may be kept in another precision than the normal equations
        H[idx[:, None], idx[None, :]] += H_p
        g[idx] += self.b.to(g.dtype) + H_p @ d
