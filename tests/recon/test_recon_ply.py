"""PLY files: plyfile (an independent implementation, test-only) reads what we write and we read what it writes
(binary of either byte order and ASCII, other elements and properties beside the vertices); values survive, bad
input leaves no file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

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


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("byte_order", ["<", ">"])
def test_reads_what_plyfile_writes(tmp_path: Path, text: bool, byte_order: str):
    """Another writer's layout: an element before the vertices, double positions, an extra vertex property."""
    vertex = np.array([(1.5, 2.25, -3.0, 255, 0, 7, 0.5), (0.1, 0.2, 0.3, 1, 2, 3, 0.0)],
                      dtype=[("x", "f8"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                             ("nx", "f4")])
    camera = np.array([(1, 2)], dtype=[("a", "i4"), ("b", "i2")])
    path = tmp_path / "other.ply"
    PlyData([PlyElement.describe(camera, "camera"), PlyElement.describe(vertex, "vertex")], text=text,
            byte_order=byte_order).write(str(path))
    back = read_ply(path)
    np.testing.assert_array_equal(back.xyz.numpy(), np.stack([vertex[c] for c in "xyz"], 1).astype(np.float32))
    np.testing.assert_array_equal(back.rgb.numpy(), np.stack([vertex[c] for c in ("red", "green", "blue")], 1))


def test_empty_cloud_is_a_valid_file(tmp_path: Path):
    write_ply(tmp_path / "e.ply", PointCloud.concat([]))
    assert PlyData.read(str(tmp_path / "e.ply"))["vertex"].count == 0


def test_bad_cloud_writes_nothing(tmp_path: Path):
    with pytest.raises(ValueError):
        write_ply(tmp_path / "bad.ply", PointCloud(torch.zeros(4, 3), torch.zeros(5, 3, dtype=torch.uint8)))
    assert list(tmp_path.iterdir()) == []


HEADER = "ply\nformat {} 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"


@pytest.mark.parametrize("content", [
    "not a ply file", "", "ply\nformat ascii 1.0\nelement vertex 1\n",  # no magic, empty, no end_header
    HEADER.format("ascii") + "1 2 3\n4 5\n", HEADER.format("ascii") + "1 2 3\na b c\n",  # short row, not numbers
    HEADER.format("binary_little_endian") + "123",  # truncated
    HEADER.format("ascii").replace("x\n", "x\nproperty list uchar int vertex_indices\n"),  # faces
])
def test_read_ply_reports_garbage(tmp_path: Path, content: str):
    (tmp_path / "x.ply").write_text(content)
    with pytest.raises(DatasetError, match="cannot read point cloud"):
        read_ply(tmp_path / "x.ply")
