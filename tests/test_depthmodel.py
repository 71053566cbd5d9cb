"""The network adapter: canonical resampling, exact linear decoders, and the least-squares code fit."""

from __future__ import annotations

import pytest
import torch

from codeslam.data.frame import Frame
from codeslam.depthmodel import DepthModel, fit_code_linear, fit_cost, predict_depth
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera
from codeslam.network import CodeNetwork, NetworkConfig

TINY = dict(code_size=6, width=32, height=32, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
            full_res_channels=4, bottleneck_channels=4, fc_units=16)


def _model(linear: bool = True, seed: int = 0) -> DepthModel:
    """A random tiny network. Its code layer is scaled up: at initialisation a code entry moves the proximity by
    ~1e-4, too little to test a fit against float32 rounding; scaled by 30 it moves it by ~3e-3 (like a trained
    network's, whose codes are O(1) and change depth by centimetres)."""
    torch.manual_seed(seed)
    net = CodeNetwork(NetworkConfig(**TINY, linear_decoder=linear))
    with torch.no_grad():
        net.decoder.fc.weight.mul_(30.0)
    return DepthModel(net)


def _frame(seed: int = 0, width: int = 48, height: int = 40) -> Frame:
    """A frame of a camera other than the canonical one: a depth ramp with a box and a few holes."""
    g = torch.Generator().manual_seed(seed)
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float32), torch.arange(width, dtype=torch.float32),
                          indexing="ij")
    depth = 1.0 + 2.0 * u / width + 0.5 * v / height
    depth[10:20, 12:24] = 0.8
    image = torch.stack([(1 / depth).clamp(0, 1), 0.5 + 0.4 * torch.sin(0.7 * u), 0.3 + 0.2 * torch.rand(
        height, width, generator=g)])
    depth[torch.rand(height, width, generator=g) < 0.05] = 0.0
    cam = PinholeCamera(fx=40.0, fy=40.0, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height)
    return Frame(0.5, image, cam, depth, torch.eye(4, dtype=torch.float64), 3)


def test_fit_code_linear_matches_a_generic_least_squares_solver():
    g = torch.Generator().manual_seed(0)
    B, C, H, W = 2, 5, 6, 7
    jac = torch.randn(B, C, H, W, generator=g, dtype=torch.float64)
    prox0, target = torch.rand(B, 1, H, W, generator=g, dtype=torch.float64), torch.rand(B, 1, H, W, generator=g,
                                                                                       dtype=torch.float64)
    weight = (torch.rand(B, 1, H, W, generator=g) > 0.3).double() * 40.0
    code = fit_code_linear(prox0, jac, target, weight, prior_weight=0.7)
    for b in range(B):
        # stack sqrt(w) (J c - r) and sqrt(prior) c into one ordinary least-squares problem
        sw = weight[b].flatten().sqrt()
        A = torch.cat([sw[:, None] * jac[b].flatten(1).T, 0.7**0.5 * torch.eye(C, dtype=torch.float64)])
        rhs = torch.cat([sw * (target[b] - prox0[b]).flatten(), torch.zeros(C, dtype=torch.float64)])
        ref = torch.linalg.lstsq(A, rhs[:, None]).solution[:, 0]
        torch.testing.assert_close(code[b], ref, atol=1e-10, rtol=1e-10)


def test_canonical_resamples_image_and_depth_to_the_network_camera():
    model = _model()
    f = model.canonical(_frame())
    assert f.image.shape == (3, 32, 32) and f.depth.shape == (32, 32)
    assert f.index == 3 and f.timestamp == 0.5 and f.pose is not None
    # nearest resampling never invents depths: every value is one of the source's
    src = _frame().depth
    vals = f.depth[f.depth > 0]
    assert bool(torch.isin(vals, src[src > 0]).all())


