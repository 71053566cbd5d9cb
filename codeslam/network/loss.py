"""The training loss (paper Sec. 2.1-2.2): Laplace negative log-likelihood of the ground-truth proximity on
four pyramid levels plus the KL divergence of the code posterior to N(0, I).

Normalisation, per batch::

    nll      = sum_l 4^l * sum_{valid pixels of level l} (|p - mu| / b + log b)  /  N_0
    kl       = mean over images of KL(N(mean, exp(logvar)) || N(0, I))
    nll_zero = nll with mu decoded from the zero code and b held fixed (no gradient to b)
    shape    = shape_error of the zero-code prediction (scale-free; see the function)
    loss     = nll + kl_weight * kl / (H * W) + zero_code_weight * nll_zero + shape_weight * shape

where N_0 is the number of valid pixels at the finest level. Level l has 4^-l times the pixels of level 0,
so the weight 4^l ("to account for the lower pixel count", Sec. 2.1) gives every level about the same
influence; dividing by N_0 makes ``nll`` a per-pixel quantity that does not depend on batch size or holes.
With ``kl_weight = 1`` the first two terms are the negative ELBO per finest-level pixel.

``nll_zero`` is not in the paper. The NLL cannot tell a code c from c - m with the decoder's first layer shifted
by J m, so only the KL keeps the codes centred on 0 and pushes what the image alone predicts into D(I, 0); on a
CPU budget that pressure is too weak (measured: after 500 steps the mean code over the validation images had
norm 12 and the zero-code proximity RMSE, 0.19, was worse than a constant's, 0.15, while the encoded code's was
0.067). The term trains the image-only prediction D(I, 0), which SLAM uses to initialise every keyframe, directly;
b is held fixed in it so that the uncertainty keeps describing the reconstruction with a code.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from codeslam.constants import MAX_PROXIMITY, MIN_PROXIMITY
from codeslam.geometry.image import depth_pyramid
from codeslam.geometry.proximity import depth_to_prox
from codeslam.network.config import NUM_LEVELS


class LossParts(NamedTuple):
    total: torch.Tensor  # () the optimised scalar
    nll: torch.Tensor  # () level-weighted Laplace NLL per finest-level valid pixel
    nll_levels: list[torch.Tensor]  # NUM_LEVELS x () mean NLL over the valid pixels of each level (for logging)
    kl: torch.Tensor  # () KL divergence per image (nats)
    nll_zero: torch.Tensor  # () level-weighted NLL of the zero-code prediction (0 when not computed)
    shape: torch.Tensor  # () the zero-code prediction's shape_error (0 when not computed)


def proximity_pyramid(depth: torch.Tensor, avg_depth: float, levels: int = NUM_LEVELS) -> list[torch.Tensor]:
    """Depth (B, 1, H, W) in metres, 0 = invalid -> ``levels`` proximity maps (B, 1, H / 2^l, W / 2^l), finest
    first, with 0 where no valid depth falls in the pixel. Depth is averaged over the valid children before the
    conversion (:func:`codeslam.geometry.image.depth_pyramid`), so holes never leak into valid pixels."""
    return [depth_to_prox(d, avg_depth) for d in depth_pyramid(depth, levels)]  # Eq. 4 on every level


def laplace_nll(prox: torch.Tensor, mu: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per-pixel negative log-likelihood of a Laplace distribution without its constant log 2 (Eq. 3):
    ``|p - mu| / b + log b``; all shapes equal, returns that shape."""
    return (prox - mu).abs() / b + torch.log(b)  # Eq. 3


def kl_to_standard_normal(mean: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mean, diag(exp(logvar))) || N(0, I)) per row: (B, C), (B, C) -> (B,)
    ``= 1/2 sum_i (mean_i^2 + exp(logvar_i) - 1 - logvar_i)`` (Kingma & Welling, App. B)."""
    return 0.5 * (mean.square() + logvar.exp() - 1.0 - logvar).sum(dim=-1)


def level_weight(level: int) -> float:
    """Weight of pyramid level ``level`` (0 = finest): x4 per coarser level (Sec. 2.1)."""
    return 4.0**level


def pyramid_nll(
    mu: list[torch.Tensor], b: list[torch.Tensor], prox: list[torch.Tensor]
) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Level-weighted Laplace NLL over the valid pixels, divided by N_0 -> (scalar, per-level means (detached)).
    mu, b, prox: NUM_LEVELS lists of (B, 1, H / 2^l, W / 2^l), finest first, ``prox`` 0 where invalid."""
    n_valid0 = (prox[0] > 0).sum().clamp_min(1)  # N_0
    nll = mu[0].new_zeros(())
    nll_levels = []
    for lvl, (m, s, p) in enumerate(zip(mu, b, prox, strict=True)):
        valid = p > 0  # (B, 1, h, w)
        per_px = torch.where(valid, laplace_nll(p, m, s), torch.zeros_like(m))
        level_sum = per_px.sum()
        nll = nll + level_weight(lvl) * level_sum
        nll_levels.append(level_sum.detach() / valid.sum().clamp_min(1))
    return nll / n_valid0, nll_levels


