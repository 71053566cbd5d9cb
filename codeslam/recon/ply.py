"""Coloured point clouds as PLY files (plyfile), written atomically.

Vertices carry ``x y z`` (float32) and ``red green blue`` (uint8), the properties every viewer (MeshLab,
CloudCompare, Open3D, Blender) reads as a coloured cloud. Binary little-endian by default; ``text=True`` writes
ASCII PLY.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import torch

from codeslam.errors import DatasetError
from codeslam.io import atomic_write
from codeslam.recon.fusion import PointCloud


def _vertex_array(cloud: PointCloud) -> np.ndarray:
    """-> (N,) structured array with fields x, y, z (f4) and red, green, blue (u1)."""
    xyz = torch.as_tensor(cloud.xyz).detach().cpu().to(torch.float32).numpy()
    rgb = torch.as_tensor(cloud.rgb).detach().cpu().to(torch.uint8).numpy()
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValueError(f"a point cloud needs xyz (N, 3) and rgb (N, 3), got {xyz.shape} and {rgb.shape}")
    vertex = np.empty(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"),
                                       ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for k, name in enumerate("xyz"):
        vertex[name] = xyz[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        vertex[name] = rgb[:, k]
    return vertex


def write_ply(
    path: str | os.PathLike, cloud: PointCloud, text: bool = False, comments: Sequence[str] = ()
) -> None:
    """Write ``cloud`` as a PLY vertex list (x, y, z, red, green, blue), atomically."""
    from plyfile import PlyData, PlyElement

    element = PlyElement.describe(_vertex_array(cloud), "vertex")
    data = PlyData([element], text=text, comments=[" ".join(str(c).split()) for c in comments])
    with atomic_write(path, "wb") as f:
        data.write(f)


def read_ply(path: str | os.PathLike) -> PointCloud:
    """Read the vertices (and colours, white when absent) of a PLY file; DatasetError when it cannot be read."""
    from plyfile import PlyData, PlyParseError

    try:
        data = PlyData.read(str(path))
        v = data["vertex"]
    except (OSError, KeyError, ValueError, PlyParseError) as e:
        raise DatasetError(f"cannot read point cloud {path}: {' '.join(str(e).split())}") from None
    xyz = np.stack([np.asarray(v[c], dtype=np.float32) for c in "xyz"], axis=1)
    names = v.data.dtype.names or ()
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([np.asarray(v[c], dtype=np.uint8) for c in ("red", "green", "blue")], axis=1)
    else:
        rgb = np.full_like(xyz, 255, dtype=np.uint8)
    return PointCloud(torch.from_numpy(xyz), torch.from_numpy(rgb))
