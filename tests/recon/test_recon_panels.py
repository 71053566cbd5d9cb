"""Panels: a PNG of the expected size is written atomically; the Jacobian colouring's signs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.recon.panels import Tile, depth_range, signed_overlay, write_panel


def test_panel_png_is_written(tmp_path: Path):
    img = torch.rand(3, 24, 32)
    depth = 1 + torch.rand(24, 32)
    depth[0, 0] = 0.0
    rows = [[Tile("image", img), Tile("gt", depth, "depth"), Tile("b", torch.rand(24, 32), "uncertainty")],
            [Tile("grey", img[0]), None, Tile("pred", depth * 1.1, "depth")]]
    write_panel(tmp_path / "p.png", rows, title="test")
    with Image.open(tmp_path / "p.png") as im:
        assert im.format == "PNG" and im.size[0] > 200 and im.size[1] > 100
    assert [p.name for p in tmp_path.iterdir()] == ["p.png"]


def test_bad_tile_kind_and_empty_panel_are_refused(tmp_path: Path):
    with pytest.raises(ValueError):
        Tile("x", np.zeros((2, 2)), "histogram")
    with pytest.raises(ValueError):
        write_panel(tmp_path / "e.png", [])
    assert not (tmp_path / "e.png").exists()


def test_depth_range_ignores_invalid_values():
    lo, hi = depth_range([np.array([0.0, np.nan, 1.0, 2.0, 3.0])], percentiles=(0, 100))
    assert (lo, hi) == (1.0, 3.0)
    assert depth_range([np.zeros(4)]) == (0.0, 1.0)


def test_signed_overlay_colours_by_sign_and_keeps_the_image_where_zero():
    gray = np.full((2, 3), 0.5)
    values = np.array([[1.0, 0.0, -1.0], [0.5, 0.0, -0.5]])
    out = signed_overlay(gray, values, scale=1.0)
    assert out.shape == (2, 3, 3)
    assert out[0, 0, 0] > out[0, 0, 2]  # positive: red
    assert out[0, 2, 2] > out[0, 2, 0]  # negative: blue
    np.testing.assert_allclose(out[:, 1], 0.5)  # zero: the grey image