def _log_depth(prox: torch.Tensor) -> torch.Tensor:
    """``log D - log a`` of proximity ``p = a / (D + a)`` (Eq. 4 inverted), with p held inside (0, 1): the
    decoder's heads are not bounded, and a prediction outside gives no shape gradient (its NLL still pulls it)."""
    p = prox.clamp(MIN_PROXIMITY, MAX_PROXIMITY)
    return torch.log1p(-p) - torch.log(p)


def shape_error(mu: list[torch.Tensor], prox: list[torch.Tensor]) -> torch.Tensor:
    """The error of the predicted depth's shape alone, blind to its scale, summed over the levels (not in the paper).

    With ``R = log D(mu) - log D(prox)`` on the valid pixels of a level: the mean absolute difference of R between
    horizontal and between vertical neighbours that are both valid (gradient matching, Li & Snavely, MegaDepth, CVPR
    2018), plus the mean over images of R's variance (the scale-invariant log error of Eigen et al., NIPS 2014,
    with lambda = 1). Multiplying an image's predicted depth by any constant leaves both unchanged.
    mu, prox: NUM_LEVELS lists of (B, 1, H / 2^l, W / 2^l), ``prox`` 0 where invalid -> ()."""
    total = mu[0].new_zeros(())
    for m, p in zip(mu, prox, strict=True):
        valid = p > 0  # (B, 1, h, w)
        R = torch.where(valid, _log_depth(m) - _log_depth(torch.where(valid, p, 0.5)), 0.0)  # (B, 1, h, w)
        vx = valid[..., :, 1:] & valid[..., :, :-1]  # (B, 1, h, w - 1) both neighbours valid
        vy = valid[..., 1:, :] & valid[..., :-1, :]  # (B, 1, h - 1, w)
        gx = (R[..., :, 1:] - R[..., :, :-1]).abs() * vx
        gy = (R[..., 1:, :] - R[..., :-1, :]).abs() * vy
        total = total + gx.sum() / vx.sum().clamp_min(1) + gy.sum() / vy.sum().clamp_min(1)
        n = valid.flatten(1).sum(1).clamp_min(1)  # (B,) valid pixels per image
        mean = R.flatten(1).sum(1) / n  # (B,)
        var = (R.flatten(1).square().sum(1) / n - mean.square()).clamp_min(0.0)  # (B,)
        total = total + var.mean()
    return total


def network_loss(
    mu: list[torch.Tensor],
    b: list[torch.Tensor],
    prox: list[torch.Tensor],
    code_mean: torch.Tensor,
    code_logvar: torch.Tensor,
    kl_weight: float,
    mu_zero: list[torch.Tensor] | None = None,
    zero_code_weight: float = 0.0,
    prox_zero: list[torch.Tensor] | None = None,
    shape_weight: float = 0.0,
) -> LossParts:
    """The loss of one batch (see the module docstring).

    mu, b, prox: NUM_LEVELS lists of (B, 1, H / 2^l, W / 2^l), finest first, ``prox`` 0 where invalid (as from
    :func:`proximity_pyramid`); code_mean, code_logvar: (B, C); mu_zero: like mu, decoded from the zero code,
    needed when ``zero_code_weight`` or ``shape_weight`` > 0; prox_zero: the zero code's target when it is not
    ``prox`` (the code path's targets scaled, ``train.code_scale``); shape_weight: the weight of the zero code's
    :func:`shape_error` (``train.shape_weight``).
    """
    nll, nll_levels = pyramid_nll(mu, b, prox)
    kl = kl_to_standard_normal(code_mean, code_logvar).mean()
    H, W = prox[0].shape[-2:]
    total = nll + kl_weight * kl / (H * W)
    nll_zero = nll.new_zeros(())
    shape = nll.new_zeros(())
    if mu_zero is not None:
        target = prox if prox_zero is None else prox_zero
        nll_zero, _ = pyramid_nll(mu_zero, [s.detach() for s in b], target)
        total = total + zero_code_weight * nll_zero
        if shape_weight > 0:
            shape = shape_error(mu_zero, target)
            total = total + shape_weight * shape
    elif zero_code_weight > 0 or shape_weight > 0:
        raise ValueError("zero_code_weight or shape_weight > 0 needs mu_zero (forward with decode_zero=True)")
    return LossParts(total, nll, nll_levels, kl, nll_zero, shape)