def test_linear_decoders_reproduce_the_network_at_any_code_on_every_level():
    model = _model()
    frames = [model.canonical(_frame(s)) for s in range(2)]
    feats = model.features(torch.stack([f.image for f in frames]))
    decs = model.linear_decoders(feats)
    codes = torch.randn(2, model.code_size, generator=torch.Generator().manual_seed(3))
    mu = model.decode(feats, codes)
    for i, dec in enumerate(decs):
        assert dec.num_levels == 4 and dec.code_size == model.code_size and dec.avg_depth == model.avg_depth
        assert dec.levels[0].uncertainty is not None
        for lvl in range(4):
            torch.testing.assert_close(dec.prox(codes[i], lvl), mu[lvl][i, 0], atol=2e-5, rtol=1e-4)


def test_keyframe_holds_the_canonical_image_camera_and_decoder():
    model = _model()
    kf = model.keyframe(model.canonical(_frame()))
    assert kf.image.shape == (3, 32, 32) and kf.camera == model.camera
    assert kf.decoder.levels[0].prox0.shape == (32, 32)


@pytest.mark.parametrize("linear", [True, False])
def test_optimised_code_never_fits_worse_than_the_zero_code(linear):
    """A least-squares fit with the prior: cost(c*) <= cost(0) = zero-code data cost, so the RMSE on the fitted
    pixels cannot grow; for the linear decoder it is the exact minimiser (no other code does better)."""
    model = _model(linear, seed=1)
    f = model.canonical(_frame(2))
    feats = model.features(f.image[None])
    target = model.target_prox(f.depth)[None, None]
    weight = (target > 0).float() / 0.01**2
    code = model.fit_codes(feats, target, sigma=0.01)
    zero = torch.zeros_like(code)
    p_fit, p_zero = model.decode(feats, code)[0], model.decode(feats, zero)[0]
    c_fit, c_zero = fit_cost(p_fit, target, weight, code), fit_cost(p_zero, target, weight, zero)
    assert float(c_fit) <= float(c_zero)
    mask = target > 0
    rmse_fit = (p_fit - target)[mask].square().mean().sqrt()
    rmse_zero = (p_zero - target)[mask].square().mean().sqrt()
    assert rmse_fit <= rmse_zero
    if linear:
        assert rmse_fit < rmse_zero
        g = torch.Generator().manual_seed(4)
        for _ in range(5):  # random perturbations of the optimum only raise the cost
            other = code + 0.05 * torch.randn(code.shape, generator=g)
            assert float(fit_cost(model.decode(feats, other)[0], target, weight, other)) > float(c_fit)


def test_fit_recovers_a_code_whose_depth_is_in_the_span():
    model = _model(seed=2)
    f = model.canonical(_frame(1))
    feats = model.features(f.image[None])
    c_true = torch.randn(1, model.code_size, generator=torch.Generator().manual_seed(5))
    target = model.decode(feats, c_true)[0]
    code = model.fit_codes(feats, target, sigma=1e-4)
    torch.testing.assert_close(code, c_true, atol=1e-3, rtol=1e-3)


def test_predict_depth_modes_and_their_requirements():
    model = _model()
    frames = [model.canonical(_frame(s)) for s in range(2)]
    preds = predict_depth(model, frames, ["zero", "encode", "optimise"])
    for p in preds:
        assert set(p.prox) == {"zero", "encode", "optimise"}
        assert p.uncertainty.shape == (32, 32) and bool((p.uncertainty > 0).all())
        assert p.depth("zero", model.avg_depth).shape == (32, 32)
        torch.testing.assert_close(p.codes["zero"], torch.zeros(model.code_size))
    no_depth = [model.canonical(Frame(0.0, torch.rand(3, 40, 48), _frame().camera))]
    assert len(predict_depth(model, no_depth, ["zero"])) == 1
    with pytest.raises(CodeSLAMError, match="ground-truth depth"):
        predict_depth(model, no_depth, ["optimise"])
    with pytest.raises(CodeSLAMError, match="unknown depth mode"):
        predict_depth(model, frames, ["magic"])
