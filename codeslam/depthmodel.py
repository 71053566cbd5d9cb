"""The code network as the rest of codeslam uses it: any frame in, canonical-camera depth, codes and linear
decoders out.

:class:`DepthModel` wraps a trained :class:`~codeslam.network.CodeNetwork` and offers, for images of any camera
(resampled to the network's canonical camera first, the paper's intrinsics correction, Sec. 5.3):

* the zero-code depth ``D(I, 0)`` (single-view prediction, Sec. 3), the encoder's code of a known depth, and the
  code optimised to fit a known depth (:meth:`DepthModel.fit_codes`, Gauss-Newton with the decoder Jacobian
  and the VAE prior, Sec. 5.1 / Fig. 5 "code minimising reconstruction error");
* the :class:`~codeslam.sfm.LinearDecoder` of every pyramid level (``prox0``, ``J = dD/dc`` and the uncertainty
  b), computed once per keyframe by one batched forward pass (Sec. 4.1), and :class:`~codeslam.sfm.Keyframe`\\ s
  for :func:`codeslam.sfm.sfm` and the SLAM system.

:func:`predict_depth` runs the three modes of ``codeslam depth`` over a list of frames.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch

from codeslam.data.frame import Frame, resample_frame
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.proximity import depth_to_prox, prox_to_depth
from codeslam.network.jacobian import code_jacobian
from codeslam.network.model import CodeNetwork, to_network_image
from codeslam.recon.metrics import DepthErrors
from codeslam.sfm.decoder import LinearDecoder, fit_code_linear
from codeslam.sfm.keyframes import Keyframe

#: depth modes of :func:`predict_depth` and ``codeslam depth``
MODES = ("zero", "encode", "optimise")
#: Noise (proximity units) of the ground truth in the code fit: the weight of the data term against the VAE prior
#: N(0, I). 0.01 is about the quantisation and sensor noise of Kinect depth seen through p = a / (d + a) with
#: a = 1.5 m (2 cm at 3 m), so the fit follows the data wherever the data constrain the code.
FIT_PROX_SIGMA = 0.01
#: Gauss-Newton iterations of the code fit of a nonlinear decoder (a linear decoder needs exactly one).
FIT_MAX_ITERATIONS = 10
#: Step halvings tried when a Gauss-Newton step of a nonlinear decoder increases the cost.
FIT_MAX_HALVINGS = 8
#: The fit stops when an iteration lowers the cost by less than this fraction.
FIT_RELATIVE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class CanonicalFrame:
    """A frame resampled to the network's canonical camera.

    Attributes:
        image: (3, H, W) RGB in [0, 1] (0 where the canonical ray leaves the source image).
        depth: (H, W) metres, 0 = invalid (nearest-neighbour resampled), or None without ground-truth depth.
        pose: (4, 4) float64 T_wc or None. timestamp: seconds. index: position in its sequence.
        valid: (H, W) bool, where ``image`` was computed from real source pixels only (None: everywhere).
    """

    image: torch.Tensor
    depth: torch.Tensor | None
    pose: torch.Tensor | None
    timestamp: float
    index: int
    valid: torch.Tensor | None = None


def fit_cost(prox: torch.Tensor, target: torch.Tensor, weight: torch.Tensor, code: torch.Tensor,
             prior_weight: float = 1.0) -> torch.Tensor:
    """(B,) ``0.5 sum w (t - p)^2 + 0.5 prior |c|^2``; prox, target, weight (B, 1, H, W), code (B, C)."""
    data = 0.5 * (weight.double() * (target.double() - prox.double()).square()).flatten(1).sum(1)
    return data + 0.5 * prior_weight * code.double().square().sum(1)


class DepthModel:
    """A :class:`~codeslam.network.CodeNetwork` (in eval mode) and everything the tools need from it."""

    def __init__(self, network: CodeNetwork) -> None:
        self.network = network.eval()

    @classmethod
    def load(cls, weights: str | os.PathLike | None = None, device: torch.device | str = "cpu") -> DepthModel:
        """From a weights file (the shipped default weights when None); WeightsError for a bad file."""
        from codeslam.network.weights import load_model

        return cls(load_model(weights, device=device))

    # --- properties ---------------------------------------------------------------------------------------
    @property
    def config(self):
        return self.network.config

    @property
    def camera(self) -> PinholeCamera:
        """The canonical camera every image is resampled to."""
        return self.network.camera

    @property
    def avg_depth(self) -> float:
        """The average depth a of the proximity p = a / (d + a) (Eq. 4)."""
        return self.network.avg_depth

    @property
    def code_size(self) -> int:
        return self.network.code_size

    @property
    def device(self) -> torch.device:
        return next(self.network.parameters()).device

    # --- frames -------------------------------------------------------------------------------------------
    def canonical(self, frame: Frame) -> CanonicalFrame:
        """Resample a frame's image (bilinear, anti-aliased) and depth (nearest) to the canonical camera."""
        f = resample_frame(frame, self.camera)
        return CanonicalFrame(f.image.float().clamp(0, 1), None if f.depth is None else f.depth.float(), f.pose,
                              float(f.timestamp), int(f.index), f.valid)

    def target_prox(self, depth: torch.Tensor) -> torch.Tensor:
        """Depth (...) -> proximity (...) with the network's a; 0 where the depth is invalid."""
        return depth_to_prox(depth, self.avg_depth)

    # --- network ------------------------------------------------------------------------------------------
    def features(self, images: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) canonical RGB -> the U-Net features (run once per image)."""
        x = to_network_image(images.to(self.device, torch.float32), self.config.in_channels)
        with torch.no_grad():
            return self.network.image_features(x)

    def uncertainty(self, feats: list[torch.Tensor]) -> list[torch.Tensor]:
        """-> 4 levels of the Laplace scale b (B, 1, h, w), from the image only (Sec. 2.1)."""
        with torch.no_grad():
            return self.network.uncertainty(feats)

    def decode(self, feats: list[torch.Tensor], codes: torch.Tensor) -> list[torch.Tensor]:
        """Codes (B, C) -> 4 levels of proximity (B, 1, h, w), finest first."""
        with torch.no_grad():
            return self.network.decode(feats, codes.to(self.device, torch.float32))

    def encode(self, feats: list[torch.Tensor], prox: torch.Tensor) -> torch.Tensor:
        """Proximity (B, 1, H, W), 0 where unknown -> the encoder's mean code (B, C)."""
        with torch.no_grad():
            mean, _ = self.network.encode(feats, prox.to(self.device, torch.float32))
        return mean

    def linear_decoders(self, feats: list[torch.Tensor], codes: torch.Tensor | None = None,
                        jacobian_dtype: torch.dtype | None = None) -> list[LinearDecoder]:
        """One :class:`LinearDecoder` per image: all pyramid levels of ``prox0`` and ``J = dD/dc`` from one batched
        forward pass (:func:`codeslam.network.code_jacobian`, J computed in ``jacobian_dtype``, default the
        network's) and the uncertainty b. For the linear decoder this is exact; a nonlinear decoder is
        linearised at ``codes`` (B, C) (default zero): ``D(c') ~ (D(c) - J c) + J c'``."""
        B = feats[0].shape[0]
        if codes is None:
            codes = feats[0].new_zeros(B, self.code_size)
        prox, jac = code_jacobian(self.network, feats=feats, code=codes.to(feats[0]), all_levels=True,
                                  dtype=jacobian_dtype)
        b = self.uncertainty(feats)
        out = []
        for i in range(B):
            c = codes[i].to(feats[0])
            prox0 = [p[i, 0] - torch.einsum("chw,c->hw", J[i], c) for p, J in zip(prox, jac)]  # (h, w) per level
            out.append(LinearDecoder.from_levels(prox0, [J[i] for J in jac], self.avg_depth, [u[i, 0] for u in b]))
        return out

    def fit_codes(
        self, feats: list[torch.Tensor], target: torch.Tensor, sigma: float = FIT_PROX_SIGMA,
        max_iterations: int = FIT_MAX_ITERATIONS,
    ) -> torch.Tensor:
        """The code minimising ``0.5 sum_valid (p_gt - D(I, c))^2 / sigma^2 + 0.5 |c|^2`` (the data term on the
        finest level, masked to valid ground truth, plus the VAE prior) by Gauss-Newton with the decoder
        Jacobian. For a linear decoder one step is the exact least-squares solution; a nonlinear decoder
        iterates, halving steps that raise the cost, so the cost never exceeds that of the zero code.

        target (B, 1, H, W) proximity with 0 = unknown -> codes (B, C).
        """
        target = target.to(self.device, torch.float32)
        weight = (target > 0).to(target.dtype) / sigma**2  # (B, 1, H, W): valid ground truth only
        code = target.new_zeros(target.shape[0], self.code_size)  # (B, C)
        if self.config.linear_decoder:  # affine in the code: one Gauss-Newton step is the exact minimiser
            prox0, J = code_jacobian(self.network, feats=feats)  # (B, 1, H, W), (B, C, H, W)
            return fit_code_linear(prox0, J, target, weight)
        cost = fit_cost(self.decode(feats, code)[0], target, weight, code)  # (B,)
        for _ in range(max_iterations):
            prox, J = code_jacobian(self.network, feats=feats, code=code)  # exact Jacobian at the current code
            lin0 = prox - torch.einsum("bchw,bc->bhw", J, code)[:, None]  # D(c') ~ lin0 + J c'
            step = fit_code_linear(lin0, J, target, weight) - code  # to the minimiser of the linearised cost
            new_code, new_cost = code, cost
            for _ in range(FIT_MAX_HALVINGS):  # per image: accept the first step length that lowers the cost
                cand = code + step
                cand_cost = fit_cost(self.decode(feats, cand)[0], target, weight, cand)
                better = cand_cost < new_cost
                new_code = torch.where(better[:, None], cand, new_code)
                new_cost = torch.where(better, cand_cost, new_cost)
                if bool(better.all()):
                    break
                step = 0.5 * step
            decrease = (cost - new_cost) / cost.clamp_min(torch.finfo(cost.dtype).tiny)
            code, cost = new_code, new_cost
            if bool((decrease < FIT_RELATIVE_TOLERANCE).all()):
                break
        return code

    def keyframe(self, frame: CanonicalFrame) -> Keyframe:
        """A canonical frame -> the :class:`Keyframe` (RGB image, canonical camera, linear decoder) that
        :func:`codeslam.sfm.sfm` and the SLAM system optimise."""
        feats = self.features(frame.image[None])
        decoder = self.linear_decoders(feats)[0]
        return Keyframe(frame.image.to(self.device), self.camera, decoder, frame.valid)


