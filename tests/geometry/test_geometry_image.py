"""Image utilities: gradient scale, pyramid geometry, masked depth pyramid, sub-pixel lookup."""

import pytest
import torch

from codeslam.geometry.camera import PinholeCamera, pixel_grid
from codeslam.geometry.image import (
    bilinear_sample,
    depth_pyramid,
    image_gradients,
    image_is_finite,
    image_pyramid,
    nearest_sample,
    pyramid_cameras,
    rgb_to_gray,
    sample_with_gradient,
)

F64 = torch.float64


def _ramp(h: int, w: int, gu: float, gv: float, c: float = 0.1) -> torch.Tensor:
    """(1, 1, h, w) image I = c + gu u + gv v."""
    grid = pixel_grid(h, w, F64)
    return (c + gu * grid[..., 0] + gv * grid[..., 1])[None, None]


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_image_is_finite_finds_one_bad_pixel(bad):
    img = torch.rand(3, 384, 512)
    assert image_is_finite(img) and image_is_finite(torch.ones(3, 480, 640))
    img[1, 200, 300] = bad
    assert not image_is_finite(img)
    img[1, 200, 300] = 0.5
    img[0, 0, 0], img[2, -1, -1] = float("inf"), float("-inf")  # the two infinities do not cancel
    assert not image_is_finite(img)


def test_rgb_to_gray_weights():
    img = torch.zeros(1, 3, 2, 2)
    img[:, 1] = 1.0
    assert torch.allclose(rgb_to_gray(img), torch.full((1, 1, 2, 2), 0.587), atol=1e-6)
    assert rgb_to_gray(torch.rand(2, 3, 5, 7)).shape == (2, 1, 5, 7)


def test_gradients_are_per_pixel_derivatives_on_a_ramp():
    img = _ramp(12, 16, 0.03, -0.02)
    g = image_gradients(img)
    assert g.shape == (1, 1, 2, 12, 16)
    inner = g[..., 1:-1, 1:-1]
    assert torch.allclose(inner[:, :, 0], torch.full_like(inner[:, :, 0], 0.03))
    assert torch.allclose(inner[:, :, 1], torch.full_like(inner[:, :, 1], -0.02))


def test_image_pyramid_sizes_and_pixel_centre_geometry():
    levels = 4
    img = _ramp(48, 64, 0.01, 0.02)
    pyr = image_pyramid(img, levels)
    assert [tuple(p.shape[-2:]) for p in pyr] == [(48 // 2**k, 64 // 2**k) for k in range(levels)]
    # A linear ramp survives the blur; level k's pixel (u, v) sits at ((u + 0.5) 2^k - 0.5, ...) of level 0, which
    # is the geometry of pyramid_cameras (camera.scaled(0.5 ** k)).
    cam = PinholeCamera(fx=50.0, fy=50.0, cx=31.5, cy=23.5, width=64, height=48)
    for k, (level, cam_k) in enumerate(zip(pyr, pyramid_cameras(cam, levels))):
        assert (cam_k.width, cam_k.height) == (level.shape[-1], level.shape[-2])
        s = 2**k
        expected = _ramp(level.shape[-2], level.shape[-1], 0.01 * s, 0.02 * s, 0.1 + 0.03 * (s - 1) / 2)
        assert torch.allclose(level[..., 2:-2, 2:-2], expected[..., 2:-2, 2:-2], atol=1e-9)
        assert abs(cam_k.cx - ((cam.cx + 0.5) / s - 0.5)) < 1e-12


def test_depth_pyramid_ignores_invalid_children():
    depth = torch.tensor([[1.0, 3.0, 0.0, 0.0], [0.0, 0.0, 0.0, float("nan")], [2.0, 2.0, 5.0, 0.0],
                          [2.0, 2.0, 0.0, 7.0]])[None, None]
    pyr = depth_pyramid(depth, 3)
    assert torch.equal(pyr[0].isnan(), torch.zeros_like(depth, dtype=torch.bool))
    assert pyr[1][0, 0].tolist() == [[2.0, 0.0], [2.0, 6.0]]
    assert pyr[2][0, 0, 0, 0].item() == pytest.approx((2.0 + 2.0 + 6.0) / 3)  # mean of the valid children only


def test_bilinear_sample_is_exact_on_linear_images_and_reports_validity():
    img = torch.cat([_ramp(10, 12, 0.5, -0.25), _ramp(10, 12, 0.0, 1.0)], dim=1).expand(2, 2, 10, 12)
    uv = torch.tensor([[[0.0, 0.0], [3.3, 7.9], [11.0, 9.0], [11.2, 3.0]],
                       [[5.5, 4.25], [-0.1, 2.0], [2.0, 9.5], [6.0, 6.0]]], dtype=F64)
    values, valid = bilinear_sample(img, uv)
    assert values.shape == (2, 2, 4) and valid.shape == (2, 4)
    assert valid.tolist() == [[True, True, True, False], [True, False, False, True]]
    expected = torch.stack([0.1 + 0.5 * uv[..., 0] - 0.25 * uv[..., 1], 0.1 + uv[..., 1]], dim=1)
    assert torch.allclose(values[valid[:, None].expand_as(values)], expected[valid[:, None].expand_as(values)])


def test_nearest_sample_never_mixes_values():
    img = torch.arange(12.0).reshape(1, 1, 3, 4)
    uv = torch.tensor([[[0.4, 0.4], [1.6, 1.2], [3.4, 2.4], [-0.6, 0.0]]])
    values, valid = nearest_sample(img, uv)
    assert values[0, 0, :3].tolist() == [0.0, 6.0, 11.0]
    assert valid.tolist() == [[True, True, True, False]]


def test_sample_with_gradient_matches_separate_lookups():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(2, 3, 9, 11, generator=g)
    grad = image_gradients(img)
    uv = torch.rand(2, 20, 2, generator=g) * torch.tensor([10.0, 8.0])
    values, grads, valid = sample_with_gradient(img, grad, uv)
    assert grads.shape == (2, 3, 2, 20)
    v2, valid2 = bilinear_sample(img, uv)
    gu, _ = bilinear_sample(grad[:, :, 0], uv)
    gv, _ = bilinear_sample(grad[:, :, 1], uv)
    assert torch.allclose(values, v2) and torch.equal(valid, valid2)
    assert torch.allclose(grads[:, :, 0], gu) and torch.allclose(grads[:, :, 1], gv)
