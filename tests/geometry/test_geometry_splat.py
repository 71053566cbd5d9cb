import math

import torch

from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.splat import splat_depth


def _translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> torch.Tensor:
    T = torch.eye(4, dtype=torch.float64)
    T[:3, 3] = torch.tensor([x, y, z], dtype=torch.float64)
    return T


def test_the_identity_gives_the_depth_back_exactly():
    cam = canonical_camera(32, 24)
    depth = 1.0 + torch.rand(24, 32, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    assert torch.equal(splat_depth(depth, cam, _translation()), depth)


def test_a_plane_approached_by_t_is_t_nearer_everywhere_its_pixels_reach():
    # A fronto-parallel plane 2 m away, the destination 0.5 m nearer: its points spread apart in the image and
    # leave one-pixel cracks, which take their neighbours' depth; the plane fills the whole destination view.
    cam = canonical_camera(32, 24)
    depth = torch.full((24, 32), 2.0, dtype=torch.float64)
    out = splat_depth(depth, cam, _translation(z=-0.5))
    assert torch.isfinite(out).all()
    assert torch.allclose(out, torch.full_like(out, 1.5), atol=1e-12)


def test_the_nearest_surface_wins_where_two_land_on_one_pixel():
    # A square at 1 m before a wall at 4 m; the destination 0.2 m to the side. The square moves 4 times as far in
    # the image as the wall, so it lands on pixels the wall also reaches: those must read the square's depth.
    cam = canonical_camera(64, 48)
    depth = torch.full((48, 64), 4.0, dtype=torch.float64)
    depth[18:30, 26:38] = 1.0
    out = splat_depth(depth, cam, _translation(x=0.2))  # points move +0.2 m in x: right in the image
    shift = cam.fx * 0.2  # pixels the square moves (the wall moves a quarter of it)
    assert shift > 6
    centre_u = round(31.5 + shift)
    assert out[24, centre_u] == 1.0
    near = (out - 1.0).abs() < 1e-9
    assert abs(int(near.sum()) - 144) <= 24, int(near.sum())  # the square's 12x12 pixels, give or take an edge
    assert not near[:, : round(26 + shift) - 1].any()  # nothing of the square left where it was


def test_pixels_outside_the_valid_mask_and_behind_the_camera_are_not_splatted():
    cam = canonical_camera(32, 24)
    depth = torch.full((24, 32), 2.0, dtype=torch.float64)
    valid = torch.zeros(24, 32, dtype=torch.bool)
    valid[:, :16] = True
    out = splat_depth(depth, cam, _translation(), valid)
    assert torch.equal(out[:, :16], depth[:, :16])
    assert torch.equal(out[:, 16], depth[:, 16])  # the crack filling reaches one pixel beyond
    assert torch.isinf(out[:, 17:]).all()
    behind = splat_depth(depth, cam, _translation(z=-3.0))  # the plane is 1 m behind the destination
    assert torch.isinf(behind).all()
    far = depth.clone()
    far[0, 0] = math.inf
    far[0, 1] = 0.0
    out = splat_depth(far, cam, _translation())
    assert out[0, 0] == 2.0 and out[0, 1] == 2.0  # holes of the source are cracks, filled by their neighbours
