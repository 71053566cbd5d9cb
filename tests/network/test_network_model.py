"""The network module: shapes, the image-only uncertainty, the linear-decoder identity and the code Jacobian."""

from __future__ import annotations

import pytest
import torch

from codeslam.errors import CodeSLAMError, ConfigError
from codeslam.network.config import NUM_LEVELS, NetworkConfig, RunConfig, load_run_config
from codeslam.network.jacobian import code_jacobian, jacobian_dtype
from codeslam.network.model import CodeNetwork, count_parameters, to_network_image


def _model(cfg: NetworkConfig, seed: int = 0, dtype=torch.float64) -> CodeNetwork:
    torch.manual_seed(seed)
    return CodeNetwork(cfg).to(dtype).eval()


def _autograd_jacobian(model: CodeNetwork, feats, code: torch.Tensor) -> list[torch.Tensor]:
    """Reverse-mode reference: levels x (B, C, h, w)."""
    full = torch.autograd.functional.jacobian(lambda c: tuple(model.decode(feats, c)), code)  # (B,1,h,w,B,C)
    B = code.shape[0]
    return [torch.stack([J[i, 0, :, :, i, :] for i in range(B)]).permute(0, 3, 1, 2) for J in full]


@pytest.mark.parametrize("linear", [True, False])
@pytest.mark.parametrize("in_channels", [1, 3])
def test_output_shapes(tiny_config, linear, in_channels):
    cfg = tiny_config(linear_decoder=linear, in_channels=in_channels, width=48, height=32)
    model = _model(cfg, dtype=torch.float32).train()
    image, prox = torch.rand(2, in_channels, 32, 48), torch.rand(2, 1, 32, 48)
    out = model(image, prox)
    assert len(out.mu) == len(out.b) == NUM_LEVELS
    for lvl in range(NUM_LEVELS):
        assert out.mu[lvl].shape == out.b[lvl].shape == (2, 1, 32 // 2**lvl, 48 // 2**lvl)
        assert (out.b[lvl] > 0).all()
    assert out.code_mean.shape == out.code_logvar.shape == out.code.shape == (2, cfg.code_size)
    assert not torch.equal(out.code, out.code_mean)  # sampled in training
    model.eval()
    assert torch.equal(model(image, prox).code, model(image, prox).code_mean)  # the mean at eval


def test_default_network_size():
    """The documented default: ~3.0M parameters (12 MB of float32), 128x96 grey input, code 128."""
    model = CodeNetwork()
    assert 2_500_000 < count_parameters(model) < 3_500_000
    assert model.camera.width == 128 and model.camera.height == 96


def test_uncertainty_depends_on_the_image_only(tiny_config):
    model = _model(tiny_config())
    image = torch.rand(2, 1, 32, 32, dtype=torch.float64)
    feats = model.image_features(image)
    b = model.uncertainty(feats)
    out1 = model(image, torch.rand(2, 1, 32, 32, dtype=torch.float64), sample=True)
    out2 = model(image, torch.rand(2, 1, 32, 32, dtype=torch.float64), sample=True)
    assert not torch.allclose(out1.code, out2.code)  # different depth and noise ...
    assert not torch.allclose(out1.mu[0], out2.mu[0])  # ... change mu ...
    for lvl in range(NUM_LEVELS):  # ... but never b
        assert torch.equal(out1.b[lvl], b[lvl]) and torch.equal(out2.b[lvl], b[lvl])
    other = model.uncertainty(model.image_features(torch.rand(2, 1, 32, 32, dtype=torch.float64)))
    assert not torch.allclose(other[0], b[0])


def test_linear_decoder_is_affine_in_the_code(tiny_config):
    """D(I, c) = D(I, 0) + J c on every level, with J from code_jacobian (one batched forward pass)."""
    model = _model(tiny_config(), seed=1)
    image = torch.rand(3, 1, 32, 32, dtype=torch.float64)
    prox0, jac = code_jacobian(model, image, all_levels=True)
    feats = model.image_features(image)
    for seed in range(3):
        code = torch.randn(3, 8, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 3
        mu = model.decode(feats, code)
        for lvl in range(NUM_LEVELS):
            pred = prox0[lvl] + torch.einsum("bchw,bc->bhw", jac[lvl], code)[:, None]
            torch.testing.assert_close(mu[lvl], pred, rtol=1e-10, atol=1e-12)
    assert jac[0].abs().max() > 0  # the code matters


def test_linear_jacobian_matches_autograd(tiny_config):
    model = _model(tiny_config(), seed=2)
    image = torch.rand(2, 1, 32, 32, dtype=torch.float64)
    feats = model.image_features(image)
    code = torch.randn(2, 8, dtype=torch.float64)
    prox, jac = code_jacobian(model, feats=feats, code=code, all_levels=True, chunk_size=3)
    ref = _autograd_jacobian(model, feats, code)
    mu = model.decode(feats, code)
    for lvl in range(NUM_LEVELS):
        torch.testing.assert_close(jac[lvl], ref[lvl], rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(prox[lvl], mu[lvl], rtol=1e-9, atol=1e-12)


def test_linear_jacobian_float32_at_default_size():
    """The default network in float32: the identity holds to float tolerance (relative to the proximity)."""
    model = _model(NetworkConfig(code_size=32), dtype=torch.float32)
    image = torch.rand(1, 1, 96, 128)
    prox0, jac = code_jacobian(model, image)
    assert prox0.shape == (1, 1, 96, 128) and jac.shape == (1, 32, 96, 128)
    code = torch.randn(1, 32)
    with torch.no_grad():
        mu = model.decode(model.image_features(image), code)[0]
    pred = prox0 + torch.einsum("bchw,bc->bhw", jac, code)[:, None]
    assert (mu - pred).abs().max() < 1e-4


def test_a_jacobian_computed_in_bfloat16_is_the_float32_one_to_its_precision(tiny_config):
    """The code Jacobian in bfloat16 (SLAMConfig.jacobian_dtype): returned in the features' float32, within
    bfloat16's rounding of the float32 one (8 bits of mantissa: about 0.4% a product, a few of them in a row);
    the decoded proximity is the float32 one, bit for bit."""
    model = _model(tiny_config(), seed=4, dtype=torch.float32)
    feats = model.image_features(torch.rand(2, 1, 32, 32))
    prox, jac = code_jacobian(model, feats=feats, all_levels=True)
    prox_b, jac_b = code_jacobian(model, feats=feats, all_levels=True, dtype=torch.bfloat16)
    for lvl in range(NUM_LEVELS):
        assert jac_b[lvl].dtype == torch.float32
        assert torch.equal(prox_b[lvl], prox[lvl])
        scale = jac[lvl].abs().max()
        err = (jac_b[lvl] - jac[lvl]).abs().max() / scale
        assert 0 < err < 0.03, (lvl, float(err))  # rounded, but to bfloat16's precision


def test_auto_jacobian_type_is_bfloat16_only_on_a_cpu_with_bfloat16_instructions(monkeypatch):
    caps = {"amx_bf16": True, "avx512_bf16": False}
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: caps, raising=False)
    assert jacobian_dtype("auto", "cpu") == torch.bfloat16
    assert jacobian_dtype("auto", "cuda") == torch.float32  # a GPU keeps float32
    assert jacobian_dtype("auto", "cpu", torch.float64) == torch.float32  # a float64 system checks the maths
    caps.update(amx_bf16=False, avx512_bf16=True)  # AVX-512's bfloat16 dot products without the tile unit
    assert jacobian_dtype("auto", "cpu") == torch.bfloat16
    caps["avx512_bf16"] = False  # neither: oneDNN would convert in software, slower than float32
    assert jacobian_dtype("auto", "cpu") == torch.float32
    monkeypatch.delattr(torch.cpu, "get_capabilities")  # a torch that cannot tell: float32
    assert jacobian_dtype("auto", "cpu") == torch.float32
    assert jacobian_dtype("bfloat16") == torch.bfloat16 and jacobian_dtype("float32") == torch.float32
    with pytest.raises(ValueError, match="floating-point"):
        jacobian_dtype("int8")


def test_nonlinear_jacobian_matches_autograd_at_nonzero_code(tiny_config):
    model = _model(tiny_config(linear_decoder=False), seed=3)
    image = torch.rand(2, 1, 32, 32, dtype=torch.float64)
    feats = model.image_features(image)
    code = torch.randn(2, 8, dtype=torch.float64) * 2
    prox, jac = code_jacobian(model, feats=feats, code=code, all_levels=True)
    ref = _autograd_jacobian(model, feats, code)
    mu = model.decode(feats, code)
    for lvl in range(NUM_LEVELS):
        torch.testing.assert_close(jac[lvl], ref[lvl], rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(prox[lvl], mu[lvl], rtol=1e-9, atol=1e-12)
    # nonlinear: the Jacobian really changes with the code (ReLU switching), unlike the linear decoder's
    _, jac0 = code_jacobian(model, feats=feats)
    assert not torch.allclose(jac0, jac[0])


def test_bad_input_is_a_user_error(tiny_config):
    model = _model(tiny_config(), dtype=torch.float32)
    with pytest.raises(CodeSLAMError, match="images of shape"):
        model.image_features(torch.rand(1, 1, 30, 32))
    with pytest.raises(CodeSLAMError, match="3-channel"):
        to_network_image(torch.rand(1, 1, 8, 8), 3)
    grey = to_network_image(torch.ones(1, 3, 8, 8), 1)
    assert grey.shape == (1, 1, 8, 8) and torch.allclose(grey, torch.ones_like(grey))


def test_config_validation_and_yaml_overlay(tmp_path):
    with pytest.raises(ConfigError, match="multiple of 16"):
        NetworkConfig(width=100)
    with pytest.raises(ConfigError, match="in_channels"):
        NetworkConfig(in_channels=2)
    path = tmp_path / "c.yaml"
    path.write_text("network:\n  code_size: 32\n  width: 256\n  height: 192\ntrain:\n  steps: 7\n")
    cfg = load_run_config(path)
    assert cfg.network == NetworkConfig(code_size=32, width=256, height=192)
    assert cfg.train.steps == 7 and cfg.train.batch_size == RunConfig().train.batch_size
    path.write_text("network:\n  code_sise: 32\n")
    with pytest.raises(ConfigError, match="unknown network option"):
        load_run_config(path)
    path.write_text("train:\n  steps: many\n")
    with pytest.raises(ConfigError, match="train.steps must be an integer"):
        load_run_config(path)
    path.write_text("network: [\n")
    with pytest.raises(ConfigError, match="cannot read config"):
        load_run_config(path)


def test_forward_decodes_the_zero_code_in_the_same_call(tiny_config):
    model = _model(tiny_config(linear_decoder=False))
    image, prox = torch.rand(2, 1, 32, 32, dtype=torch.float64), torch.rand(2, 1, 32, 32, dtype=torch.float64)
    out = model(image, prox, sample=True, noise=torch.randn(2, 8, dtype=torch.float64), decode_zero=True)
    feats = model.image_features(image)
    for lvl, (mu, mu0) in enumerate(zip(model.decode(feats, out.code), model.decode(feats, torch.zeros(2, 8,
                                        dtype=torch.float64)), strict=True)):
        torch.testing.assert_close(out.mu[lvl], mu)
        torch.testing.assert_close(out.mu_zero[lvl], mu0)
    assert model(image, prox).mu_zero is None
