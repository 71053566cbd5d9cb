"""A new keyframe's depth prior corrected by the map (not in the paper; added for a measured reason, below).

In the paper every keyframe starts from the network's zero-code depth ``D(I, 0)`` of its own image alone, and the
code prior holds the keyframe near it. The network's errors are view-dependent and mostly low-frequency: on the
generator's walks its zero code is a smooth layout nearer at every image border than in the middle, whatever the
room, and 93-95% of its log-depth error lies below a 4-pixel Gaussian (``docs/results/slam_table.md``, sessions of
2026-11-29 and 2026-11-30). The window corrects each keyframe's shape toward the truth while it holds it, but the
next keyframe starts again from the network's own view. Here the new keyframe's zero code is moved part of the way
toward the map: the newest window keyframe's current depth is splatted into the new view
(:func:`codeslam.geometry.splat.splat_depth`) and the low frequencies of its log-depth difference to the network's
zero code are added, with ``weight``, to the zero code's log depth. The difference is taken less its median, so the
map passes on shape only, never scale: a new keyframe started at the map's scale let every map shrink from keyframe
to keyframe (tenth and twentieth sessions), and the network's scale is what holds a monocular map's scale here.
The code's Jacobian and uncertainty are the network's, so the window corrects the new keyframe as before, only from
a better start and toward a better prior. As LSD-SLAM and DSO start a new keyframe's depth from the previous one's,
but as a prior beside the network's, not in its place: with the map's depth alone (weight 1, no low-pass) the
generator walk 42 went from 0.23 to 0.48 m.

Measured (``docs/results/slam_table.md``, session of 2026-12-02, twenty-eighth; ``window.map_prior_weight`` and
``map_prior_blur``): weight 0.35 with a low-pass of 8 pixels at 128x96 took the suite's 18 network runs to 0.913x
the ATE in geometric mean over two start frames; without the low-pass (the map's texture passed on) 0.98x, with the
map's depth alone 2.1x on walk 42. With the dataset's depth the walk towards a blank wall got 5.5x worse. The cause
(twenty-ninth session): the stand-in's true depth lies in its code's span by construction, and the pixel-wise
correction moves its prior off the span; ``in_span`` (``window.map_prior_span``) fits the correction by the code
instead, which gives the stand-in back its figures and takes the network's gain away (what the map corrects in the
network's prior is what its span cannot express).
"""

from __future__ import annotations

import dataclasses

import kornia
import torch

from codeslam.geometry.image import image_pyramid
from codeslam.geometry.proximity import depth_to_prox, prox_to_depth
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder, fit_code_linear

SPAN_RIDGE = 1e-3
"""Ridge of the least-squares fit of the map's correction by the code (``in_span``), relative to the mean diagonal
of ``J J^T``: keeps the fitted code finite where directions of the span barely change the depth."""

MIN_COVERAGE = 0.3
"""The share of the new view that the map's splatted depth must cover (valid pixels of both) for a correction;
below it the network's prior is kept as it is."""


def low_pass(x: torch.Tensor, weight: torch.Tensor, sigma: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised Gaussian convolution: (H, W) values ``x`` known where ``weight`` (H, W) is 1 -> their smooth
    average ``sum(G w x) / sum(G w)`` and the covered share ``sum(G w)`` (zero far from any known value)."""
    k = int(2 * round(3 * sigma) + 1)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return kornia.filters.gaussian_blur2d(t[None, None], (k, k), (sigma, sigma), border_type="constant")[0, 0]

    num, den = blur(torch.where(weight > 0, x, torch.zeros_like(x))), blur(weight)
    return num / den.clamp_min(1e-6), den


def map_prior(decoder: LinearDecoder, map_depth: torch.Tensor, weight: float, sigma: float,
              valid: torch.Tensor | None = None, in_span: bool = False) -> LinearDecoder:
    """The keyframe's decoder with its zero-code proximity moved toward the map (module docstring).

    decoder: the network's decoder of the new keyframe; map_depth: (H, W) the map's depth in the keyframe's view at
    the finest level, +inf where unknown (:func:`codeslam.geometry.splat.splat_depth`); weight: the share of the
    map's correction taken (0: the decoder unchanged); sigma: the low-pass Gaussian's width in finest-level pixels;
    valid: (H, W) where the keyframe's image holds real pixels (None: everywhere); in_span: take only the part of
    the correction that the keyframe's code can make (below).

    With ``e`` the map's log depth less the zero code's, less its median over the pixels both know, the new zero
    code's log depth is ``log D(I, 0) + weight * lowpass(e)`` (where the low-pass covers less than a fifth of a
    pixel's neighbourhood, nothing is added); the coarser levels get the finest level's change through the image
    pyramid. With ``in_span`` that change (in proximity) is fitted by the code, ``c = argmin |J_0 c - change|^2``
    with a small ridge, and every level l moves by its own ``J_l c``: the zero code becomes ``D(I, c)``, the code
    prior is re-centred on the map and any depth the network's span held it still holds. Jacobians and
    uncertainties are the network's."""
    if weight <= 0:
        return decoder
    log_d0 = prox_to_depth(decoder.levels[0].prox0.to(torch.float64), decoder.avg_depth).log()
    known = torch.isfinite(map_depth) & (map_depth > 0)
    if valid is not None:
        known &= valid.to(known.device)
    if float(known.double().mean()) < MIN_COVERAGE:
        return decoder
    e = torch.where(known, map_depth.to(torch.float64).log() - log_d0, torch.zeros_like(log_d0))
    e = e - e[known].median()
    smooth, cover = low_pass(e, known.to(torch.float64), sigma)
    change = weight * torch.where(cover > 0.2, smooth, torch.zeros_like(smooth))
    a = decoder.avg_depth
    delta = depth_to_prox((log_d0 + change).exp(), a) - depth_to_prox(log_d0.exp(), a)  # exactly 0 where unchanged
    if in_span:
        # The change the code can make: c = argmin |J c - delta|^2 + ridge |c|^2, every level moved by its own J c
        # (the zero code becomes D(I, c): the code prior re-centred on the map, the network's span kept).
        lv0 = decoder.levels[0]
        ridge = SPAN_RIDGE * float(lv0.jac.to(torch.float64).square().sum((1, 2)).mean())  # mean diagonal of J J^T
        zero = torch.zeros_like(delta)[None, None]
        c = fit_code_linear(zero, lv0.jac[None].to(torch.float64), delta[None, None], torch.ones_like(zero), ridge)[0]
        steps = [torch.einsum("c,chw->hw", c.to(lv.jac.dtype), lv.jac).to(torch.float64) for lv in decoder.levels]
    else:
        steps = [dp[0, 0] for dp in image_pyramid(delta[None, None], decoder.num_levels)]
    levels = tuple(DecoderLevel((lv.prox0.to(torch.float64) + dp).to(lv.prox0.dtype), lv.jac, lv.uncertainty)
                   for dp, lv in zip(steps, decoder.levels))
    return dataclasses.replace(decoder, levels=levels)  # the decoder's own class (a ScaledDecoder stays one)
