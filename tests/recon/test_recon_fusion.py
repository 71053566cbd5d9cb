"""Point-cloud fusion: slant cropping on analytic planes, depth edges and holes, the masked bilateral filter, and
back-projection with poses."""

from __future__ import annotations

import math

import pytest
import torch

from codeslam.errors import ConfigError
from codeslam.geometry.camera import canonical_camera, pixel_grid, unproject_jac_depth
from codeslam.geometry.image import slant_cosine
from codeslam.geometry.lie import se3_exp
from codeslam.recon.fusion import (
    FusionConfig,
    FusionView,
    bilateral_depth,
    fuse,
    keep_mask,
    view_points,
)

CAM = canonical_camera(64, 48)
D = torch.float64


def _rays() -> torch.Tensor:
    """(H, W, 3) viewing rays with z = 1."""
    return unproject_jac_depth(pixel_grid(CAM.height, CAM.width, D), CAM.params(D))


def plane_depth(normal, offset: float) -> torch.Tensor:
    """z-depth (H, W) of the plane n . X = offset seen by CAM at the origin."""
    n = torch.tensor(normal, dtype=D)
    return offset / (_rays() @ n)


def plane_cosine(normal) -> torch.Tensor:
    """Analytic |cos| of the angle between the plane's normal and every pixel's ray (H, W)."""
    n = torch.nn.functional.normalize(torch.tensor(normal, dtype=D), dim=0)
    r = torch.nn.functional.normalize(_rays(), dim=-1)
    return (r @ n).abs()


def _normal_at(angle_deg: float) -> tuple[float, float, float]:
    """A plane normal tilted by ``angle_deg`` from the optical axis about the camera's y axis."""
    a = math.radians(angle_deg)
    return (math.sin(a), 0.0, math.cos(a))


@pytest.mark.parametrize("normal", [_normal_at(0.0), _normal_at(30.0), _normal_at(55.0), (0.3, -0.5, 0.81)])
def test_slant_cosine_of_a_plane_is_the_analytic_one(normal):
    """Sobel differences of points on a plane lie in the plane, so the normal is exact everywhere."""
    depth = plane_depth(normal, 2.0)
    assert bool((depth > 0).all())
    cos = slant_cosine(depth[None, None], CAM.params(depth.dtype))[0, 0]
    torch.testing.assert_close(cos, plane_cosine(normal), atol=1e-9, rtol=0)


def test_fronto_parallel_plane_is_kept_entirely_and_a_steep_plane_is_dropped():
    cfg = FusionConfig(bilateral=False, max_slant_deg=75.0)
    flat = plane_depth((0.0, 0.0, 1.0), 2.0)
    assert bool(keep_mask(flat[None, None], CAM, cfg).all())
    # a plane whose normal is 85 degrees from the optical axis: the rays (hfov 60 degrees) meet it at 55-115
    # degrees from its normal; the analytic slant decides which pixels stay
    normal = _normal_at(85.0)
    steep = plane_depth(normal, 0.3)
    valid = steep > 0  # rays more than 90 degrees from the normal miss the plane
    keep = keep_mask(torch.where(valid, steep, torch.zeros_like(steep))[None, None], CAM, cfg)[0, 0]
    cos = plane_cosine(normal)
    assert bool((keep <= (cos >= math.cos(math.radians(75.0)))).all())  # nothing steeper than the limit survives
    # clearly below the limit and away from the invalid half (the 3x3 erosion): everything survives
    interior = -torch.nn.functional.max_pool2d(-valid[None, None].double(), 3, 1, 1)[0, 0] > 0.5
    clear = interior & (cos >= math.cos(math.radians(74.0)))
    assert bool(clear.any()) and bool(keep[clear].all())
    assert 0.05 < keep.double().mean() < 0.6  # a part of the plane stays, most of it goes
    tilted = plane_depth(_normal_at(30.0), 2.0)
    assert bool(keep_mask(tilted[None, None], CAM, cfg).all())  # 30 degrees (+ up to 37 at the border) stays


def test_depth_edge_drops_exactly_the_pixels_whose_sobel_window_spans_it():
    depth = torch.full((CAM.height, CAM.width), 1.0, dtype=D)
    depth[:, 32:] = 2.0
    keep = keep_mask(depth[None, None], CAM, FusionConfig(bilateral=False))[0, 0]
    dropped_cols = sorted({int(c) for c in torch.nonzero(~keep)[:, 1]})
    assert dropped_cols == [31, 32]
    assert bool(keep[:, :31].all()) and bool(keep[:, 33:].all())


