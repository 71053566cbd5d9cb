"""Resampling between cameras (the intrinsics correction) and undistortion, on synthetic scenes rendered exactly."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from kornia.geometry.calibration import distort_points, undistort_points

from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera, canonical_camera, pixel_grid, unproject_jac_depth
from codeslam.geometry.image import inside_image
from codeslam.geometry.resample import (
    resample_depth,
    resample_image,
    resample_valid_mask,
    source_pixels,
    undistort_depth,
    undistort_image,
)

F64 = torch.float64
# A tilted plane n . X = 1 in camera coordinates (z between ~1.4 and ~2.9 m over a 70 degree field of view).
PLANE_N = torch.tensor([0.15, -0.1, 0.5], dtype=F64)
# TUM fr1's published radial-tangential coefficients (k1, k2, p1, p2, k3).
TUM_FR1_DIST = (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)


def _texture(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """A smooth texture on the plane's (x, y) coordinates, values in [0, 1]."""
    return 0.5 + 0.2 * torch.sin(3.0 * x + 0.5) * torch.cos(2.5 * y) + 0.1 * x


def _render_rays(ray: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays (..., 3) with unit z -> (image, z-depth), each (...), of the textured plane."""
    z = 1.0 / (ray @ PLANE_N)  # X = z ray with n . X = 1
    X = ray * z[..., None]
    return _texture(X[..., 0], X[..., 1]), z


def _render(cam: PinholeCamera) -> tuple[torch.Tensor, torch.Tensor]:
    """The plane seen by an undistorted camera: image (1, 1, H, W), depth (1, 1, H, W)."""
    ray = unproject_jac_depth(pixel_grid(cam.height, cam.width, F64), cam.params(F64))
    img, z = _render_rays(ray)
    return img[None, None], z[None, None]


def _render_distorted(cam: PinholeCamera) -> torch.Tensor:
    """The plane seen by a distorted camera (1, 1, H, W): each pixel's ray from an accurate point undistortion."""
    grid = pixel_grid(cam.height, cam.width, F64).reshape(-1, 2)
    und = undistort_points(grid, cam.K(F64), torch.tensor(cam.dist, dtype=F64), num_iters=100)
    ray = unproject_jac_depth(und, cam.params(F64))
    img, _ = _render_rays(ray)
    return img.reshape(1, 1, cam.height, cam.width)


SRC = PinholeCamera(fx=60.0, fy=58.0, cx=40.2, cy=29.7, width=80, height=60)


def _strict(src: PinholeCamera, dst: PinholeCamera) -> torch.Tensor:
    """(dst.height, dst.width) bool: pixels whose source lookup is a true bilinear interpolation (all four
    neighbours inside). The valid mask also admits the half-pixel border band, where values are clamped."""
    return inside_image(source_pixels(src, dst, F64), src.height, src.width)


def test_resampled_image_matches_direct_render():
    dst = PinholeCamera(fx=45.0, fy=47.0, cx=31.0, cy=22.5, width=64, height=48)
    img_src, _ = _render(SRC)
    img_dst, _ = _render(dst)
    out = resample_image(img_src, SRC, dst)
    mask = resample_valid_mask(SRC, dst)
    assert mask.float().mean() > 0.9
    assert (out[0, 0][~mask] == 0).all()
    # Bilinear interpolation error of this texture at a 60 px focal length: |g''| h^2 / 8 ~ 1e-3.
    assert (out - img_dst)[0, 0][_strict(SRC, dst)].abs().max() < 2e-3
    assert (out - img_dst)[0, 0][mask].abs().max() < 1e-2  # border band: clamped by at most half a pixel


def test_resampled_depth_is_nearest_and_keeps_z():
    dst = PinholeCamera(fx=45.0, fy=47.0, cx=31.0, cy=22.5, width=64, height=48)
    _, depth_src = _render(SRC)
    depth_src[..., 20:30, 30:40] = 0.0  # a hole
    _, depth_dst = _render(dst)
    out = resample_depth(depth_src, SRC, dst)
    mask = resample_valid_mask(SRC, dst)
    # Every output is a copy of one source depth (never a mix) ...
    src_values = depth_src.flatten()
    assert torch.isin(out.flatten(), src_values).all()
    # ... of the nearest source pixel, so it differs from the directly rendered z by at most the depth change
    # across half a pixel diagonal, and the hole stays a hole.
    uv = source_pixels(SRC, dst, F64)
    nearest = depth_src[0, 0, uv[..., 1].round().long().clamp(0, 59), uv[..., 0].round().long().clamp(0, 79)]
    assert torch.equal(out[0, 0][mask], nearest[mask])
    ok = mask & (out[0, 0] > 0)
    assert (out - depth_dst)[0, 0][ok].abs().max() < 0.03
    assert (out[0, 0][mask] == 0).sum() > 20


def test_anti_aliasing_for_a_large_shrink():
    src = PinholeCamera(fx=517.3, fy=516.5, cx=318.6, cy=255.3, width=640, height=480)
    dst = canonical_camera()
    u, v = pixel_grid(480, 640).unbind(-1)
    checker = ((u.long() + v.long()) % 2).float()[None, None]  # the highest frequency an image can hold
    out = resample_image(checker, src, dst)
    naive = resample_image(checker, src, dst, antialias=False)
    mask = resample_valid_mask(src, dst)
    assert (out[0, 0][mask] - 0.5).abs().max() < 0.05  # filtered to the mean grey
    assert (naive[0, 0][mask] - 0.5).abs().max() > 0.3  # what aliasing looks like
    # A smooth image survives the filtered path.
    img_src, _ = _render(src)
    img_dst, _ = _render(dst)
    assert (resample_image(img_src, src, dst) - img_dst)[0, 0][_strict(src, dst)].abs().max() < 5e-3


@settings(max_examples=30, deadline=None)
@given(
    fx=st.floats(35.0, 90.0), aspect=st.floats(0.9, 1.1),
    dcx=st.floats(-4.0, 4.0), dcy=st.floats(-4.0, 4.0),
    width=st.integers(40, 90), height=st.integers(30, 70),
)
def test_resample_there_and_back_recovers_the_interior_property(fx, aspect, dcx, dcy, width, height):
    dst = PinholeCamera(fx=fx, fy=fx * aspect, cx=(width - 1) / 2 + dcx, cy=(height - 1) / 2 + dcy,
                        width=width, height=height)
    img, _ = _render(SRC)
    back = resample_image(resample_image(img, SRC, dst), dst, SRC)
    # Source pixels whose ray lands at least one pixel inside dst and whose dst neighbours come from
    # at least one pixel inside the source.
    uv = source_pixels(dst, SRC, F64)
    inside_dst = (uv[..., 0] >= 1) & (uv[..., 0] <= width - 2) & (uv[..., 1] >= 1) & (uv[..., 1] <= height - 2)
    grid = pixel_grid(SRC.height, SRC.width, F64)
    inside_src = (grid[..., 0] >= 2) & (grid[..., 0] <= SRC.width - 3) & (grid[..., 1] >= 2) & (
        grid[..., 1] <= SRC.height - 3)
    interior = inside_dst & inside_src
    if interior.sum() < 20:
        return
    assert (back - img)[0, 0][interior].abs().max() < 0.01
    assert (back[0, 0][~resample_valid_mask(dst, SRC)] == 0).all()


def test_distort_undistort_points_round_trip():
    cam = PinholeCamera(fx=130.0, fy=129.0, cx=79.6, cy=63.8, width=160, height=120, dist=TUM_FR1_DIST)
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(200, 2, generator=g, dtype=F64) * torch.tensor([159.0, 119.0], dtype=F64)
    K, dist = cam.K(F64), torch.tensor(cam.dist, dtype=F64)
    back = undistort_points(distort_points(pts, K, dist), K, dist, num_iters=100)
    assert (back - pts).abs().max() < 1e-6


def test_undistort_image_matches_the_ideal_camera():
    cam = PinholeCamera(fx=130.0, fy=129.0, cx=79.6, cy=63.8, width=160, height=120, dist=TUM_FR1_DIST)
    distorted = _render_distorted(cam)
    ideal, ideal_depth = _render(cam.without_distortion())
    out = undistort_image(distorted, cam)
    mask = resample_valid_mask(cam, cam.without_distortion())
    assert mask.float().mean() > 0.9
    assert (out - ideal)[0, 0][_strict(cam, cam.without_distortion())].abs().max() < 1e-3
    assert (out - distorted)[0, 0][mask].abs().max() > 0.02  # the distortion is not negligible
    # Straight from the distorted camera to the canonical one in one interpolation.
    canon = canonical_camera(64, 48)
    direct, _ = _render(canon)
    both = resample_image(distorted, cam, canon)
    assert (both - direct)[0, 0][_strict(cam, canon)].abs().max() < 3e-3  # 2.3x shrink: pre-filtered


def test_undistort_depth_keeps_values():
    cam = PinholeCamera(fx=130.0, fy=129.0, cx=79.6, cy=63.8, width=160, height=120, dist=TUM_FR1_DIST)
    depth = torch.rand(2, 1, 120, 160, generator=torch.Generator().manual_seed(1)) + 0.5
    depth[:, :, :10] = 0.0
    out = undistort_depth(depth, cam)
    assert out.shape == (2, 1, 120, 160)
    assert torch.isin(out.flatten(), depth.flatten()).all()


def test_bad_inputs_raise_codeslam_errors():
    with pytest.raises(CodeSLAMError, match="camera is 80x60"):
        resample_image(torch.zeros(1, 1, 10, 10), SRC, canonical_camera())
    with pytest.raises(CodeSLAMError, match="no distortion"):
        resample_image(torch.zeros(1, 1, 60, 80), SRC, SRC.cropped(0, 0, 80, 60).__class__(
            fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60, dist=TUM_FR1_DIST))


def test_identity_resample_is_exact_and_dtype_follows_input():
    img = torch.rand(1, 3, 60, 80, generator=torch.Generator().manual_seed(2))
    out = resample_image(img, SRC, SRC)
    assert out.dtype == torch.float32 and torch.allclose(out, img, atol=1e-5)
    assert math.isclose(resample_valid_mask(SRC, SRC).float().mean().item(), 1.0)


def test_resample_validity_marks_exactly_the_pixels_undistortion_fills():
    """Undistorting TUM fr1's camera leaves parts of the frame uncovered (filled with 0): the validity mask is
    False exactly there, and a resampled mask drops every pixel whose footprint touches an invalid one."""
    from codeslam.data.imageio import undistort_frame
    from codeslam.geometry.resample import resample_validity

    cam = PinholeCamera(160.0, 160.0, 79.5, 61.5, 160, 120, TUM_FR1_DIST)
    image, _, valid = undistort_frame(cam, torch.ones(3, 120, 160), None)
    assert valid is not None and 0 < int((~valid).sum()) < valid.numel() // 4
    assert torch.equal(valid, image.mean(0) > 0)
    ideal = cam.without_distortion()
    assert resample_validity(None, ideal, ideal) is None  # identity, every pixel real
    mask = torch.ones(120, 160, dtype=torch.bool)
    mask[:, 80] = False  # one invalid column
    half = ideal.resized(80, 60)
    out = resample_validity(mask, ideal, half)
    assert out is not None and not bool(out[:, 40].any()) and bool(out[:, 20].all()) and bool(out[:, 60].all())


def test_cached_lookups_give_the_uncached_values_and_no_shared_tensor():
    """The sampling grid and the valid mask are cached per pair of cameras (every frame of a sequence is resampled
    between the same cameras). The values are bit for bit those of the lookup at the map computed afresh, and
    what a caller gets can be changed without touching the cache."""
    from codeslam.geometry.image import bilinear_sample, nearest_sample

    dist = PinholeCamera(160.0, 160.0, 79.5, 61.5, 160, 120, TUM_FR1_DIST)
    ideal = dist.without_distortion()
    small = ideal.resized(40, 30)  # no anti-aliasing pass below a shrink of 4: the lookup alone
    img = torch.rand(2, 3, 120, 160, generator=torch.Generator().manual_seed(4))
    depth = torch.rand(1, 1, 120, 160, generator=torch.Generator().manual_seed(5)) + 0.5
    for src, dst in ((ideal, small), (dist, ideal)):
        mask = inside_image(source_pixels(src, dst, F64), src.height, src.width, margin=0.5)
        uv = source_pixels(src, dst, torch.float32)
        direct, _ = bilinear_sample(img, uv.expand((2,) + uv.shape), padding_mode="border")
        for _ in range(2):  # the first call fills the caches, the second reads them
            assert torch.equal(resample_valid_mask(src, dst), mask)
            assert torch.equal(resample_image(img, src, dst, antialias=False), direct * mask)
        uv64 = source_pixels(src, dst, F64).to(torch.float32)
        near, _ = nearest_sample(depth, uv64[None])
        assert torch.equal(resample_depth(depth, src, dst), near * mask)
    resample_valid_mask(dist, ideal)[:] = False  # the caller's own copy: the cache keeps its mask
    assert bool(resample_valid_mask(dist, ideal).any())
    assert torch.equal(resample_image(img, dist, ideal, antialias=False).ne(0).any(1), mask.expand(2, -1, -1))


def test_validity_of_a_repeated_mask_comes_from_the_cache_and_is_the_callers_own():
    """A reader that masks a fixed border gives every frame the same validity mask; its resampling is kept per
    pair of cameras, and a different mask is resampled afresh."""
    from codeslam.geometry.resample import resample_validity

    cam = PinholeCamera(160.0, 160.0, 79.5, 61.5, 160, 120)
    half = cam.resized(80, 60)
    valid = torch.ones(120, 160, dtype=torch.bool)
    valid[:, 80] = False
    first = resample_validity(valid, cam, half)
    first[:] = True  # the caller's to change
    again = resample_validity(valid.clone(), cam, half)
    assert not bool(again[:, 40].any()) and bool(again[:, 20].all())
    valid[:, 100] = False  # another mask between the same cameras is resampled afresh
    other = resample_validity(valid, cam, half)
    assert not bool(other[:, 50].any()) and bool(again[:, 50].all())
    assert resample_validity(None, cam, cam) is None
