"""The intensity-conditioned variational depth auto-encoder (paper Sec. 2.1, Fig. 3), in one file.

Three branches, all fully convolutional except the code bottleneck:

* **Image U-Net** on the intensity image: strided 3x3 convolutions down to 1/16 resolution, then bilinear
  up-sampling with skip concatenations back to full resolution. Its features ``feats[s]`` at every scale
  s = 0 (full), 1 (1/2), ..., 4 (1/16) condition the depth branches, and the uncertainty ``b`` of the
  Laplace likelihood is predicted from them alone, so ``b`` never depends on the code (Sec. 2.1).
* **Depth encoder**: proximity (with its validity mask) -> strided convolutions, each followed by the
  concatenation of the image features of that resolution -> two fully connected layers (512, ReLU) ->
  mean and log-variance of the code; sampled with the reparameterisation trick in training.
* **Depth decoder**: code -> fully connected layer to a 1/16 map -> at every scale the image features are
  joined in and a 3x3 convolution applied -> bilinear up-sampling, except the last up-sampling, which is a
  transposed convolution -> proximity mean ``mu`` on 4 pyramid levels (finest first).

With ``linear_decoder`` (the paper's reference network) the decoder uses identity activations and joins a
decoder feature L1 with an image feature L2 as ``[L1, L2, L1 * L2]``: every operation is then affine in the
code, so ``D(I, c) = D(I, 0) + J(I) c`` exactly and J can be computed once per keyframe
(:mod:`codeslam.network.jacobian`). Otherwise the decoder uses ReLU and plain concatenation ``[L1, L2]``.
``mu`` has no output nonlinearity in either case; it is clamped to valid proximity where it becomes a depth
(:func:`codeslam.geometry.proximity.prox_to_depth`).

Shapes: images (B, in_channels, H, W) in [0, 1]; proximity (B, 1, H, W) with 0 = unknown depth; codes (B, C).

Size and speed of the default config (128x96 grey, code 128, widths 8/16/32/64/128): 2.98M parameters (12 MB as
float32; 1.45M in the encoder, mostly its fully connected layers, 1.09M in the decoder, 0.44M in the U-Net). A
training step (forward, loss, backward, Adam) runs at ~57 images/s at batch 16 on an idle 2-core CPU with
channels-last tensors (46 images/s without), measured with ``codeslam train`` and a stand-alone step loop.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn as nn
import torch.nn.functional as F

from codeslam.constants import MIN_UNCERTAINTY
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, canonical_camera
from codeslam.geometry.image import rgb_to_gray
from codeslam.network.config import NUM_LEVELS, NUM_SCALES, NetworkConfig

#: initial bias of the proximity heads: p = 0.5 is the proximity of the average depth a (Eq. 4)
_INIT_PROX = 0.5
#: initial uncertainty b (proximity units) set through the bias of the softplus heads
_INIT_UNCERTAINTY = 0.1


class NetworkOutput(NamedTuple):
    """What :meth:`CodeNetwork.forward` returns (a tuple, so DistributedDataParallel can traverse it)."""

    mu: list[torch.Tensor]  # NUM_LEVELS x (B, 1, H / 2^l, W / 2^l) proximity means, finest first
    b: list[torch.Tensor]  # NUM_LEVELS x (B, 1, H / 2^l, W / 2^l) Laplace scales (> 0), finest first
    code_mean: torch.Tensor  # (B, C)
    code_logvar: torch.Tensor  # (B, C)
    code: torch.Tensor  # (B, C) the code that was decoded (a sample in training, the mean otherwise)
    mu_zero: list[torch.Tensor] | None = None  # like mu, decoded from the zero code (with ``decode_zero``)


def conv3x3(c_in: int, c_out: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(c_in, c_out, kernel_size=3, stride=stride, padding=1)


def upsample2(x: torch.Tensor) -> torch.Tensor:
    """(B, C, h, w) -> (B, C, 2h, 2w), bilinear (a linear map, so the linear decoder stays affine)."""
    return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)


def join(decoder_feat: torch.Tensor, image_feat: torch.Tensor, linear: bool) -> torch.Tensor:
    """Concatenate a decoder feature L1 (B, K, h, w) with an image feature L2 (B, K, h, w) along channels:
    ``[L1, L2, L1 * L2]`` (B, 3K, h, w) for the linear decoder (Sec. 2.1: keeps the image's influence on the
    code Jacobian), ``[L1, L2]`` (B, 2K, h, w) otherwise."""
    if linear:
        return torch.cat([decoder_feat, image_feat, decoder_feat * image_feat], dim=1)
    return torch.cat([decoder_feat, image_feat], dim=1)


def to_network_image(image: torch.Tensor, in_channels: int) -> torch.Tensor:
    """RGB (B, 3, H, W) in [0, 1] -> the network's input (B, in_channels, H, W): luma for 1 channel."""
    if image.shape[-3] == in_channels:
        return image
    if image.shape[-3] == 3 and in_channels == 1:
        return rgb_to_gray(image)
    raise CodeSLAMError(f"the network takes {in_channels}-channel images, got {image.shape[-3]} channels")


