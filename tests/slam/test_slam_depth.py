"""Depth models for keyframes: the network adapter gives the network's own decoding on every level, the stand-in
reproduces the measured depth at its true code."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from slam_scene import synth_frames

from codeslam.data.frame import resample_frame
from codeslam.depthmodel import DepthModel
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.proximity import depth_to_prox
from codeslam.network import CodeNetwork, NetworkConfig
from codeslam.slam.depth import network_depth_model, standin_depth_model, standin_true_code


def test_standin_reaches_the_measured_depth_at_its_true_code():
    frame = synth_frames(3, 12, 10.0)[5]
    dec = standin_depth_model(code_size=16, num_levels=3, seed=2)(frame)
    assert dec.num_levels == 3 and dec.code_size == 16
    target = depth_to_prox(frame.depth.double(), 1.5)
    torch.testing.assert_close(dec.prox(standin_true_code(5, 16, 0.2, seed=2)), target)
    assert float((dec.prox(torch.zeros(16, dtype=torch.float64)) - target).abs().mean()) > 0.01  # zero code is off
    with pytest.raises(CodeSLAMError, match="depth maps"):
        standin_depth_model()(dataclasses.replace(frame, depth=None))


def test_network_depth_model_decodes_like_the_network():
    torch.manual_seed(0)
    cfg = NetworkConfig(code_size=4, width=64, height=48, image_channels=(4, 4, 4, 4), depth_channels=(4, 4, 4, 4),
                        full_res_channels=4, bottleneck_channels=4, fc_units=8)
    model = DepthModel(CodeNetwork(cfg).eval())
    frame = resample_frame(synth_frames(3, 12, 10.0)[0], model.camera)
    dec = network_depth_model(model)(frame)
    assert dec.num_levels == 4 and dec.code_size == 4 and dec.avg_depth == cfg.avg_depth
    code = torch.tensor([0.5, -1.0, 0.25, 2.0])
    feats = model.features(frame.image[None])
    want = model.decode(feats, code[None])  # 4 levels of (1, 1, h, w)
    for lvl in range(4):
        torch.testing.assert_close(dec.prox(code, lvl), want[lvl][0, 0], atol=1e-5, rtol=1e-4)
        assert dec.levels[lvl].uncertainty is not None
    other = dataclasses.replace(frame, camera=canonical_camera(64, 48, hfov_deg=70))
    with pytest.raises(CodeSLAMError, match="canonical camera"):
        network_depth_model(model)(other)
