"""Keyframes as the optimiser sees them: a grey image, its camera and its linear depth decoder, stacked per
pyramid level for batched evaluation over frame pairs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, pixel_grid
from codeslam.geometry.image import image_gradients, image_pyramid, pyramid_cameras, rgb_to_gray
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder, ScaledDecoder


@dataclass(frozen=True)
class Keyframe:
    """One frame of an SfM problem.

    Attributes:
        image: (H, W), (1, H, W) grey or (3, H, W) RGB, values in [0, 1].
        camera: the pinhole camera of ``image`` (finest level).
        decoder: its linear depth decoder (level 0 has the size of ``image``), or None for a frame of unknown
            depth (the tracker's current frame): it can then only be the B of photometric pairs, its code has no
            effect and its proximity reads as invalid (no occlusion test against it).
        valid: (H, W) bool, where ``image`` holds real pixels (None: everywhere), on any device
            (:func:`build_levels` moves it); photometric residuals never read the others (loss (i)).
    """

    image: torch.Tensor
    camera: PinholeCamera
    decoder: LinearDecoder | None
    valid: torch.Tensor | None = None

    def __post_init__(self) -> None:
        H, W = self.image.shape[-2:]
        if self.image.dim() not in (2, 3) or (self.image.dim() == 3 and self.image.shape[0] not in (1, 3)):
            raise CodeSLAMError(f"keyframe image must be (H, W), (1, H, W) or (3, H, W), got {tuple(self.image.shape)}")
        if (self.camera.height, self.camera.width) != (H, W):
            raise CodeSLAMError(f"keyframe image is {W}x{H} but its camera is {self.camera.width}x{self.camera.height}")
        if self.valid is not None and tuple(self.valid.shape) != (H, W):
            raise CodeSLAMError(f"keyframe validity mask is {tuple(self.valid.shape)}, its image {W}x{H}")
        if self.decoder is not None and tuple(self.decoder.levels[0].prox0.shape) != (H, W):
            raise CodeSLAMError(
                f"keyframe image is {W}x{H} but its decoder's finest level is "
                f"{self.decoder.levels[0].prox0.shape[1]}x{self.decoder.levels[0].prox0.shape[0]}"
            )

    @property
    def gray(self) -> torch.Tensor:
        """(1, H, W) grey image."""
        img = self.image if self.image.dim() == 3 else self.image[None]
        return rgb_to_gray(img[None])[0] if img.shape[0] == 3 else img


@dataclass(frozen=True)
class LevelData:
    """All F keyframes at one pyramid level, stacked. N = H W pixels, C = code size.

    Attributes:
        gray: (F, 1, H, W) grey images.
        gray_grad: (F, 1, 2, H, W) their Sobel gradients (d/du, d/dv).
        prox0: (F, 1, H, W) decoded proximity at the zero code.
        jac: (F, C, H, W) d prox / d code.
        uncertainty: (F, 1, H, W) the network's Laplace scale b, or None.
        params: (F, 4) intrinsics (fx, fy, cx, cy) at this level.
        avg_depth: (F,) average depth a of each decoder (Eq. 4).
        uv: (N, 2) pixel coordinates, row-major (pixel n = (n % W, n // W)).
        gray_valid: (F, 1, H, W) 1 where the grey value comes from real pixels only, 0 elsewhere; None when
            every keyframe's image is valid everywhere.
        level: the pyramid level (0 = finest).
        scale_entry: the codes' last entry is a log scale of the depth, exactly (the keyframes'
            :class:`~codeslam.sfm.decoder.ScaledDecoder`): ``jac``'s last channel is its column at the last
            linearisation (:meth:`refresh_scale_column`), :meth:`prox` leaves it out and :meth:`avg_depth_at`
            applies it.
    """

    gray: torch.Tensor
    gray_grad: torch.Tensor
    prox0: torch.Tensor
    jac: torch.Tensor
    uncertainty: torch.Tensor | None
    params: torch.Tensor
    avg_depth: torch.Tensor
    uv: torch.Tensor
    gray_valid: torch.Tensor | None = None
    level: int = 0
    scale_entry: bool = False

    @property
    def height(self) -> int:
        return self.gray.shape[-2]

    @property
    def width(self) -> int:
        return self.gray.shape[-1]

    @property
    def num_frames(self) -> int:
        return self.gray.shape[0]

    @property
    def code_size(self) -> int:
        return self.jac.shape[1]

    @cached_property
    def jac_channels_last(self) -> torch.Tensor:
        """``jac`` in channels-last memory, for bilinear lookups of J_B at warped pixels
        (:func:`~codeslam.sfm.residuals.sample_by_frame`): a pixel's C values are one contiguous row, so a
        lookup reads four rows instead of C planes (measured with ``grid_sample`` at C = 128, 128x96, 24,000
        points, one thread: 40 -> 7 ms per lookup), and the normal equations read J_A's rows from it too.
        Made once per level, on first use."""
        return self.jac.contiguous(memory_format=torch.channels_last)

    def prox(self, codes: torch.Tensor) -> torch.Tensor:
        """codes (F, C) -> (F, 1, H, W) decoded proximity ``prox0 + J c`` (exact for a linear decoder)."""
        F_, C, H, W = self.jac.shape
        k = C - 1 if self.scale_entry else C  # the scale is not linear in proximity: avg_depth_at applies it
        # One (1, C) x (C, N) product per frame. torch.einsum("fchw,fc->fhw") chose a batched matrix-vector
        # product over the transposed Jacobian instead: 5.1 against 0.12 ms at C = 64, 4 x 128x96, 2 threads (the
        # same values to the bit), about 6% of a SLAM window solve, which evaluates this at every step.
        return self.prox0 + torch.bmm(codes[:, None, :k], self.jac.reshape(F_, C, H * W)[:, :k]).reshape(F_, 1, H, W)

    def avg_depth_at(self, codes: torch.Tensor) -> torch.Tensor:
        """(F,) the average depth a each frame's proximity is read with: ``a exp(s)`` with a scale entry (the
        depth ``a (1 - p) / p`` scaled by exp(s) exactly), else ``avg_depth``."""
        return self.avg_depth * torch.exp(codes[:, -1]) if self.scale_entry else self.avg_depth

    def refresh_scale_column(self, codes: torch.Tensor) -> None:
        """With a scale entry: the scale's column of ``jac`` at ``codes``
        (:meth:`~codeslam.sfm.decoder.ScaledDecoder.scale_column` at the current linear proximity), in the compact
        form ``d r / d c = s_A J[u]`` of the residuals (which carry ``d D / d p`` at ``a exp(s)``)."""
        if not self.scale_entry:
            return
        col = ScaledDecoder.scale_column(self.prox(codes.detach())[:, 0])  # (F, H, W)
        self.jac[:, -1] = col
        if "jac_channels_last" in self.__dict__:
            self.__dict__["jac_channels_last"][:, -1] = col  # the cached copy of jac (jac_channels_last)


def build_levels(
    keyframes: Sequence[Keyframe], levels: Sequence[int], dtype: torch.dtype | None = None, device=None
) -> dict[int, LevelData]:
    """Stack the keyframes at each requested pyramid level (0 = finest). The image pyramid is
    :func:`codeslam.geometry.image.image_pyramid`; the decoders must provide every requested level.
    ``dtype``/``device`` default to those of the first decoder."""
    with_dec = [kf for kf in keyframes if kf.decoder is not None]
    if not with_dec:
        raise CodeSLAMError("an SfM problem needs at least one keyframe with a depth decoder")
    ref = with_dec[0].decoder.levels[0].jac
    dtype = dtype or ref.dtype
    device = device if device is not None else ref.device
    n_levels = max(levels) + 1
    C = with_dec[0].decoder.code_size
    shape = keyframes[0].image.shape[-2:]
    for i, kf in enumerate(keyframes):
        if kf.image.shape[-2:] != shape:
            raise CodeSLAMError(f"keyframe {i} is {tuple(kf.image.shape[-2:])}, keyframe 0 is {tuple(shape)}")
        if kf.decoder is None:
            continue
        if kf.decoder.code_size != C:
            raise CodeSLAMError(f"keyframe {i} has code size {kf.decoder.code_size}, another has {C}")
        if kf.decoder.num_levels < n_levels:
            raise CodeSLAMError(f"keyframe {i}'s decoder has {kf.decoder.num_levels} levels, {n_levels} needed")
    grays = torch.stack([kf.gray for kf in keyframes]).to(dtype=dtype, device=device)  # (F, 1, H, W)
    pyr = image_pyramid(grays, n_levels)
    valid_pyr = None
    if any(kf.valid is not None for kf in keyframes):
        valids = torch.stack([torch.ones(shape, dtype=dtype, device=device) if kf.valid is None
                              else kf.valid.to(dtype=dtype, device=device) for kf in keyframes])[:, None]
        valid_pyr = image_pyramid(valids, n_levels)  # share of real pixels under each pyramid pixel
    out = {}
    for lvl in sorted(set(levels)):
        gray = pyr[lvl].contiguous()
        H, W = gray.shape[-2:]
        # A frame without a decoder: proximity 0 (the invalid sentinel) and a zero Jacobian.
        unknown = DecoderLevel(torch.zeros(H, W, dtype=dtype, device=device),
                               torch.zeros(C, H, W, dtype=dtype, device=device))
        decs = [unknown if kf.decoder is None else kf.decoder.levels[lvl] for kf in keyframes]
        if any(tuple(d.prox0.shape) != (H, W) for d in decs):
            raise CodeSLAMError(f"a decoder's level {lvl} does not match the image pyramid's {W}x{H}")
        has_b = all(d.uncertainty is not None for d in decs if d is not unknown)
        cams = [pyramid_cameras(kf.camera, n_levels)[lvl] for kf in keyframes]
        out[lvl] = LevelData(
            gray=gray,
            gray_grad=image_gradients(gray),
            prox0=torch.stack([d.prox0 for d in decs])[:, None].to(dtype=dtype, device=device),
            jac=torch.stack([d.jac for d in decs]).to(dtype=dtype, device=device).contiguous(),
            uncertainty=torch.stack([torch.zeros(H, W, dtype=dtype, device=device) if d is unknown
                                     else d.uncertainty for d in decs])[:, None].to(dtype=dtype, device=device)
            if has_b else None,
            params=torch.stack([c.params(dtype, device) for c in cams]),
            avg_depth=torch.tensor([1.0 if kf.decoder is None else kf.decoder.avg_depth for kf in keyframes],
                                   dtype=dtype, device=device),
            uv=pixel_grid(H, W, dtype, device).reshape(-1, 2),
            gray_valid=None if valid_pyr is None else real_pixels(valid_pyr[lvl]),
            level=lvl,
            scale_entry=any(isinstance(kf.decoder, ScaledDecoder) for kf in keyframes),
        )
    return out


def real_pixels(share: torch.Tensor) -> torch.Tensor:
    """(F, 1, H, W) share of real source pixels under each pyramid pixel -> 1 where it is all real, else 0.

    Not eroded by the 3x3 Sobel footprint, although the gradients next to an unreal pixel see it: the residuals
    stay exact either way, and eroding cost too much of the coarse levels (16x12 at level 3). Measured with
    `codeslam slam` on TUM fr1/rpy, whose canonical frames lose their last two rows: eroded, ATE 0.068 m and
    8.2 deg rotation RMSE; not eroded, 0.046 m and 5.7 deg (no mask at all: 0.044 m, 5.6 deg)."""
    return (share >= 1.0 - 1e-4).to(share.dtype)
