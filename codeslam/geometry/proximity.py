"""Proximity, the paper's hybrid depth parametrisation (Sec. 2.2, Eq. 4): ``p = a / (d + a)``.

``a`` is the average depth: depths in [0, a] map to proximities in [0.5, 1] (like depth), depths in [a, inf)
to [0, 0.5] (like inverse depth). ``a`` may be a float or a tensor broadcastable against the depth.

Invalid values: a depth that is not finite or not positive (the datasets' 0 = "no measurement") maps to
proximity 0, and proximity 0 (or non-finite) decodes back to depth 0, so the "invalid" sentinel survives a
round trip. Every other proximity is clamped to [MIN_PROXIMITY, MAX_PROXIMITY] before decoding, so a decoder
output that is slightly negative or above 1 (a linear decoder can produce both) still decodes to a finite
positive depth; the derivatives below are those of the clamped function (0 where the clamp is active).
"""

from __future__ import annotations

import torch

from codeslam.constants import MAX_PROXIMITY, MIN_PROXIMITY


def _valid_depth(depth: torch.Tensor) -> torch.Tensor:
    """(...) bool: finite and positive."""
    return torch.isfinite(depth) & (depth > 0)


def _valid_prox(prox: torch.Tensor) -> torch.Tensor:
    """(...) bool: finite and not the invalid sentinel 0."""
    return torch.isfinite(prox) & (prox != 0)


def depth_to_prox(depth: torch.Tensor, a: float | torch.Tensor) -> torch.Tensor:
    """Depth (...) in metres -> proximity (...) in (0, 1]; invalid depth -> 0."""
    valid = _valid_depth(depth)
    d = torch.where(valid, depth, torch.ones_like(depth))  # safe value keeps gradients finite
    return torch.where(valid, a / (d + a), torch.zeros_like(depth))  # Eq. 4


def d_prox_d_depth(depth: torch.Tensor, a: float | torch.Tensor) -> torch.Tensor:
    """Elementwise derivative of :func:`depth_to_prox`, (...): ``-a / (d + a)^2`` (0 at invalid depth)."""
    valid = _valid_depth(depth)
    d = torch.where(valid, depth, torch.ones_like(depth))
    return torch.where(valid, -a / (d + a) ** 2, torch.zeros_like(depth))


def prox_to_depth(prox: torch.Tensor, a: float | torch.Tensor) -> torch.Tensor:
    """Proximity (...) -> depth (...) ``d = a (1 - p) / p`` (Eq. 4 inverted) with ``p`` clamped to
    [MIN_PROXIMITY, MAX_PROXIMITY]; proximity 0 or non-finite -> depth 0 (invalid)."""
    valid = _valid_prox(prox)
    p = torch.where(valid, prox, torch.ones_like(prox)).clamp(MIN_PROXIMITY, MAX_PROXIMITY)
    return torch.where(valid, a * (1 - p) / p, torch.zeros_like(prox))


def d_depth_d_prox(prox: torch.Tensor, a: float | torch.Tensor) -> torch.Tensor:
    """Elementwise derivative of :func:`prox_to_depth`, (...): ``-a / p^2`` inside the clamp range, 0 where
    the clamp is active or the proximity is invalid."""
    valid = _valid_prox(prox)
    p = torch.where(valid, prox, torch.ones_like(prox))
    inside = valid & (p >= MIN_PROXIMITY) & (p <= MAX_PROXIMITY)
    return torch.where(inside, -a / p**2, torch.zeros_like(prox))
