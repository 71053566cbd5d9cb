"""The training loss: Laplace NLL on 4 levels weighted x4 per coarser level, invalid depth masked, KL term."""

from __future__ import annotations

import math

import pytest
import torch

from codeslam.network.loss import (
    kl_to_standard_normal,
    laplace_nll,
    network_loss,
    proximity_pyramid,
    shape_error,
)


def _levels(values: list[float], B: int = 1, size: int = 8) -> list[torch.Tensor]:
    """4 constant maps (B, 1, size / 2^l, size / 2^l)."""
    return [torch.full((B, 1, size >> lvl, size >> lvl), v, dtype=torch.float64) for lvl, v in enumerate(values)]


def test_laplace_nll_by_hand():
    # |0.7 - 0.5| / 0.1 + log 0.1
    assert math.isclose(float(laplace_nll(torch.tensor(0.7), torch.tensor(0.5), torch.tensor(0.1))),
                        2.0 + math.log(0.1), rel_tol=1e-6)


def test_level_weights_are_four_per_level():
    """Constant error e_l on level l: every level contributes 4^l * (pixels of l) * nll_l / N_0 = nll_l."""
    prox = _levels([0.5, 0.5, 0.5, 0.5])
    mu = _levels([0.6, 0.5, 0.5, 0.5])
    b = _levels([0.1, 0.1, 0.1, 0.1])
    zero = torch.zeros(1, 4, dtype=torch.float64)
    base = math.log(0.1)
    parts = network_loss(mu, b, prox, zero, zero, kl_weight=1.0)
    # level 0: 1 + log 0.1 ; levels 1-3: log 0.1 each, weighted 4^l over 4^-l as many pixels
    assert math.isclose(float(parts.nll), (1.0 + base) + 3 * base, rel_tol=1e-9)
    for lvl in range(1, 4):  # moving the error to level l changes the total by exactly the same amount
        mu_l = _levels([0.5] * 4)
        mu_l[lvl] = mu_l[lvl] + 0.1
        assert math.isclose(float(network_loss(mu_l, b, prox, zero, zero, 1.0).nll), float(parts.nll), rel_tol=1e-9)
    assert [round(float(x), 9) for x in parts.nll_levels] == [round(1 + base, 9)] + [round(base, 9)] * 3
    assert float(parts.kl) == 0.0 and float(parts.total) == float(parts.nll)


def test_hand_computed_loss_with_invalid_pixels():
    """A 16x16 batch of two with holes, checked against the formula written out per level."""
    torch.manual_seed(0)
    depth = torch.rand(2, 1, 16, 16, dtype=torch.float64) * 3 + 0.5
    depth[0, 0, 0, 0] = 0.0
    depth[1, 0, 5:7, 3:9] = 0.0
    prox = proximity_pyramid(depth, 2.0)
    mu = [p + 0.05 * torch.randn_like(p) for p in prox]
    b = [0.05 + torch.rand_like(p) * 0.1 for p in prox]
    mean, logvar = torch.randn(2, 4, dtype=torch.float64), torch.randn(2, 4, dtype=torch.float64)
    parts = network_loss(mu, b, prox, mean, logvar, kl_weight=0.5)
    n0 = int((depth > 0).sum())
    expected = 0.0
    for lvl in range(4):
        valid = prox[lvl] > 0
        expected += 4**lvl * float(((prox[lvl] - mu[lvl]).abs() / b[lvl] + b[lvl].log())[valid].sum())
    expected /= n0
    assert math.isclose(float(parts.nll), expected, rel_tol=1e-12)
    kl = float(kl_to_standard_normal(mean, logvar).mean())
    assert math.isclose(float(parts.total), expected + 0.5 * kl / 256, rel_tol=1e-12)


def test_invalid_pixels_are_ignored():
    depth = torch.full((1, 1, 8, 8), 2.0, dtype=torch.float64)
    depth[0, 0, :2, :2] = 0.0  # a hole covering one whole level-1 pixel and a level-0 block
    prox = proximity_pyramid(depth, 2.0)
    assert float(prox[0][0, 0, 0, 0]) == 0.0 and float(prox[1][0, 0, 0, 0]) == 0.0
    assert math.isclose(float(prox[2][0, 0, 0, 0]), 0.5)  # coarser levels average only the valid children
    mu = [torch.full_like(p, 0.5) for p in prox]
    b = [torch.full_like(p, 0.2) for p in prox]
    zero = torch.zeros(1, 2, dtype=torch.float64)
    clean = network_loss(mu, b, prox, zero, zero, 1.0)
    for lvl in range(2):  # garbage predictions at invalid pixels change nothing
        mu[lvl][0, 0, 0, 0] = 100.0
        b[lvl][0, 0, 0, 0] = 1e-3
    dirty = network_loss(mu, b, prox, zero, zero, 1.0)
    assert float(dirty.total) == float(clean.total)


def test_kl_formula_against_torch_distributions():
    mean, logvar = torch.randn(3, 5, dtype=torch.float64), torch.randn(3, 5, dtype=torch.float64)
    q = torch.distributions.Normal(mean, (0.5 * logvar).exp())
    p = torch.distributions.Normal(torch.zeros_like(mean), torch.ones_like(mean))
    ref = torch.distributions.kl_divergence(q, p).sum(-1)
    torch.testing.assert_close(kl_to_standard_normal(mean, logvar), ref)
    assert torch.all(kl_to_standard_normal(torch.zeros(2, 3), torch.zeros(2, 3)) == 0)