@dataclass
class DepthPrediction:
    """The result of :func:`predict_depth` for one frame, at the canonical camera (finest level).

    Attributes:
        frame: the canonical frame (image, ground truth).
        uncertainty: (H, W) Laplace scale b of the proximity.
        codes: mode -> (C,) code. prox: mode -> (H, W) decoded proximity (unclamped network output).
    """

    frame: CanonicalFrame
    uncertainty: torch.Tensor
    codes: dict[str, torch.Tensor] = field(default_factory=dict)
    prox: dict[str, torch.Tensor] = field(default_factory=dict)

    def depth(self, mode: str, avg_depth: float) -> torch.Tensor:
        """(H, W) metres of ``mode`` (Eq. 4 inverted, proximity clamped to (0, 1))."""
        return prox_to_depth(self.prox[mode], avg_depth)


def predict_depth(
    model: DepthModel, frames: Sequence[CanonicalFrame], modes: Sequence[str], sigma: float = FIT_PROX_SIGMA,
) -> list[DepthPrediction]:
    """Depth of every frame in every mode: "zero" (``D(I, 0)``), "encode" (the encoder's mean code of the ground
    truth) and "optimise" (:meth:`DepthModel.fit_codes` on the ground truth). Frames are processed one at a time
    (the Jacobian of a 128-entry code needs 129 decoder passes per image)."""
    unknown = [m for m in modes if m not in MODES]
    if unknown:
        raise CodeSLAMError(f"unknown depth mode {unknown[0]!r}; choose from {', '.join(MODES)}")
    if any(m != "zero" for m in modes):
        missing = [f.index for f in frames if f.depth is None]
        if missing:
            raise CodeSLAMError(f"modes encode and optimise need ground-truth depth; frame {missing[0]} has none")
    out = []
    for f in frames:
        feats = model.features(f.image[None])
        pred = DepthPrediction(f, model.uncertainty(feats)[0][0, 0].cpu())
        target = None if f.depth is None else model.target_prox(f.depth)[None, None]  # (1, 1, H, W)
        for mode in modes:
            if mode == "zero":
                code = feats[0].new_zeros(1, model.code_size)
            elif mode == "encode":
                code = model.encode(feats, target)
            else:
                code = model.fit_codes(feats, target, sigma)
            pred.codes[mode] = code[0].cpu()
            pred.prox[mode] = model.decode(feats, code)[0][0, 0].cpu()
        out.append(pred)
    return out


def evaluate_predictions(preds: Sequence[DepthPrediction], avg_depth: float) -> dict[str, DepthErrors]:
    """Pooled errors of every mode of :func:`predict_depth`'s results against their frames' ground truth (frames
    without depth count as None in ``per_frame``), with proximity ``a / (d + a)`` of average depth ``avg_depth``."""
    modes = list(preds[0].prox) if preds else []
    errors = {m: DepthErrors() for m in modes}
    for p in preds:
        if p.frame.depth is None:
            for e in errors.values():
                e.per_frame.append(None)
            continue
        gt_prox = depth_to_prox(p.frame.depth, avg_depth)
        for m in modes:
            errors[m].add(p.prox[m], gt_prox, p.depth(m, avg_depth), p.frame.depth)
    return errors
