"""Camera effects of training data version 2: each effect does what its docstring says, geometry moves depth with
the image, a step's draws repeat, and configs without effects leave augmentation as it was."""

from __future__ import annotations

import math

import pytest
import torch

from codeslam.network.camera_effects import (
    CameraEffects,
    apply_camera_effects,
    exposure_gain,
    lens_distortion,
    motion_blur,
    rolling_shutter,
    sensor_noise,
    vignette,
)
from codeslam.network.config import TrainConfig
from codeslam.network.data import augment_batch, camera_effects_of

H, W = 24, 32


def _ramp(b: int = 2) -> torch.Tensor:
    """(b, 3, H, W) a smooth image with horizontal and vertical structure."""
    v, u = torch.meshgrid(torch.linspace(0, 1, H), torch.linspace(0, 1, W), indexing="ij")
    return torch.stack([0.2 + 0.6 * u, 0.3 + 0.4 * v, 0.5 + 0.2 * u * v])[None].expand(b, 3, H, W).clone()


def test_photometric_effects():
    x = _ramp()
    assert torch.allclose(exposure_gain(x, torch.zeros(2)), x)
    assert float(exposure_gain(x, torch.full((2,), 2.0)).max()) == 1.0  # saturates
    v = vignette(torch.ones(1, 1, H, W), torch.tensor([0.5]))
    assert float(v[0, 0, 0, 0]) == pytest.approx(0.5, abs=1e-6) and float(v[0, 0, H // 2, W // 2]) > 0.99
    n = torch.randn(2, 3, H, W, generator=torch.Generator().manual_seed(0))
    assert torch.equal(sensor_noise(x, torch.zeros(2), torch.ones(2), n), x)
    dark, bright = torch.full((1, 1, 64, 64), 0.05), torch.full((1, 1, 64, 64), 0.8)
    g = torch.ones(1)
    nd = sensor_noise(dark, torch.full((1,), 0.05), g, torch.randn(1, 1, 64, 64)) - dark
    nb = sensor_noise(bright, torch.full((1,), 0.05), g, torch.randn(1, 1, 64, 64)) - bright
    assert float(nb.std()) > 2 * float(nd.std())  # shot noise grows with the signal


def test_motion_blur_spreads_a_dot_along_its_direction_and_keeps_flat_images():
    dot = torch.zeros(1, 1, 21, 21)
    dot[0, 0, 10, 10] = 1.0
    h = motion_blur(dot, torch.tensor([6.0]), torch.tensor([0.0]))[0, 0]
    assert float(h.sum()) == pytest.approx(1.0, abs=1e-5)
    assert float(h[10].sum()) > 0.99 and float(h[10, 13]) > 0.05  # all of it on the row, spread along x
    vert = motion_blur(dot, torch.tensor([6.0]), torch.tensor([math.pi / 2]))[0, 0]
    assert float(vert[:, 10].sum()) > 0.99
    assert torch.allclose(motion_blur(dot, torch.tensor([0.0]), torch.tensor([0.3])), dot, atol=1e-6)
    flat = torch.full((2, 3, H, W), 0.4)
    assert torch.allclose(motion_blur(flat, torch.tensor([5.0, 3.0]), torch.tensor([0.2, 1.0])), flat, atol=1e-6)


def test_geometric_effects_move_depth_with_the_image():
    x = _ramp(1)
    depth = 1.0 + x[:, :1]  # depth and channel 0 carry the same pattern
    img, dep = rolling_shutter(x, depth, torch.tensor([0.0]))
    assert torch.allclose(img, x, atol=1e-6) and torch.equal(dep, depth)
    # a shift of an even number of pixels moves the bottom row right by half of it, the top row left
    img, dep = rolling_shutter(x, depth, torch.tensor([4.0]))
    assert torch.allclose(img[0, 0, -1, 4:], x[0, 0, -1, 2:-2], atol=1e-5)
    assert torch.allclose(img[0, 0, 0, :-4], x[0, 0, 0, 2:-2], atol=1e-5)
    assert torch.allclose(dep[..., 3:-3], 1.0 + img[:, :1, :, 3:-3], atol=2e-2)  # away from the edges
    assert bool((dep[0, 0, -1, :2] == 0).all())  # what comes in from outside the image has no depth
    img, dep = lens_distortion(x, depth, torch.tensor([0.0]))
    assert torch.allclose(img, x, atol=1e-5) and torch.equal(dep, depth)
    img, dep = lens_distortion(x, depth, torch.tensor([0.3]))  # the undistorted corners are not covered
    assert float(dep[0, 0, 0, 0]) == 0.0 and float(img[0, :, 0, 0].abs().max()) < 1e-6
    assert float(dep[0, 0, H // 2, W // 2]) > 0 and float((dep == 0).float().mean()) < 0.2


def test_apply_is_reproducible_and_off_by_default():
    x, depth = _ramp(), torch.ones(2, 1, H, W)
    fx = CameraEffects(exposure=0.5, vignetting=0.4, sensor_noise=0.03, motion_blur=5, rolling_shutter=3,
                       distortion=0.2)
    a = apply_camera_effects(x, depth, fx, torch.Generator().manual_seed(1))
    b = apply_camera_effects(x, depth, fx, torch.Generator().manual_seed(1))
    c = apply_camera_effects(x, depth, fx, torch.Generator().manual_seed(2))
    assert torch.equal(a[0], b[0]) and not torch.equal(a[0], c[0])
    assert float(a[0].min()) >= 0 and float(a[0].max()) <= 1
    assert camera_effects_of(TrainConfig()) is None
    cfg = TrainConfig(exposure=0.5)
    assert camera_effects_of(cfg) == CameraEffects(exposure=0.5)
    imgs = (x * 255).round().to(torch.uint8)
    dep = torch.full((2, H, W), 5000, dtype=torch.int32).to(torch.uint16)
    plain = augment_batch(imgs, dep, TrainConfig(), 1, torch.Generator().manual_seed(3))[0]
    again = augment_batch(imgs, dep, TrainConfig(), 1, torch.Generator().manual_seed(3))[0]
    exposed = augment_batch(imgs, dep, cfg, 1, torch.Generator().manual_seed(3))[0]
    assert torch.equal(plain, again) and not torch.equal(plain, exposed)
    with pytest.raises(Exception, match="motion_blur"):
        TrainConfig(motion_blur=50.0)


def test_narrow_field_of_view_blacks_out_bands_and_their_depth():
    from codeslam.network.camera_effects import narrow_field_of_view

    x, depth = _ramp(2), torch.ones(2, 1, H, W)
    bands = torch.tensor([[0.25, 0.0, 0.0, 0.125], [0.0, 0.0, 0.0, 0.0]])
    img, dep = narrow_field_of_view(x, depth, bands)
    assert float(img[0, :, :6].abs().max()) == 0.0 and float(dep[0, :, :6].max()) == 0.0  # top quarter
    assert float(img[0, :, :, -4:].abs().max()) == 0.0 and float(dep[0, :, 6:, :-4].min()) == 1.0
    assert torch.equal(img[1], x[1]) and torch.equal(dep[1], depth[1])
    fx = CameraEffects(border=0.15)
    out, d = apply_camera_effects(x, depth, fx, torch.Generator().manual_seed(0))
    assert float((d == 0).float().mean()) < 0.5
