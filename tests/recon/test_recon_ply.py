"""PLY output: plyfile reads what we write (binary and ASCII), values survive, bad input leaves no file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData

from codeslam.errors import DatasetError
from codeslam.recon.fusion import PointCloud
from codeslam.recon.ply import read_ply, write_ply


def _cloud(n: int = 50) -> PointCloud:
    gen = torch.Generator().manual_seed(1)
    return PointCloud(torch.randn(n, 3, generator=gen), torch.randint(0, 256, (n, 3), generator=gen).to(torch.uint8))


@pytest.mark.parametrize("text", [False, True])
def test_round_trip_through_plyfile(tmp_path: Path, text: bool):
    cloud = _cloud()
    path = tmp_path / "c.ply"
    write_ply(path, cloud, text=text, comments=["made by a test\nwith a newline"])
    data = PlyData.read(str(path))
    v = data["vertex"]
    assert v.count == len(cloud)
    assert [p.name for p in v.properties] == ["x", "y", "z", "red", "green", "blue"]
    assert data.text == text
    assert data.comments == ["made by a test with a newline"]
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    np.testing.assert_allclose(xyz, cloud.xyz.numpy(), rtol=1e-6 if text else 0, atol=1e-6 if text else 0)
    back = read_ply(path)
    assert torch.equal(back.rgb, cloud.rgb)


def test_empty_cloud_is_a_valid_file(tmp_path: Path):
    write_ply(tmp_path / "e.ply", PointCloud.concat([]))
    assert PlyData.read(str(tmp_path / "e.ply"))["vertex"].count == 0


def test_bad_cloud_writes_nothing(tmp_path: Path):
    with pytest.raises(ValueError):
        write_ply(tmp_path / "bad.ply", PointCloud(torch.zeros(4, 3), torch.zeros(5, 3, dtype=torch.uint8)))
    assert list(tmp_path.iterdir()) == []


def test_read_ply_reports_garbage(tmp_path: Path):
    (tmp_path / "x.ply").write_text("not a ply file")
    with pytest.raises(DatasetError):
        read_ply(tmp_path / "x.ply")