def test_holes_and_their_neighbours_are_dropped():
    depth = torch.full((CAM.height, CAM.width), 1.5, dtype=D)
    depth[10, 20] = 0.0
    depth[30, 40] = float("nan")
    keep = keep_mask(depth[None, None], CAM, FusionConfig(bilateral=False))[0, 0]
    assert int((~keep).sum()) == 18
    assert not bool(keep[9:12, 19:22].any()) and not bool(keep[29:32, 39:42].any())


def test_depth_range_limits():
    depth = plane_depth((0.0, 0.0, 1.0), 2.0)
    assert not bool(keep_mask(depth[None, None], CAM, FusionConfig(bilateral=False, max_depth=1.5)).any())
    assert not bool(keep_mask(depth[None, None], CAM, FusionConfig(bilateral=False, min_depth=2.5)).any())


def test_bilateral_filter_smooths_noise_keeps_edges_and_holes():
    gen = torch.Generator().manual_seed(0)
    depth = torch.full((CAM.height, CAM.width), 1.0, dtype=D)
    depth[:, 32:] = 2.0
    noisy = depth * (1 + 0.01 * torch.randn(depth.shape, generator=gen, dtype=D))
    noisy[20, 10] = 0.0  # a hole
    out = bilateral_depth(noisy[None, None], 5, 1.5, 0.05)[0, 0]
    assert out[20, 10] == 0.0  # holes stay invalid
    inner = torch.ones_like(depth, dtype=torch.bool)
    inner[:, 30:34] = False
    inner[18:23, 8:13] = False
    err_in = (noisy - depth)[inner].std()
    err_out = (out - depth)[inner].std()
    assert err_out < 0.5 * err_in  # noise reduced
    # the 1 m / 2 m edge is not blurred: pixels next to it stay within 3% of their side
    assert float(((out[:, 31] - 1.0).abs()).max()) < 0.03 and float(((out[:, 32] - 2.0).abs()).max()) < 0.06
    # neighbours of the hole are not pulled towards 0
    ring = out[19:22, 9:12].clone()
    ring[1, 1] = 1.0  # the hole itself
    assert float(((ring - 1.0).abs()).max()) < 0.03


def test_view_points_back_projects_with_the_pose_and_colours():
    depth = plane_depth((0.0, 0.0, 1.0), 2.0).float()
    image = torch.zeros(3, CAM.height, CAM.width)
    image[0] = 1.0  # red
    T_wc = se3_exp(torch.tensor([0.5, -0.2, 1.0, 0.0, 0.3, 0.0], dtype=D))
    cloud = view_points(FusionView(image, depth, CAM, T_wc), FusionConfig(bilateral=False))
    assert len(cloud) == CAM.height * CAM.width
    # every point lies on the world image of the plane z_c = 2: (R^T (X - t))_z = 2
    X = cloud.xyz.double()
    z_c = ((X - T_wc[:3, 3]) @ T_wc[:3, :3])[:, 2]
    torch.testing.assert_close(z_c, torch.full_like(z_c, 2.0), atol=1e-5, rtol=0)
    assert bool((cloud.rgb == torch.tensor([255, 0, 0], dtype=torch.uint8)).all())


def test_fuse_concatenates_views_within_the_pixel_bound_and_stride_thins():
    depth = plane_depth((0.0, 0.0, 1.0), 2.0).float()
    depth[:, 40:] = 3.0
    image = torch.rand(3, CAM.height, CAM.width)
    views = [FusionView(image, depth, CAM, torch.eye(4, dtype=D)) for _ in range(3)]
    full = fuse(views)
    assert 0 < len(full) <= 3 * CAM.height * CAM.width
    assert len(full) == 3 * len(view_points(views[0]))
    thin = fuse(views, FusionConfig(stride=2))
    assert 0 < len(thin) <= len(full) / 4 + 3 * CAM.height


def test_config_rejects_nonsense():
    with pytest.raises(ConfigError):
        FusionConfig(kernel_size=4)
    with pytest.raises(ConfigError):
        FusionConfig(max_slant_deg=0.0)
    with pytest.raises(ConfigError):
        FusionConfig(min_depth=5.0, max_depth=1.0)