class ImageUNet(nn.Module):
    """Intensity image (B, Cin, H, W) -> features at scales 0..4 (full, 1/2, 1/4, 1/8, 1/16)."""

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        w = cfg.image_channels  # widths at 1/2 .. 1/16
        c_prev = [cfg.in_channels, *w[:-1]]
        self.down = nn.ModuleList(
            nn.Sequential(conv3x3(c_prev[k], w[k], stride=2), nn.ReLU(), conv3x3(w[k], w[k]), nn.ReLU())
            for k in range(NUM_SCALES)
        )
        # up[k] fuses the up-sampled coarser features with the skip at scale k (0 = full resolution)
        skip = [cfg.in_channels, *w[:-1]]  # channels of the skip input at scales 0..3
        out = [cfg.full_res_channels, *w[:-1]]  # feature widths at scales 0..3
        coarser = [*out[1:], w[-1]]  # width of the features coming up from scale k + 1
        self.up = nn.ModuleList(
            nn.Sequential(conv3x3(coarser[k] + skip[k], out[k]), nn.ReLU()) for k in range(NUM_SCALES)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        skips = [x]  # scale 0: the (normalised) image itself
        for k in range(NUM_SCALES):
            skips.append(self.down[k](skips[-1]))  # (B, w_k, H / 2^(k+1), W / 2^(k+1))
        feats = [skips[NUM_SCALES]]  # scale 4: (B, w_3, H/16, W/16)
        for k in reversed(range(NUM_SCALES)):
            y = torch.cat([upsample2(feats[0]), skips[k]], dim=1)  # (B, coarser + skip, H / 2^k, W / 2^k)
            feats.insert(0, self.up[k](y))
        return feats  # [(B, full_res_channels, H, W), (B, w_0, H/2, W/2), ..., (B, w_3, H/16, W/16)]


class DepthEncoder(nn.Module):
    """Proximity (B, 1, H, W) and image features -> code mean and log-variance (B, C) each."""

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        d, w = cfg.depth_channels, cfg.image_channels
        c_in = [2 + cfg.full_res_channels] + [d[k] + w[k] for k in range(NUM_SCALES - 1)]
        self.down = nn.ModuleList(
            nn.Sequential(conv3x3(c_in[k], d[k], stride=2), nn.ReLU()) for k in range(NUM_SCALES)
        )
        self.squeeze = nn.Sequential(conv3x3(d[-1] + w[-1], cfg.bottleneck_channels), nn.ReLU())
        hw = (cfg.height // 2**NUM_SCALES) * (cfg.width // 2**NUM_SCALES)
        self.fc = nn.Sequential(
            nn.Linear(cfg.bottleneck_channels * hw, cfg.fc_units),
            nn.ReLU(),
            nn.Linear(cfg.fc_units, cfg.fc_units),
            nn.ReLU(),
        )
        self.mean = nn.Linear(cfg.fc_units, cfg.code_size)
        self.logvar = nn.Linear(cfg.fc_units, cfg.code_size)

    def forward(self, feats: list[torch.Tensor], prox: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        valid = (prox > 0).to(prox.dtype)  # (B, 1, H, W): 0 marks unknown depth
        x = torch.cat([prox * valid, valid, feats[0]], dim=1)  # (B, 2 + full_res_channels, H, W)
        for k in range(NUM_SCALES):
            x = self.down[k](x)  # (B, d_k, H / 2^(k+1), W / 2^(k+1))
            x = torch.cat([x, feats[k + 1]], dim=1)  # conditioning by concatenation: (B, d_k + w_k, ...)
        x = self.squeeze(x)  # (B, bottleneck, H/16, W/16)
        h = self.fc(x.flatten(1))  # (B, fc_units)
        return self.mean(h), self.logvar(h)  # (B, C), (B, C)


class DepthDecoder(nn.Module):
    """Code (B, C) and image features -> proximity means on NUM_LEVELS levels, finest first."""

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        self.linear = cfg.linear_decoder
        k = 3 if self.linear else 2  # channel multiplier of join()
        w = cfg.image_channels
        self.h16, self.w16 = cfg.height // 2**NUM_SCALES, cfg.width // 2**NUM_SCALES
        self.fc = nn.Linear(cfg.code_size, w[3] * self.h16 * self.w16)
        # conv at scale s (4 = 1/16 ... 1 = 1/2) maps join(decoder, image features of s) to the width of s - 1
        widths = [cfg.full_res_channels, *w]  # image feature widths at scales 0..4
        self.convs = nn.ModuleList(conv3x3(k * widths[s], widths[s - 1]) for s in range(NUM_SCALES, 0, -1))
        c0 = cfg.full_res_channels
        # the last up-sampling (1/2 -> full) is a transposed convolution, as in the paper's Fig. 3
        self.deconv = nn.ConvTranspose2d(c0, c0, kernel_size=4, stride=2, padding=1)
        # proximity heads at levels 0 (full) .. 3 (1/8); level l > 0 reads the conv output of scale l
        self.heads = nn.ModuleList(
            conv3x3(k * c0 if level == 0 else widths[level - 1], 1) for level in range(NUM_LEVELS)
        )
        for head in self.heads:
            nn.init.constant_(head.bias, _INIT_PROX)

    def act(self, x: torch.Tensor) -> torch.Tensor:
        return x if self.linear else F.relu(x)

    def forward(self, feats: list[torch.Tensor], code: torch.Tensor) -> list[torch.Tensor]:
        B = code.shape[0]
        y = self.fc(code).view(B, -1, self.h16, self.w16)  # (B, w_3, H/16, W/16)
        mu: list[torch.Tensor] = [None] * NUM_LEVELS  # type: ignore[list-item]
        for i, s in enumerate(range(NUM_SCALES, 0, -1)):  # s = 4 (1/16) .. 1 (1/2)
            if s < NUM_SCALES:
                y = upsample2(y)  # (B, w_s, H / 2^s, W / 2^s)
            y = self.act(self.convs[i](join(y, feats[s], self.linear)))  # (B, width of s - 1, H/2^s, W/2^s)
            if s < NUM_LEVELS:
                mu[s] = self.heads[s](y)  # (B, 1, H / 2^s, W / 2^s)
        y = self.act(self.deconv(y))  # (B, c0, H, W)
        mu[0] = self.heads[0](join(y, feats[0], self.linear))  # (B, 1, H, W)
        return mu

    def code_directions(self, feats: list[torch.Tensor], basis: torch.Tensor,
                        dtype: torch.dtype | None = None) -> list[torch.Tensor]:
        """Linear decoder only: ``D(I, c + d) - D(I, c)`` for the m code directions ``basis`` (m, C), per level
        (B, m, H / 2^l, W / 2^l), finest first; with the unit codes as ``basis`` the columns of the code
        Jacobian (Sec. 4.1). Every layer is ``W_y y + W_f f + W_yf (y * f) + b`` (:func:`join`), affine in the
        decoder feature y, so a difference of two decodings obeys ``W_y dy + W_yf (dy * f)``: only those
        weights, no bias, no image term, and no pass over the zero code. Written by hand because the batched
        decoding of the zero and unit codes repeats the image terms C + 1 times (measured at 96x128, code 128:
        0.44 -> 0.21 s with 2 threads, 0.63 -> 0.33 s with 1).

        dtype: compute in this type (weights and features cast to it; the result comes back in the features'
        type), e.g. ``torch.bfloat16`` where the CPU multiplies it in hardware (:func:`jacobian_dtype`); None:
        the weights' type."""
        if not self.linear:
            raise ValueError("code_directions needs the linear decoder (the nonlinear one's Jacobian varies)")
        B, m = feats[0].shape[0], basis.shape[0]
        out_dtype = feats[0].dtype
        dtype = dtype or self.fc.weight.dtype
        # Channels-last: the batch of m directions with few channels each is what oneDNN's convolutions run
        # fastest in that layout (measured at 96x128, code 128: 241 -> 120 ms with 2 threads).
        # The image features go channels-last once, so that for one image (a SLAM keyframe) the product dy * f of
        # channels-last operands is one already and needs no copy (measured at 96x128, code 128, 2 threads: 143 ->
        # 125-136 ms, the same values bit for bit).
        cl = torch.channels_last
        feats = [f.to(dtype).contiguous(memory_format=cl) for f in feats]

        def layer(conv: nn.Conv2d, dy: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
            K, w = dy.shape[1], conv.weight.to(dtype)  # w: (out, 3K, 3, 3) over [y, f, y * f]
            dy = dy.contiguous(memory_format=cl)
            if B == 1:
                dyf = dy * f  # (m, K, h, w), broadcast over the m directions
            else:  # (B m, K, h, w): f of each image
                dyf = (dy.view(B, m, *dy.shape[1:]) * f[:, None]).flatten(0, 1).contiguous(memory_format=cl)
            return (F.conv2d(dy, w[:, :K].contiguous(memory_format=cl), None, conv.stride, conv.padding)
                    + F.conv2d(dyf, w[:, 2 * K :].contiguous(memory_format=cl), None, conv.stride, conv.padding))

        fc = self.fc.weight.to(dtype)
        dy = (basis.to(fc) @ fc.T).view(1, m, -1, self.h16, self.w16)
        dy = dy.expand(B, -1, -1, -1, -1).flatten(0, 1)  # (B m, w_3, H/16, W/16), image-major like the result
        out: list[torch.Tensor] = [None] * NUM_LEVELS  # type: ignore[list-item]
        for i, s in enumerate(range(NUM_SCALES, 0, -1)):  # the same walk as forward()
            if s < NUM_SCALES:
                dy = upsample2(dy)
            dy = layer(self.convs[i], dy, feats[s])
            if s < NUM_LEVELS:
                head = self.heads[s]
                out[s] = F.conv2d(dy, head.weight.to(dtype), None, head.stride, head.padding)
        dy = F.conv_transpose2d(dy.contiguous(memory_format=cl), self.deconv.weight.to(dtype), None,
                                self.deconv.stride, self.deconv.padding)
        out[0] = layer(self.heads[0], dy, feats[0])
        return [o.reshape(B, m, *o.shape[-2:]).to(out_dtype) for o in out]


class CodeNetwork(nn.Module):
    """The whole network. ``cfg`` is kept as ``self.config`` and saved with the weights."""

    def __init__(self, cfg: NetworkConfig | None = None) -> None:
        super().__init__()
        self.config = cfg or NetworkConfig()
        self.unet = ImageUNet(self.config)
        self.b_heads = nn.ModuleList(
            conv3x3(self.config.full_res_channels if lvl == 0 else self.config.image_channels[lvl - 1], 1)
            for lvl in range(NUM_LEVELS)
        )
        b_bias = torch.log(torch.expm1(torch.tensor(_INIT_UNCERTAINTY - MIN_UNCERTAINTY)))  # softplus^-1
        for head in self.b_heads:
            nn.init.constant_(head.bias, float(b_bias))
        self.encoder = DepthEncoder(self.config)
        self.decoder = DepthDecoder(self.config)

    @property
    def code_size(self) -> int:
        return self.config.code_size

    @property
    def avg_depth(self) -> float:
        return self.config.avg_depth

    @property
    def camera(self) -> PinholeCamera:
        """The canonical camera every input image must be resampled to."""
        c = self.config
        return canonical_camera(c.width, c.height, c.hfov_deg)

    def _check_image(self, image: torch.Tensor) -> None:
        c = self.config
        if image.ndim != 4 or tuple(image.shape[1:]) != (c.in_channels, c.height, c.width):
            raise CodeSLAMError(
                f"the network takes images of shape (B, {c.in_channels}, {c.height}, {c.width}), "
                f"got {tuple(image.shape)} (resample to the canonical camera and convert with to_network_image)"
            )

    def image_features(self, image: torch.Tensor) -> list[torch.Tensor]:
        """(B, in_channels, H, W) in [0, 1] -> U-Net features at scales 0 (full) .. 4 (1/16). Run it once per
        image and pass the result to :meth:`uncertainty`, :meth:`encode` and :meth:`decode`."""
        self._check_image(image)
        return self.unet((image - 0.5) * 4.0)  # roughly zero-mean, unit-range input

    def uncertainty(self, feats: list[torch.Tensor]) -> list[torch.Tensor]:
        """Image features -> NUM_LEVELS Laplace scales b (B, 1, H / 2^l, W / 2^l), finest first. From the
        image branch only (Sec. 2.1): independent of the code and of the depth."""
        return [F.softplus(self.b_heads[lvl](feats[lvl])) + MIN_UNCERTAINTY for lvl in range(NUM_LEVELS)]

    def encode(self, feats: list[torch.Tensor], prox: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features and proximity (B, 1, H, W), 0 where the depth is unknown -> code mean, log-variance (B, C)."""
        return self.encoder(feats, prox)

    def decode(self, feats: list[torch.Tensor], code: torch.Tensor) -> list[torch.Tensor]:
        """Features and code (B, C) -> NUM_LEVELS proximity means (B, 1, H / 2^l, W / 2^l), finest first."""
        return self.decoder(feats, code)

    def forward(
        self,
        image: torch.Tensor,
        prox: torch.Tensor,
        sample: bool | None = None,
        noise: torch.Tensor | None = None,
        decode_zero: bool = False,
    ) -> NetworkOutput:
        """Auto-encode ``prox`` (B, 1, H, W) conditioned on ``image`` (B, in_channels, H, W).

        ``sample`` (default: ``self.training``) draws the code with the reparameterisation trick
        ``c = mean + exp(logvar / 2) * eps`` (Kingma & Welling); otherwise the mean is decoded. ``noise``
        (B, C) supplies eps (standard normal) so that a training step is reproducible on any device.
        ``decode_zero`` also decodes the zero code (the image-only prediction) in the same decoder call.
        """
        feats = self.image_features(image)
        mean, logvar = self.encode(feats, prox)
        if self.training if sample is None else sample:
            eps = torch.randn_like(mean) if noise is None else noise
            code = mean + torch.exp(0.5 * logvar) * eps  # (B, C)
        else:
            code = mean
        if not decode_zero:
            return NetworkOutput(self.decode(feats, code), self.uncertainty(feats), mean, logvar, code)
        B = code.shape[0]
        both = self.decode([torch.cat([f, f]) for f in feats], torch.cat([code, torch.zeros_like(code)]))  # 2B
        mu, mu_zero = [m[:B] for m in both], [m[B:] for m in both]
        return NetworkOutput(mu, self.uncertainty(feats), mean, logvar, code, mu_zero)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
