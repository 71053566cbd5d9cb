"""Coloured point clouds as PLY files, written atomically.

Vertices carry ``x y z`` (float32) and ``red green blue`` (uint8), the properties every viewer (MeshLab,
CloudCompare, Open3D, Blender) reads as a coloured cloud. Binary little-endian by default; ``text=True`` writes
ASCII PLY. Written here with numpy rather than with plyfile, which is GPL: the format of a vertex list is a
short text header followed by one fixed-size record per vertex (P. Bourke, "PLY - Polygon File Format"). The
test suite reads what we write with plyfile to check it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import torch

from codeslam.errors import DatasetError
from codeslam.io import atomic_write
from codeslam.recon.fusion import PointCloud

#: PLY scalar type names (both spellings of the specification) -> numpy type without byte order.
PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
#: PLY byte order per format (text is parsed, so its order does not matter).
PLY_FORMATS = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}
_VERTEX_FIELDS = [("x", "float", "f4"), ("y", "float", "f4"), ("z", "float", "f4"),
                  ("red", "uchar", "u1"), ("green", "uchar", "u1"), ("blue", "uchar", "u1")]


def _vertex_array(cloud: PointCloud) -> np.ndarray:
    """-> (N,) little-endian structured array with fields x, y, z (f4) and red, green, blue (u1)."""
    xyz = torch.as_tensor(cloud.xyz).detach().cpu().to(torch.float32).numpy()
    rgb = torch.as_tensor(cloud.rgb).detach().cpu().to(torch.uint8).numpy()
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValueError(f"a point cloud needs xyz (N, 3) and rgb (N, 3), got {xyz.shape} and {rgb.shape}")
    vertex = np.empty(len(xyz), dtype=[(name, "<" + t) for name, _, t in _VERTEX_FIELDS])
    for k, name in enumerate("xyz"):
        vertex[name] = xyz[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        vertex[name] = rgb[:, k]
    return vertex


def write_ply(
    path: str | os.PathLike, cloud: PointCloud, text: bool = False, comments: Sequence[str] = ()
) -> None:
    """Write ``cloud`` as a PLY vertex list (x, y, z, red, green, blue), atomically. Each comment becomes one
    header line (line breaks inside it are folded to spaces)."""
    vertex = _vertex_array(cloud)
    header = ["ply", f"format {'ascii' if text else 'binary_little_endian'} 1.0"]
    header += [f"comment {' '.join(str(c).split())}" for c in comments]
    header.append(f"element vertex {len(vertex)}")
    header += [f"property {ply_type} {name}" for name, ply_type, _ in _VERTEX_FIELDS]
    header.append("end_header")
    with atomic_write(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if text:
            # float32 with 9 significant digits reads back bit for bit
            f.write("".join(f"{x:.9g} {y:.9g} {z:.9g} {r} {g} {b}\n" for x, y, z, r, g, b in vertex.tolist())
                    .encode("ascii"))
        else:
            f.write(vertex.tobytes())


def _read_header(f, path) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """-> (format, [(element name, count, [(property, numpy type)])]) from the header of an open PLY file."""
    if f.readline().strip() != b"ply":
        raise DatasetError(f"cannot read point cloud {path}: not a PLY file (no 'ply' magic line)")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    while True:
        raw = f.readline()
        if not raw:
            raise DatasetError(f"cannot read point cloud {path}: the header has no 'end_header'")
        words = raw.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        try:
            if words[0] == "format" and words[1] in PLY_FORMATS:
                fmt = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                raise DatasetError(f"cannot read point cloud {path}: list properties (faces) are not supported")
            elif words[0] == "property" and words[1] in PLY_TYPES and elements:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise ValueError
        except (IndexError, ValueError):
            raise DatasetError(f"cannot read point cloud {path}: bad header line {raw.strip()!r}") from None
    if fmt is None:
        raise DatasetError(f"cannot read point cloud {path}: the header names no format")
    return fmt, elements


def read_ply(path: str | os.PathLike) -> PointCloud:
    """Read the vertices (and colours, white when absent) of a PLY file whose elements have scalar properties
    only (a point cloud, as :func:`write_ply` writes); DatasetError when it cannot be read."""
    try:
        with open(path, "rb") as f:
            fmt, elements = _read_header(f, path)
            vertex = None
            for name, count, props in elements:  # elements are stored one after the other, in header order
                dtype = np.dtype([(p, PLY_FORMATS[fmt] + t) for p, t in props])
                if fmt == "ascii":
                    rows = [f.readline().split() for _ in range(count)]
                    data = np.array([tuple(r) for r in rows], dtype=dtype) if count else np.empty(0, dtype)
                else:
                    data = np.frombuffer(f.read(dtype.itemsize * count), dtype=dtype, count=count)
                if name == "vertex":
                    vertex = data
                    break
    except (OSError, ValueError) as e:
        raise DatasetError(f"cannot read point cloud {path}: {' '.join(str(e).split())}") from None
    if vertex is None or not all(c in (vertex.dtype.names or ()) for c in "xyz"):
        raise DatasetError(f"cannot read point cloud {path}: no vertex element with x, y and z")
    xyz = np.stack([vertex[c].astype(np.float32) for c in "xyz"], axis=1)
    if all(c in vertex.dtype.names for c in ("red", "green", "blue")):
        rgb = np.stack([vertex[c].astype(np.uint8) for c in ("red", "green", "blue")], axis=1)
    else:
        rgb = np.full_like(xyz, 255, dtype=np.uint8)
    return PointCloud(torch.from_numpy(xyz), torch.from_numpy(rgb))
