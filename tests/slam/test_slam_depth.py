"""Depth models for keyframes: the network adapter gives the network's own decoding on every level, the stand-in
reproduces the measured depth at its true code and fills a sensor's holes from their surroundings, the true prior
keeps the network's code Jacobian with the measured depth at the zero code."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from slam_scene import synth_frames

from codeslam.data.frame import resample_frame
from codeslam.depthmodel import DepthModel
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.image import image_pyramid
from codeslam.geometry.proximity import depth_to_prox
from codeslam.network import CodeNetwork, NetworkConfig
from codeslam.slam.config import SLAMConfig
from codeslam.slam.depth import (
    fill_depth_holes,
    network_depth_model,
    standin_depth_model,
    standin_true_code,
    true_prior_depth_model,
)
from codeslam.slam.system import CodeSLAM


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
    model = _tiny_model()
    cfg = model.network.config
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


def test_only_the_network_says_it_never_reads_a_frames_depth():
    # The runner reads frames without depth for it (CodeSLAM.reads_frame_depth); the stand-ins need the depth.
    model = _tiny_model()
    cfg = SLAMConfig()
    assert not CodeSLAM(cfg, network_depth_model(model)).reads_frame_depth
    assert CodeSLAM(cfg, standin_depth_model()).reads_frame_depth
    assert CodeSLAM(cfg, true_prior_depth_model(network_depth_model(model))).reads_frame_depth


def _tiny_model() -> DepthModel:
    torch.manual_seed(0)
    cfg = NetworkConfig(code_size=4, width=64, height=48, image_channels=(4, 4, 4, 4), depth_channels=(4, 4, 4, 4),
                        full_res_channels=4, bottleneck_channels=4, fc_units=8)
    return DepthModel(CodeNetwork(cfg).eval())


def test_true_prior_keeps_the_network_jacobian_with_the_measured_depth_at_the_zero_code():
    model = _tiny_model()
    frame = resample_frame(synth_frames(3, 12, 10.0)[0], model.camera)
    depth = frame.depth.clone()
    depth[10:14, 20:30] = 0.0  # a sensor's hole: filled from around it
    frame = dataclasses.replace(frame, depth=depth)
    net = network_depth_model(model)(frame)
    dec = true_prior_depth_model(network_depth_model(model))(frame)
    assert dec.num_levels == net.num_levels == 4 and dec.code_size == 4 and dec.avg_depth == net.avg_depth
    zero = torch.zeros(4)
    valid = depth > 0
    want = depth_to_prox(depth.double(), net.avg_depth)
    torch.testing.assert_close(dec.prox(zero, 0)[valid].double(), want[valid], atol=1e-6, rtol=1e-6)
    hole = dec.depth(zero, 0)[~valid]  # filled between the depths around it, not 0 or inf
    assert bool(torch.isfinite(hole).all()) and float(hole.min()) >= float(depth[valid].min()) - 1e-4
    pyr = image_pyramid(dec.prox(zero, 0)[None, None].double(), 4)
    for lvl in range(4):
        assert torch.equal(dec.levels[lvl].jac, net.levels[lvl].jac)  # the network's code Jacobian, untouched
        assert torch.equal(dec.levels[lvl].uncertainty, net.levels[lvl].uncertainty)
        torch.testing.assert_close(dec.prox(zero, lvl).double(), pyr[lvl][0, 0], atol=1e-6, rtol=1e-6)
    assert float((net.prox(zero, 0) - dec.prox(zero, 0)).abs().mean()) > 0.01  # the network's own zero code differs
    with pytest.raises(CodeSLAMError, match="depth maps"):
        true_prior_depth_model(network_depth_model(model))(dataclasses.replace(frame, depth=None))


def test_holes_are_filled_from_their_surroundings_not_with_one_depth():
    # a floor-like ramp from 1 m (bottom rows) to 8 m (top rows): scattered holes as a HoloLens leaves them, and a
    # block at the far end as beyond a sensor's range
    H, W = 48, 64
    depth = torch.linspace(8.0, 1.0, H, dtype=torch.float64)[:, None].expand(H, W).clone()
    valid = torch.rand(H, W, generator=torch.Generator().manual_seed(0)) > 0.5
    valid[:8, 24:40] = False
    out = fill_depth_holes(depth, valid)
    assert torch.equal(out[valid], depth[valid]) and bool(torch.isfinite(out).all())
    rel = (out / depth - 1).abs()
    scattered = ~valid
    scattered[:8, 24:40] = False
    # measured: mean 1.6%, largest 17% (a cluster of holes by the 1 m rows); the median depth is 59% off on average
    assert float(rel[scattered].mean()) < 0.03 and float(rel[scattered].max()) < 0.3
    assert float(out[:8, 24:40].min()) > 6.0  # the far block stays far (the median depth is 4.5 m; truth 7.1-8)
