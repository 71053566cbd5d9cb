"""Rolling-shutter rectification (codeslam.geometry.rolling_shutter) against images ray-cast row by row."""

from __future__ import annotations

import math

import pytest
import torch

from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.lie import so3_exp
from codeslam.geometry.rolling_shutter import rectify_image, rectify_points, row_times, source_pixels

OMEGA = torch.tensor([0.03, -0.06, 0.02], dtype=torch.float64)  # about 4 degrees over the readout


def _ray_cast(R_wc: torch.Tensor, cam, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """Grey level of a textured plane z = 3 (world) seen through pixels (rows, cols) by a camera at the origin
    turned by R_wc (..., 3, 3)."""
    rays = torch.stack([(cols - cam.cx) / cam.fx, (rows - cam.cy) / cam.fy, torch.ones_like(cols)], -1)
    d = (R_wc @ rays.unsqueeze(-1)).squeeze(-1)
    X = 3.0 * d / d[..., 2:3]
    return 0.5 + 0.2 * torch.sin(4.1 * X[..., 0] + 0.3) * torch.cos(3.3 * X[..., 1]) + 0.1 * torch.sin(7.7 * X[..., 1])


def _render(cam, omega: torch.Tensor, axis: str = "rows") -> torch.Tensor:
    """(H, W) rolling-shutter image: row y seen by the camera turned by s(y) omega (exactly, row by row); with
    ``axis`` "columns" column x by s(x) omega."""
    v, u = torch.meshgrid(torch.arange(cam.height, dtype=torch.float64), torch.arange(cam.width, dtype=torch.float64),
                          indexing="ij")
    s = (v - 0.5 * (cam.height - 1)) / cam.height if axis == "rows" else (u - 0.5 * (cam.width - 1)) / cam.width
    R = so3_exp(s.reshape(-1, 1) * omega.reshape(1, 3)).reshape(cam.height, cam.width, 3, 3)
    return _ray_cast(R, cam, v, u)


def test_row_times_span_the_sensor_rows():
    cam = canonical_camera(128, 96)
    top = torch.tensor([0.0, (0 - cam.cy) / cam.fy, 1.0], dtype=torch.float64)
    bottom = torch.tensor([0.0, (95 - cam.cy) / cam.fy, 1.0], dtype=torch.float64)
    assert math.isclose(float(row_times(top, cam)), -47.5 / 96, abs_tol=1e-12)
    assert math.isclose(float(row_times(bottom, cam)), 47.5 / 96, abs_tol=1e-12)
    # another camera on the same sensor (half the resolution): the same ray, the same row time
    assert math.isclose(float(row_times(bottom, cam)), float(row_times(bottom * 2, cam)), abs_tol=1e-12)


def test_column_times_span_the_sensor_rows_of_a_portrait_frame():
    cam = canonical_camera(96, 128)  # a portrait frame: the sensor's 96 rows are its columns
    left = torch.tensor([(0 - cam.cx) / cam.fx, 0.3, 1.0], dtype=torch.float64)
    right = torch.tensor([(95 - cam.cx) / cam.fx, -0.2, 1.0], dtype=torch.float64)
    assert math.isclose(float(row_times(left, cam, "columns")), -47.5 / 96, abs_tol=1e-12)
    assert math.isclose(float(row_times(right, cam, "columns")), 47.5 / 96, abs_tol=1e-12)
    with pytest.raises(ValueError, match="readout axis"):
        row_times(right, cam, "cols")  # a misspelt axis is not read as rows
    with pytest.raises(ValueError, match="readout axis"):
        source_pixels(cam, cam, OMEGA, axis="cols")  # nor by the image's rectification


@pytest.mark.parametrize("axis", ["rows", "columns"])
def test_rectified_points_are_where_a_global_shutter_sees_the_scene_point(axis):
    cam = canonical_camera(128, 96)
    uv = torch.tensor([[10.0, 5.0], [64.0, 48.0], [120.0, 90.0], [3.0, 80.0]], dtype=torch.float64)
    if axis == "rows":
        s = (uv[:, 1] - 0.5 * (cam.height - 1)) / cam.height
    else:
        s = (uv[:, 0] - 0.5 * (cam.width - 1)) / cam.width
    rays = torch.stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, torch.ones(4, dtype=torch.float64)],
                       -1)
    d = (so3_exp(s[:, None] * OMEGA) @ rays.unsqueeze(-1)).squeeze(-1)  # the rows' rays in the mid-readout camera
    expected = torch.stack([cam.fx * d[:, 0] / d[:, 2] + cam.cx, cam.fy * d[:, 1] / d[:, 2] + cam.cy], -1)
    got = rectify_points(uv, cam, cam, OMEGA, axis)
    assert torch.allclose(got, expected, atol=1e-9)
    assert torch.allclose(rectify_points(uv, cam, cam, torch.zeros(3, dtype=torch.float64), axis), uv, atol=1e-12)


@pytest.mark.parametrize("axis", ["rows", "columns"])
def test_rectified_image_matches_the_global_shutter_image(axis):
    cam = canonical_camera(128, 96)
    rs = _render(cam, OMEGA, axis).float()
    gs = _render(cam, torch.zeros(3, dtype=torch.float64)).float()
    out, inside = rectify_image(rs[None], source_pixels(cam, cam, OMEGA, axis=axis))
    other = "columns" if axis == "rows" else "rows"
    wrong, _ = rectify_image(rs[None], source_pixels(cam, cam, OMEGA, axis=other))
    inner = inside.clone()
    inner[:4], inner[-4:], inner[:, :4], inner[:, -4:] = False, False, False, False
    before = (rs - gs).abs()[inner].mean()
    after = (out[0] - gs).abs()[inner].mean()
    assert before > 0.01  # the readout moves the image by a few pixels (0.021 here)
    assert after < 0.1 * before
    assert (wrong[0] - gs).abs()[inner].mean() > 0.5 * before  # rectified along the other axis: not
    same, all_inside = rectify_image(rs[None], source_pixels(cam, cam, torch.zeros(3)))
    assert torch.allclose(same, rs[None], atol=1e-5) and bool(all_inside.all())


def test_rectification_keeps_the_images_dtype():
    cam = canonical_camera(32, 24)
    uv = source_pixels(cam, cam, OMEGA)
    for dtype in (torch.float32, torch.float64):
        out, inside = rectify_image(torch.rand(2, 24, 32, dtype=dtype), uv)
        assert out.dtype == dtype and out.shape == (2, 24, 32) and inside.shape == (24, 32)
    mask, _ = rectify_image(torch.ones(1, 24, 32, dtype=torch.bool), uv, mode="nearest")
    assert mask.dtype == torch.float32
