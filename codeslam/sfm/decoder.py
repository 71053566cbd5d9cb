"""The linear depth-decoder interface the optimiser sees, and a stand-in that needs no network.

With a linear decoder (paper Sec. 2.1, "identity activations") the decoded proximity of a keyframe is exactly
affine in its code on every pyramid level l::

    prox_l(c) = prox0_l + J_l c,        J_l = d prox_l / d c   (C images)

so ``J_l`` is computed once per keyframe (paper Sec. 4.1) and the optimiser never calls the network. The network
package builds a :class:`LinearDecoder` from its outputs (:meth:`LinearDecoder.from_levels`); tests and
benchmarks use :func:`standin_decoder`, whose Jacobian is a smooth cosine basis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import kornia
import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.image import image_pyramid
from codeslam.geometry.proximity import depth_to_prox, prox_to_depth


@dataclass(frozen=True)
class DecoderLevel:
    """One pyramid level of a linear decoder.

    Attributes:
        prox0: (H, W) proximity at the zero code.
        jac: (C, H, W) d prox / d code.
        uncertainty: (H, W) the network's Laplace scale b of the proximity, or None.
    """

    prox0: torch.Tensor
    jac: torch.Tensor
    uncertainty: torch.Tensor | None = None


@dataclass(frozen=True)
class LinearDecoder:
    """``prox_l(c) = prox0_l + J_l c`` for the levels l = 0 (finest), 1, ... of one keyframe (each level halves
    the size, as :func:`codeslam.geometry.image.image_pyramid`), with average depth ``avg_depth`` (Eq. 4)."""

    levels: tuple[DecoderLevel, ...]
    avg_depth: float

    def __post_init__(self) -> None:
        if not self.levels:
            raise CodeSLAMError("a linear decoder needs at least one pyramid level")
        if not self.avg_depth > 0:
            raise CodeSLAMError(f"average depth must be positive, got {self.avg_depth}")
        C = self.levels[0].jac.shape[0]
        H, W = self.levels[0].prox0.shape
        for k, lvl in enumerate(self.levels):
            h, w = lvl.prox0.shape
            if lvl.prox0.dim() != 2 or lvl.jac.dim() != 3 or lvl.jac.shape != (C, h, w):
                raise CodeSLAMError(
                    f"decoder level {k}: prox0 {tuple(lvl.prox0.shape)} and jac {tuple(lvl.jac.shape)} must be "
                    f"(H, W) and ({C}, H, W)"
                )
            if (h, w) != (H >> k, W >> k):
                raise CodeSLAMError(f"decoder level {k} is {h}x{w}, expected {H >> k}x{W >> k} (half per level)")
            if lvl.uncertainty is not None and lvl.uncertainty.shape != (h, w):
                raise CodeSLAMError(f"decoder level {k}: uncertainty must be {h}x{w}")

    @classmethod
    def from_levels(
        cls,
        prox0: list[torch.Tensor],
        jac: list[torch.Tensor],
        avg_depth: float,
        uncertainty: list[torch.Tensor] | None = None,
    ) -> LinearDecoder:
        """From per-level network outputs, finest first: prox0 (1, 1, H, W) | (1, H, W) | (H, W), jac
        (1, C, H, W) | (C, H, W), uncertainty like prox0 or None."""
        if len(prox0) != len(jac) or (uncertainty is not None and len(uncertainty) != len(prox0)):
            raise CodeSLAMError("decoder outputs: prox0, jac and uncertainty need the same number of levels")
        levels = []
        for k in range(len(prox0)):
            p = prox0[k].reshape(prox0[k].shape[-2:])
            J = jac[k].reshape(jac[k].shape[-3:])
            b = None if uncertainty is None else uncertainty[k].reshape(uncertainty[k].shape[-2:])
            levels.append(DecoderLevel(p, J, b))
        return cls(tuple(levels), float(avg_depth))

    @property
    def code_size(self) -> int:
        return self.levels[0].jac.shape[0]

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def prox(self, code: torch.Tensor, level: int = 0) -> torch.Tensor:
        """code (C,) -> (H_l, W_l) proximity ``prox0 + J c``."""
        lvl = self.levels[level]
        return lvl.prox0 + torch.einsum("chw,c->hw", lvl.jac, code.to(lvl.jac.dtype))

    def depth(self, code: torch.Tensor, level: int = 0) -> torch.Tensor:
        """code (C,) -> (H_l, W_l) depth in metres (Eq. 4 inverted, clamped proximity)."""
        return prox_to_depth(self.prox(code, level), self.avg_depth)

    def principal(self, k: int) -> tuple[LinearDecoder, torch.Tensor | None]:
        """The decoder restricted to the ``k`` directions of its code that move the finest level's proximity
        most: ``(decoder', U)`` with U (C, k) the leading eigenvectors of ``J_0 J_0^T`` (orthonormal, largest
        eigenvalue first) and ``decoder'`` the decoder of a code z (k,) with ``prox'_l(z) = prox_l(U z)`` on every
        level. As U is orthonormal, ``|z|^2 = |U z|^2``: the VAE's code prior keeps its form. ``(self, None)``
        when ``k >= C``.

        Written by hand (a change of variables) for a measured reason: the window's normal equations cost C^2 per
        pixel and pair, while the shipped network's J_0 has 99.4% of its energy in 32 of its 128 directions and
        99.95% in 64 (TUM fr1/rpy and the HoloLens walk, three frames each)."""
        C = self.code_size
        if k >= C:
            return self, None
        if k < 1:
            raise CodeSLAMError(f"a code subspace needs at least one direction, got {k}")
        J = self.levels[0].jac.reshape(C, -1).to(torch.float64)
        _, vecs = torch.linalg.eigh(J @ J.T)  # ascending eigenvalues
        U = vecs[:, -k:].flip(1)  # (C, k), largest first
        Ut = U.to(self.levels[0].jac.dtype)
        levels = tuple(DecoderLevel(lv.prox0, torch.einsum("ck,chw->khw", Ut, lv.jac), lv.uncertainty)
                       for lv in self.levels)
        return LinearDecoder(levels, self.avg_depth), Ut

    def to(self, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> LinearDecoder:
        def cv(t):
            return None if t is None else t.to(dtype=dtype, device=device)

        levels = tuple(DecoderLevel(cv(lv.prox0), cv(lv.jac), cv(lv.uncertainty)) for lv in self.levels)
        return LinearDecoder(levels, self.avg_depth)


@dataclass(frozen=True)
class ScaledDecoder(LinearDecoder):
    """A linear decoder whose code has one more entry, a log scale ``s`` of the decoded depth, applied exactly:
    ``D(c, s) = exp(s) D(prox0 + J c)`` (``window.free_scale``: a keyframe's scale the window moves apart from its
    code). Not in the paper; a change of variables written by hand (the scale is not linear in proximity).

    :meth:`prox` returns the proximity of the scaled depth at the same ``avg_depth``, so every consumer of
    ``prox`` and ``depth`` (the tracker's keyframe, the map's depths) sees the scaled depth. Each level's ``jac``
    has one more channel for the scale, a zero placeholder here: the window's stacked levels hold its value at the
    current code (:meth:`~codeslam.sfm.keyframes.LevelData.refresh_scale_column`), where the depth is scaled
    through the average depth instead (:meth:`~codeslam.sfm.keyframes.LevelData.avg_depth_at`)."""

    @classmethod
    def wrap(cls, decoder: LinearDecoder) -> ScaledDecoder:
        """``decoder`` with the scale entry appended to its code (0: the depth unscaled)."""
        levels = tuple(DecoderLevel(lv.prox0, torch.cat([lv.jac, torch.zeros_like(lv.jac[:1])]), lv.uncertainty)
                       for lv in decoder.levels)
        return cls(levels, decoder.avg_depth)

    def prox(self, code: torch.Tensor, level: int = 0) -> torch.Tensor:
        """code (C + 1,) -> (H_l, W_l) the proximity, at ``avg_depth``, of ``exp(s) D(prox0 + J c)``."""
        lvl = self.levels[level]
        code = code.to(lvl.jac.dtype)
        p = lvl.prox0 + torch.einsum("chw,c->hw", lvl.jac[:-1], code[:-1])
        if float(code[-1]) == 0.0:
            return p
        return depth_to_prox(prox_to_depth(p, self.avg_depth) * torch.exp(code[-1]), self.avg_depth)

    @staticmethod
    def scale_column(prox: torch.Tensor) -> torch.Tensor:
        """The scale's Jacobian column in proximity at the linear proximity ``prox``: with the depth read at the
        average depth ``a' = a exp(s)``, ``d D / d s = D = (d D / d p) (-p (1 - p))``, so the residuals' compact
        form ``(d r / d p) J`` holds the scale with the column ``-p (1 - p)`` (and ``d D / d p`` taken at a')."""
        return -prox * (1.0 - prox)

    def principal(self, k: int):
        """Not defined: take the principal directions first, then wrap (:meth:`wrap`)."""
        raise CodeSLAMError("a scaled decoder is made from the principal one, not the other way round")

    def to(self, dtype=None, device=None) -> ScaledDecoder:
        """The same decoder in ``dtype`` on ``device``, still scaled."""
        plain = LinearDecoder.to(self, dtype, device)
        return ScaledDecoder(plain.levels, plain.avg_depth)


def cosine_basis(
    code_size: int, height: int, width: int, dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """(C, H, W) the ``code_size`` lowest-frequency 2D DCT-II images (constant first), ordered by kx + ky then
    kx, each of unit RMS: smooth functions that can represent low-frequency depth corrections."""
    n = math.ceil(math.sqrt(2 * code_size)) + 1
    freqs = sorted(((kx, ky) for kx in range(n) for ky in range(n)), key=lambda f: (f[0] + f[1], f[0]))[:code_size]
    u = (torch.arange(width, dtype=dtype, device=device) + 0.5) / width  # pixel centres in (0, 1)
    v = (torch.arange(height, dtype=dtype, device=device) + 0.5) / height
    imgs = []
    for kx, ky in freqs:
        img = torch.cos(math.pi * kx * u)[None, :] * torch.cos(math.pi * ky * v)[:, None]  # (H, W)
        imgs.append(img / img.square().mean().sqrt())
    return torch.stack(imgs)


def standin_decoder(
    prox_target: torch.Tensor,
    code_size: int,
    num_levels: int,
    avg_depth: float,
    code_offset: torch.Tensor | None = None,
    basis_scale: float = 0.05,
    blur_sigma: float = 3.0,
    image: torch.Tensor | None = None,
) -> LinearDecoder:
    """A network-free linear decoder for tests and benchmarks.

    prox_target (H, W): the proximity the decoder should be able to reach. J = ``basis_scale`` times the cosine
    basis (times ``0.5 + image`` when a grey image (H, W) is given, so the Jacobian depends on the image as the
    network's does). prox0 = ``prox_target - J code_offset`` when ``code_offset`` (C,) is given (the target is
    then exactly in the span, reached at c = code_offset), else a Gaussian blur of the target (the target is
    only approximately reachable). Coarser levels are the image pyramid of prox0 and J, which is linear, so
    ``prox_l(c)`` is the pyramid of ``prox_0(c)``. The target must be hole-free (the blur and the pyramid would
    mix the invalid proximity 0 into its neighbours), like the network's output.
    """
    H, W = prox_target.shape
    jac = basis_scale * cosine_basis(code_size, H, W, prox_target.dtype, prox_target.device)
    if image is not None:
        jac = jac * (0.5 + image.to(jac.dtype))[None]
    if code_offset is not None:
        prox0 = prox_target - torch.einsum("chw,c->hw", jac, code_offset.to(jac.dtype))
    else:
        k = 2 * math.ceil(3 * blur_sigma) + 1
        prox0 = kornia.filters.gaussian_blur2d(
            prox_target[None, None], (k, k), (blur_sigma, blur_sigma), border_type="replicate"
        )[0, 0]
    stack = torch.cat([prox0[None], jac])[None]  # (1, 1 + C, H, W)
    levels = tuple(DecoderLevel(s[0, 0], s[0, 1:]) for s in image_pyramid(stack, num_levels))
    return LinearDecoder(levels, float(avg_depth))


def fit_code_linear(
    prox0: torch.Tensor, jac: torch.Tensor, target: torch.Tensor, weight: torch.Tensor, prior_weight: float = 1.0
) -> torch.Tensor:
    """The code minimising ``0.5 sum w (t - p0 - J c)^2 + 0.5 prior |c|^2`` (linear least squares with the VAE
    prior N(0, I)): ``(J^T W J + prior I) c = J^T W (t - p0)``, solved by Cholesky in float64.

    prox0 (B, 1, H, W), jac (B, C, H, W), target (B, 1, H, W), weight (B, 1, H, W) >= 0 (0 masks a pixel)
    -> code (B, C) in jac's dtype.
    """
    if not prior_weight > 0:
        raise ValueError(f"the code prior weight must be positive (it keeps the system definite), got {prior_weight}")
    B, C = jac.shape[:2]
    J = jac.double().flatten(2)  # (B, C, N)
    w = weight.double().flatten(2)  # (B, 1, N)
    r = (target.double() - prox0.double()).flatten(2)  # (B, 1, N)
    A = (J * w) @ J.transpose(1, 2)  # (B, C, C) J^T W J
    A = A + prior_weight * torch.eye(C, dtype=A.dtype, device=A.device)
    rhs = ((J * w) @ r.transpose(1, 2))  # (B, C, 1) J^T W r
    L = torch.linalg.cholesky(A)
    return torch.cholesky_solve(rhs, L)[..., 0].to(jac.dtype)  # (B, C)
