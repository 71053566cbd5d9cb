"""Depth models for keyframes: a frame -> its linear decoder ``prox_l(c) = prox0_l + J_l c`` on every pyramid
level (paper Sec. 4.1: the decoder's Jacobian is computed once per keyframe).

* :func:`network_depth_model`: the trained network (the paper's system), through
  :class:`codeslam.depthmodel.DepthModel`;
* :func:`standin_depth_model`: a network-free stand-in built from the frame's measured depth, to run and test
  the tracking and mapping back-end on RGB-D data without trained weights. It is an oracle for the depth prior
  (its zero-code depth is the blurred true depth) and is reported as such wherever it is used;
* :func:`true_prior_depth_model`: the network's decoder with its zero-code depth replaced by the frame's measured
  depth, an oracle for the prior alone (the network's code Jacobian kept).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from codeslam.data.frame import Frame
from codeslam.errors import CodeSLAMError
from codeslam.geometry.image import image_pyramid
from codeslam.geometry.proximity import depth_to_prox
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder, standin_decoder
from codeslam.slam.system import DepthModelFactory


def network_depth_model(model, jacobian_dtype: torch.dtype | None = None) -> DepthModelFactory:
    """The network's depth model: decoded proximity at the zero code, code Jacobian (one batched forward pass
    for the linear decoder) and Laplace uncertainty b on all of the network's levels.

    model: a :class:`codeslam.depthmodel.DepthModel`; frames must be in its canonical camera (``model.camera``).
    jacobian_dtype: the type the code Jacobian is computed in (``SLAMConfig.jacobian_dtype``); None: the
    network's.
    """
    camera = model.camera

    def decode(frame: Frame) -> LinearDecoder:
        if frame.camera != camera:
            raise CodeSLAMError(f"frame {frame.index} is not in the network's {camera.width}x{camera.height} "
                                "canonical camera; resample it first")
        return model.linear_decoders(model.features(frame.image[None]), jacobian_dtype=jacobian_dtype)[0]

    decode.reads_depth = False  # frames may come without their depth (CodeSLAM.reads_frame_depth)
    return decode


def _measured_depth(frame: Frame, what: str) -> torch.Tensor:
    """The frame's depth (float64) with its holes filled from their surroundings (:func:`fill_depth_holes`);
    CodeSLAMError without depth."""
    if frame.depth is None:
        raise CodeSLAMError(f"the {what} depth model needs depth maps and this dataset has none; use the "
                            "network (--depth-model network)")
    depth = frame.depth.to(torch.float64)
    valid = torch.isfinite(depth) & (depth > 0)
    if not bool(valid.any()):
        raise CodeSLAMError(f"frame {frame.index} has no valid depth for the {what} depth model")
    return fill_depth_holes(depth, valid)


def true_prior_depth_model(depth_model: DepthModelFactory) -> DepthModelFactory:
    """An oracle for the prior alone: ``depth_model``'s decoder (the network's code Jacobian and uncertainty on
    every level) with its zero-code proximity replaced by the frame's measured depth (holes filled by
    :func:`fill_depth_holes`; the coarser levels its image pyramid, as the stand-in's). Needs frames with depth.

    The stand-in replaces the code's Jacobian as well; this keeps the network's, so a run that holds here and
    fails with the network says that the tracker and the window hold and the network's zero-code depth loses the
    run (with it wrong, the code must correct it, and where the span holds the corrected shape sets the map's
    scale: ``scripts/depth_prior_eval.py --span``). Measured (docs/results/slam_table.md, twentieth session): the
    generator's nine walk and corridor runs end within 0.62% of their paths this way, eight of them at
    1.43-4.02% with the network's zero code."""

    def decode(frame: Frame) -> LinearDecoder:
        filled = _measured_depth(frame, "true-prior")
        net = depth_model(frame)
        if tuple(net.levels[0].prox0.shape) != tuple(filled.shape):
            raise CodeSLAMError(f"frame {frame.index}: its depth is {tuple(filled.shape)}, the depth model's "
                                f"output {tuple(net.levels[0].prox0.shape)}")
        prox = depth_to_prox(filled, net.avg_depth)
        pyramid = image_pyramid(prox[None, None], net.num_levels)
        levels = tuple(DecoderLevel(p[0, 0].to(lv.prox0.dtype), lv.jac, lv.uncertainty)
                       for p, lv in zip(pyramid, net.levels))
        return LinearDecoder(levels, net.avg_depth)

    return decode