def test_zero_code_term_trains_mu_zero_only():
    """nll_zero is the pyramid NLL of the zero-code prediction with b held fixed: its gradient reaches mu_zero,
    never b, and zero_code_weight scales it into the total."""
    torch.manual_seed(1)
    depth = torch.rand(1, 1, 8, 8, dtype=torch.float64) * 3 + 0.5
    prox = proximity_pyramid(depth, 1.5)
    mu = [p.clone() for p in prox]
    mu_zero = [(p + 0.1).requires_grad_() for p in prox]
    b = [torch.full_like(p, 0.2).requires_grad_() for p in prox]
    zero = torch.zeros(1, 2, dtype=torch.float64)
    parts = network_loss(mu, b, prox, zero, zero, 1.0, mu_zero, zero_code_weight=0.5)
    # every valid pixel of every level: 0.1 / 0.2 + log 0.2; weighted 4^l over 4^-l the pixels -> 4x that
    nll_zero, total, nll = (float(t.detach()) for t in (parts.nll_zero, parts.total, parts.nll))  # values; grads below
    assert math.isclose(nll_zero, 4 * (0.5 + math.log(0.2)), rel_tol=1e-12)
    assert math.isclose(total, nll + 0.5 * nll_zero, rel_tol=1e-12)
    grads = torch.autograd.grad(parts.nll_zero, [*mu_zero, *b], allow_unused=True)
    assert all(g is not None and g.abs().sum() > 0 for g in grads[:4])
    assert all(g is None or torch.all(g == 0) for g in grads[4:])


def _prox(depth: torch.Tensor) -> list[torch.Tensor]:
    return proximity_pyramid(depth, 1.5)


def test_shape_error_is_blind_to_each_images_scale():
    """A prediction that is the truth times a constant per image has no shape error, whatever the constants;
    a bent one has, and the same at every scale of it."""
    torch.manual_seed(2)
    depth = torch.rand(2, 1, 16, 16, dtype=torch.float64) * 3 + 0.5
    depth[0, 0, :3, :5] = 0  # holes
    truth = _prox(depth)
    scaled = _prox(depth * torch.tensor([0.4, 2.5], dtype=torch.float64).view(2, 1, 1, 1))
    assert float(shape_error(scaled, truth)) == pytest.approx(0.0, abs=1e-9)
    ramp = torch.linspace(0.7, 1.4, 16, dtype=torch.float64).view(1, 1, 1, 16)  # a tilt: not a scale
    bent = depth * ramp
    err = float(shape_error(_prox(bent), truth))
    assert err > 1e-3
    assert float(shape_error(_prox(bent * 3.0), truth)) == pytest.approx(err, rel=1e-6)


def test_shape_error_ignores_invalid_pixels():
    torch.manual_seed(3)
    depth = torch.rand(1, 1, 16, 16, dtype=torch.float64) * 3 + 0.5
    depth[..., 4:9, 4:9] = 0
    truth = _prox(depth)
    pred = _prox(torch.rand(1, 1, 16, 16, dtype=torch.float64) * 3 + 0.5)
    other = [p.clone() for p in pred]
    for o, t in zip(other, truth):
        o[t == 0] = 0.9  # what the prediction says where the truth is missing
    assert float(shape_error(other, truth)) == pytest.approx(float(shape_error(pred, truth)), rel=1e-12)


def test_shape_error_by_hand():
    """One 1x3 image per level, log-depth residuals R = (0, r, 0): neighbour differences |r|, |r| over 2 pairs
    (x), none in y; variance of (0, r, 0) = 2 r^2 / 9; on each of the 4 levels."""
    p = 1.5 / (torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64) + 1.5)  # depths 1, 2, 3 m at a = 1.5
    truth = [p.view(1, 1, 1, 3)] * 4
    r = 0.3
    d_pred = torch.tensor([1.0, 2.0 * math.exp(r), 3.0], dtype=torch.float64)
    pred = [(1.5 / (d_pred + 1.5)).view(1, 1, 1, 3)] * 4
    assert float(shape_error(pred, truth)) == pytest.approx(4 * (r + 2 * r * r / 9), rel=1e-9)


def test_shape_term_joins_the_total_and_trains_mu_zero_only():
    torch.manual_seed(4)
    depth = torch.rand(1, 1, 16, 16, dtype=torch.float64) * 3 + 0.5  # level 3: 2x2
    prox = _prox(depth)
    mu = [p.clone().requires_grad_() for p in prox]
    mu_zero = [(p * (1 + 0.1 * torch.rand_like(p))).requires_grad_() for p in prox]
    b = [torch.full_like(p, 0.2) for p in prox]
    zero = torch.zeros(1, 2, dtype=torch.float64)
    plain = network_loss(mu, b, prox, zero, zero, 1.0, mu_zero, zero_code_weight=0.5)
    parts = network_loss(mu, b, prox, zero, zero, 1.0, mu_zero, zero_code_weight=0.5, shape_weight=3.0)
    value = float(parts.shape.detach())
    assert float(plain.shape) == 0.0
    assert value == pytest.approx(float(shape_error(mu_zero, prox).detach()), rel=1e-12)
    assert float(parts.total.detach()) == pytest.approx(float(plain.total.detach()) + 3.0 * value, rel=1e-12)
    grads = torch.autograd.grad(parts.shape, [*mu_zero, *mu], allow_unused=True)
    assert all(g is not None and g.abs().sum() > 0 for g in grads[:4])
    assert all(g is None for g in grads[4:])
    with pytest.raises(ValueError, match="shape_weight"):
        network_loss(mu, b, prox, zero, zero, 1.0, None, shape_weight=1.0)
