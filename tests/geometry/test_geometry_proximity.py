"""Proximity p = a / (d + a) (paper Sec. 2.2): derivatives, round trips, invalid values, clamping."""

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from codeslam.constants import MAX_PROXIMITY, MIN_PROXIMITY
from codeslam.geometry.proximity import d_depth_d_prox, d_prox_d_depth, depth_to_prox, prox_to_depth

F64 = torch.float64


def _elementwise_grad(f, x: torch.Tensor) -> torch.Tensor:
    x = x.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f(x).sum(), x)
    return g


def test_d_prox_d_depth_against_autograd():
    depth = torch.rand(100, generator=torch.Generator().manual_seed(0), dtype=F64) * 20 + 0.01
    for a in (0.5, 2.0, torch.full((100,), 3.0, dtype=F64)):
        assert torch.allclose(d_prox_d_depth(depth, a), _elementwise_grad(lambda d, a=a: depth_to_prox(d, a), depth))


def test_d_depth_d_prox_against_autograd():
    prox = torch.rand(100, generator=torch.Generator().manual_seed(1), dtype=F64) * 0.98 + 0.01
    for a in (0.5, 2.0):
        assert torch.allclose(d_depth_d_prox(prox, a), _elementwise_grad(lambda p, a=a: prox_to_depth(p, a), prox))


def test_derivatives_are_reciprocal():
    depth = torch.linspace(0.1, 10, 50, dtype=F64)
    prox = depth_to_prox(depth, 2.0)
    assert torch.allclose(d_prox_d_depth(depth, 2.0) * d_depth_d_prox(prox, 2.0), torch.ones(50, dtype=F64))


def test_average_depth_maps_to_one_half():
    a = 2.0
    assert depth_to_prox(torch.tensor([a]), a).item() == 0.5
    near = depth_to_prox(torch.linspace(1e-3, a, 20), a)
    far = depth_to_prox(torch.linspace(a, 1e3, 20), a)
    assert (near >= 0.5).all() and (near <= 1.0).all() and (far <= 0.5).all() and (far > 0).all()
    assert (near.diff() < 0).all()  # monotone decreasing


def test_invalid_depth_is_zero_both_ways_with_finite_gradients():
    depth = torch.tensor([0.0, -1.0, float("nan"), float("inf"), 1.0], dtype=F64, requires_grad=True)
    prox = depth_to_prox(depth, 2.0)
    assert prox[:4].tolist() == [0.0] * 4
    assert prox_to_depth(prox, 2.0)[:4].tolist() == [0.0] * 4
    prox.sum().backward()
    assert torch.isfinite(depth.grad).all()
    assert d_prox_d_depth(depth.detach(), 2.0)[:4].tolist() == [0.0] * 4
    assert prox_to_depth(torch.tensor([float("nan")]), 2.0).item() == 0.0


def test_decoding_clamps_out_of_range_proximity():
    a = 2.0
    prox = torch.tensor([-0.3, 1e-9, 1.0, 1.7], dtype=F64)
    depth = prox_to_depth(prox, a)
    far = a * (1 - MIN_PROXIMITY) / MIN_PROXIMITY
    near = a * (1 - MAX_PROXIMITY) / MAX_PROXIMITY
    assert torch.allclose(depth, torch.tensor([far, far, near, near], dtype=F64))
    assert d_depth_d_prox(prox, a).tolist() == [0.0] * 4


@settings(max_examples=50, deadline=None)
@given(depth=st.floats(1e-2, 500), a=st.floats(0.1, 10))  # p stays inside the clamp range
def test_depth_prox_round_trip_property(depth, a):
    d = torch.tensor(depth, dtype=F64)
    p = depth_to_prox(d, a)
    assert MIN_PROXIMITY <= p.item() <= MAX_PROXIMITY
    assert torch.isclose(prox_to_depth(p, a), d, rtol=1e-9)


@settings(max_examples=50, deadline=None)
@given(prox=st.floats(MIN_PROXIMITY, MAX_PROXIMITY), a=st.floats(0.1, 10))
def test_prox_depth_round_trip_property(prox, a):
    p = torch.tensor(prox, dtype=F64)
    assert torch.isclose(depth_to_prox(prox_to_depth(p, a), a), p, rtol=1e-9)