def standin_true_code(frame_index: int, code_size: int = 32, scale: float = 0.2, seed: int = 0) -> torch.Tensor:
    """(C,) float64 code at which :func:`standin_depth_model` (with ``code_offset_scale=scale`` and ``seed``)
    reproduces frame ``frame_index``'s measured proximity: ``scale`` times a standard normal draw seeded by
    ``seed`` and the frame index."""
    gen = torch.Generator().manual_seed(seed * 1_000_003 + frame_index)
    return scale * torch.randn(code_size, generator=gen, dtype=torch.float64)


def fill_depth_holes(depth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(H, W) depth with its invalid pixels (``valid`` False) filled from the valid ones around them, by
    OpenCV's Navier-Stokes inpainting in log depth (its Telea method gives erratic values on float images).

    A sensor's holes are scattered (the HoloLens walk's depth misses 38-69% of the pixels at 128x96, spread over
    the whole image), along its border (TUM's undistortion) or beyond its range (a corridor's far end past 10 m):
    each is filled by its surroundings, where the single median depth used before made a scattered half of a
    HoloLens frame one flat depth and a corridor's far end 3 m away. Measured by holding out a random 20% of the
    valid pixels (every 12th frame, 128x96): mean |log depth| error of the filled values HoloLens walk 0.255 ->
    0.0073, TUM fr1/rpy 0.272 -> 0.0136 (a push-pull pyramid fill: 0.0078, 0.0130)."""
    log_d = torch.where(valid, depth.clamp_min(1e-6).log(), torch.zeros_like(depth)).cpu().numpy().astype(np.float32)
    holes = (~valid).cpu().numpy().astype(np.uint8)
    filled = torch.from_numpy(cv2.inpaint(log_d, holes, 3, cv2.INPAINT_NS)).to(depth)
    return torch.where(valid, depth, filled.exp())


def standin_depth_model(
    code_size: int = 32, num_levels: int = 4, avg_depth: float = 1.5, code_offset_scale: float | None = 0.2,
    blur_sigma: float = 3.0, basis_scale: float = 0.05, seed: int = 0,
) -> DepthModelFactory:
    """A stand-in depth model from the frame's own depth (see :func:`codeslam.sfm.standin_decoder`), holes filled
    from their surroundings (:func:`fill_depth_holes`); Jacobian = a smooth cosine basis times ``0.5 + grey
    image``. Needs frames with depth.

    With ``code_offset_scale`` (default) the measured proximity is reached exactly at a random code
    ``c* ~ N(0, code_offset_scale^2 I)`` (:func:`standin_true_code`), so the zero code is the truth
    plus a smooth, scale-changing error that the optimisation must remove, as a trained auto-encoder's span
    holds the depth its zero code only approximates. The default puts the zero code at the network issue's bar,
    0.8 times the error of the best constant proximity (measured on ``codeslam synth --seed 3`` at 128x96:
    proximity RMSE 0.060 against 0.079).
    With ``code_offset_scale=None`` the zero code is the
    measured proximity blurred by ``blur_sigma`` pixels, which the code can only approximate (measured on the
    generator's rooms: the window then trades depth accuracy for photometric fit at occlusion edges).
    """

    def decode(frame: Frame) -> LinearDecoder:
        filled = _measured_depth(frame, "stand-in")  # the stand-in needs a hole-free target
        offset = None if code_offset_scale is None else standin_true_code(frame.index, code_size,
                                                                           code_offset_scale, seed)
        return standin_decoder(depth_to_prox(filled, avg_depth), code_size, num_levels, avg_depth,
                               code_offset=offset, basis_scale=basis_scale, blur_sigma=blur_sigma,
                               image=frame.gray[0].to(torch.float64))

    return decode
