"""Procedural indoor scenes: a room with floor, walls and ceiling, furniture, clutter, wall decor and lights.

World frame: z up, metres, the room spans ``[0, W] x [0, D] x [0, H]``. A scene is a handful of tensors of
analytic primitives (see :mod:`codeslam.synth.primitives`) with a material table
(:mod:`codeslam.synth.textures`) and point lights. Everything is drawn from one ``numpy`` Generator seeded
by the scene seed, so a seed always gives the same scene.

Furniture is composed of primitives in an object frame (x along the object, y towards its front, z up from
the floor) and placed either against a wall (facing into the room) or free-standing; footprints do not
overlap. Tables, desks, shelves and cabinet tops carry clutter (books, mugs, bottles, papers, bowls,
keyboards, boxes, plants).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.synth import textures as tx
from codeslam.synth.primitives import (
    BOX,
    CYLINDER,
    ELLIPSOID,
    SDF_FUNCS,
    Prims,
    sdf_room,
)

# Point-light falloff is I / (d² + s²) with this softening length s (metres): no singular highlights near a lamp.
LIGHT_SOFTENING = 0.5


@dataclass
class Scene:
    """A synthetic room.

    Attributes:
        room_lo, room_hi: (3,) float32 corners of the room box.
        room_material: (6,) int64 material of each room face ``2 * axis + (face at hi)``; 4 = floor, 5 = ceiling.
        prims: (boxes, cylinders, ellipsoids), each a :class:`Prims`.
        materials: (M, MATERIAL_PARAMS) float32 material table.
        light_pos: (L, 3) float32 point-light positions.
        light_rgb: (L, 3) float32 linear intensities (irradiance at 1 m).
        ambient: (3,) float32 linear ambient irradiance.
        seed: the seed the scene was built from.
        surfaces: horizontal tops where clutter stands (tables, desks, shelves), as tuples
            ``(cx, cy, top_z, half_x, half_y, yaw)``; camera paths use them as things to look at.
    """

    room_lo: torch.Tensor
    room_hi: torch.Tensor
    room_material: torch.Tensor
    prims: tuple[Prims, Prims, Prims]
    materials: torch.Tensor
    light_pos: torch.Tensor
    light_rgb: torch.Tensor
    ambient: torch.Tensor
    seed: int = 0
    surfaces: list = field(default_factory=list)

    @property
    def size(self) -> tuple[float, float, float]:
        d = (self.room_hi - self.room_lo).tolist()
        return (d[0], d[1], d[2])

    @property
    def num_primitives(self) -> int:
        return sum(len(p) for p in self.prims)

    def object_distance(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance (R,) of world points (R, 3) to the nearest object (not the room's walls)."""
        points = points.to(torch.float32)
        d = torch.full((points.shape[0],), float("inf"))
        for kind, pr in enumerate(self.prims):
            if len(pr):
                d = torch.minimum(d, SDF_FUNCS[kind](points[:, None, :], pr.params()).amin(dim=-1))
        return d

    def room_distance(self, points: torch.Tensor) -> torch.Tensor:
        """Distance (R,) of points (R, 3) to the nearest wall, floor or ceiling (negative outside)."""
        return sdf_room(points.to(torch.float32), self.room_lo, self.room_hi)

    def free_distance(self, points: torch.Tensor) -> torch.Tensor:
        """Distance (R,) to the nearest surface of any kind (negative inside an object or outside)."""
        return torch.minimum(self.object_distance(points), self.room_distance(points))


# ------------------------------------------------------------------------------------------- palettes
def _hsv(h: float, s: float, v: float) -> tuple[float, float, float]:
    return colorsys.hsv_to_rgb(h % 1.0, min(max(s, 0.0), 1.0), min(max(v, 0.0), 1.0))


def _jitter(rng: np.random.Generator, col, amount: float = 0.08):
    return tuple(float(np.clip(c * (1.0 + rng.uniform(-amount, amount)), 0.0, 1.0)) for c in col)


def _wood_colours(rng: np.random.Generator):
    """Light (oak, pine), mid (teak, cherry) or dark (walnut, wenge) wood: early/late wood colours."""
    tone = rng.choice(["light", "mid", "dark", "grey"], p=[0.35, 0.3, 0.25, 0.1])
    h = rng.uniform(0.05, 0.11)
    s = {"light": 0.35, "mid": 0.55, "dark": 0.6, "grey": 0.12}[tone] + rng.uniform(-0.08, 0.08)
    v = {"light": 0.78, "mid": 0.55, "dark": 0.3, "grey": 0.6}[tone] + rng.uniform(-0.08, 0.08)
    return _hsv(h, s, v), _hsv(h - 0.01, s + 0.1, v * rng.uniform(0.55, 0.75))


def _wall_paint(rng: np.random.Generator):
    if rng.random() < 0.8:  # off-white / beige / light grey, as most real rooms
        return _hsv(rng.uniform(0.05, 0.6), rng.uniform(0.0, 0.12), rng.uniform(0.7, 0.95))
    return _hsv(rng.random(), rng.uniform(0.1, 0.3), rng.uniform(0.6, 0.9))


def _vivid(rng: np.random.Generator):
    return _hsv(rng.random(), rng.uniform(0.4, 0.9), rng.uniform(0.35, 0.95))


def _muted(rng: np.random.Generator):
    return _hsv(rng.random(), rng.uniform(0.05, 0.45), rng.uniform(0.2, 0.85))


def _neutral(rng: np.random.Generator):
    v = rng.choice([rng.uniform(0.05, 0.2), rng.uniform(0.35, 0.6), rng.uniform(0.75, 0.95)])
    return _hsv(rng.random(), rng.uniform(0.0, 0.08), v)


def _rot2(yaw: float, x: float, y: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return c * x - s * y, s * x + c * y


def _aabb_of_footprint(cx, cy, hx, hy, yaw):
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    ex, ey = c * hx + s * hy, s * hx + c * hy
    return cx - ex, cy - ey, cx + ex, cy + ey


# --------------------------------------------------------------------------------------------- builder
class _Builder:
    """Accumulates primitives, materials and footprints while a scene is drawn."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5C3E]))
        self.seed = seed
        self.materials: list[np.ndarray] = []
        self.parts: list[list] = [[], [], []]  # per kind: rows (cx, cy, cz, hx, hy, hz, yaw, mat)
        self.footprints: list[tuple[float, float, float, float]] = []
        self.surfaces: list[tuple] = []  # (cx, cy, top_z, hx, hy, yaw) where clutter may stand
        self.W = self.D = self.H = 0.0

    # -- materials
    def mat(self, kind: int, col_a, col_b=(0.0, 0.0, 0.0), scale=1.0, p1=0.0, p2=0.0, emissive=0.0,
            col_c=(0.0, 0.0, 0.0), amp=0.1) -> int:
        salt = int(self.rng.integers(0, 100000))
        self.materials.append(tx.material(kind, col_a, col_b, scale, p1, p2, salt, emissive, col_c, amp))
        return len(self.materials) - 1

    def wood_mat(self, axis_y: bool = False) -> int:
        a, b = _wood_colours(self.rng)
        return self.mat(tx.WOOD, a, b, scale=self.rng.uniform(15, 40), p2=float(axis_y), amp=0.25)

    def paint_mat(self, col=None, amp=0.08) -> int:
        col = _muted(self.rng) if col is None else col
        return self.mat(tx.PAINT, col, _jitter(self.rng, col, 0.2), scale=self.rng.uniform(2, 8),
                        p1=self.rng.uniform(0, 0.5), amp=amp)

    def surface_mat(self) -> int:
        """A furniture surface: wood, laminate/paint, stone or fabric."""
        r = self.rng.random()
        if r < 0.5:
            return self.wood_mat(axis_y=False)
        if r < 0.75:
            return self.paint_mat(_neutral(self.rng) if self.rng.random() < 0.6 else _muted(self.rng))
        if r < 0.88:
            a = _neutral(self.rng)
            return self.mat(tx.MARBLE, a, _jitter(self.rng, _neutral(self.rng), 0.1),
                            scale=self.rng.uniform(2, 6))
        return self.mat(tx.PANELS, *_wood_colours(self.rng), scale=self.rng.uniform(2, 4), p1=0.006)

    def fabric_mat(self) -> int:
        a = _vivid(self.rng) if self.rng.random() < 0.5 else _muted(self.rng)
        return self.mat(tx.FABRIC, a, _muted(self.rng), scale=self.rng.uniform(80, 160),
                        p1=float(self.rng.random() < 0.3))

    # -- primitives
    def add(self, kind: int, center, half, yaw: float, mat: int) -> None:
        self.parts[kind].append([*map(float, center), *map(float, half), float(yaw), mat])

    def add_part(self, base, yaw: float, kind: int, local_center, half, mat: int, part_yaw: float = 0.0):
        """Add a primitive given in the object frame (base (x, y, z), rotated by yaw)."""
        dx, dy = _rot2(yaw, local_center[0], local_center[1])
        self.add(kind, (base[0] + dx, base[1] + dy, base[2] + local_center[2]), half, yaw + part_yaw, mat)

    # -- placement
    def free(self, cx, cy, hx, hy, yaw, margin=0.05) -> bool:
        x0, y0, x1, y1 = _aabb_of_footprint(cx, cy, hx, hy, yaw)
        if x0 < 0.02 or y0 < 0.02 or x1 > self.W - 0.02 or y1 > self.D - 0.02:
            return False
        for a0, b0, a1, b1 in self.footprints:
            if x0 < a1 + margin and a0 < x1 + margin and y0 < b1 + margin and b0 < y1 + margin:
                return False
        return True

    def claim(self, cx, cy, hx, hy, yaw) -> None:
        self.footprints.append(_aabb_of_footprint(cx, cy, hx, hy, yaw))

    def wall_spot(self, width: float, depth: float, tries: int = 30):
        """A free spot against a random wall for an object of width x depth: (cx, cy, yaw) or None."""
        for _ in range(tries):
            wall = int(self.rng.integers(0, 4))
            length = self.W if wall < 2 else self.D
            if width > length - 0.1:
                continue
            s = self.rng.uniform(width / 2 + 0.03, length - width / 2 - 0.03)
            gap = 0.02
            if wall == 0:
                cx, cy, yaw = s, depth / 2 + gap, 0.0
            elif wall == 1:
                cx, cy, yaw = s, self.D - depth / 2 - gap, math.pi
            elif wall == 2:
                cx, cy, yaw = depth / 2 + gap, s, -math.pi / 2
            else:
                cx, cy, yaw = self.W - depth / 2 - gap, s, math.pi / 2
            if self.free(cx, cy, width / 2, depth / 2, yaw):
                return cx, cy, yaw
        return None

    def floor_spot(self, hx: float, hy: float, tries: int = 30, margin: float = 0.4):
        if 2 * hx >= self.W or 2 * hy >= self.D:  # wider than the room (a corridor)
            return None
        for _ in range(tries):
            yaw = float(self.rng.uniform(-math.pi, math.pi)) if self.rng.random() < 0.5 else \
                float(self.rng.integers(0, 4)) * math.pi / 2
            cx = self.rng.uniform(hx, self.W - hx)
            cy = self.rng.uniform(hy, self.D - hy)
            if self.free(cx, cy, hx, hy, yaw, margin=margin):
                return cx, cy, yaw
        return None


# ---------------------------------------------------------------------------------------------- objects
def _legs(b: _Builder, base, yaw, hx, hy, height, mat, inset=0.05):
    r = b.rng.uniform(0.018, 0.035)
    round_legs = b.rng.random() < 0.5
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = (sx * (hx - inset), sy * (hy - inset), height / 2)
            if round_legs:
                b.add_part(base, yaw, CYLINDER, c, (r, r, height / 2), mat)
            else:
                b.add_part(base, yaw, BOX, c, (r, r, height / 2), mat)


def _table(b: _Builder, against_wall: bool) -> bool:
    w, d = b.rng.uniform(0.8, 1.8), b.rng.uniform(0.55, 1.0)
    h = b.rng.uniform(0.68, 0.78)
    spot = b.wall_spot(w, d) if against_wall else b.floor_spot(w / 2, d / 2)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, d / 2, yaw)
    top = b.surface_mat()
    t = b.rng.uniform(0.025, 0.05)
    base = (cx, cy, 0.0)
    b.add_part(base, yaw, BOX, (0, 0, h - t / 2), (w / 2, d / 2, t / 2), top)
    leg_mat = top if b.rng.random() < 0.5 else b.paint_mat(_neutral(b.rng))
    _legs(b, base, yaw, w / 2, d / 2, h - t, leg_mat)
    if b.rng.random() < 0.5:  # apron under the top
        ah = 0.06
        b.add_part(base, yaw, BOX, (0, d / 2 - 0.06, h - t - ah / 2), (w / 2 - 0.06, 0.01, ah / 2), leg_mat)
    b.surfaces.append((cx, cy, h, w / 2 - 0.04, d / 2 - 0.04, yaw))
    if not against_wall:  # chairs around
        for side in (-1, 1):
            if b.rng.random() < 0.6:
                _chair_at(b, base, yaw, (b.rng.uniform(-w / 4, w / 4), side * (d / 2 + 0.25)),
                          math.pi if side > 0 else 0.0)
    return True


def _chair_at(b: _Builder, table_base, table_yaw, local_xy, face_yaw):
    """A chair whose seat centre is at local_xy of a table and which faces the table."""
    dx, dy = _rot2(table_yaw, *local_xy)
    cx, cy = table_base[0] + dx, table_base[1] + dy
    yaw = table_yaw + face_yaw + b.rng.uniform(-0.3, 0.3)
    s = b.rng.uniform(0.2, 0.24)
    if not b.free(cx, cy, s, s, yaw, margin=0.02):
        return
    b.claim(cx, cy, s, s, yaw)
    seat_h = b.rng.uniform(0.42, 0.48)
    mat = b.surface_mat() if b.rng.random() < 0.6 else b.fabric_mat()
    base = (cx, cy, 0.0)
    b.add_part(base, yaw, BOX, (0, 0, seat_h - 0.02), (s, s, 0.02), mat)
    _legs(b, base, yaw, s, s, seat_h - 0.04, mat, inset=0.03)
    back_h = b.rng.uniform(0.35, 0.5)
    b.add_part(base, yaw, BOX, (0, -s + 0.015, seat_h + back_h / 2), (s, 0.015, back_h / 2), mat)


def _desk(b: _Builder) -> bool:
    w, d, h = b.rng.uniform(1.0, 1.8), b.rng.uniform(0.55, 0.8), b.rng.uniform(0.7, 0.76)
    spot = b.wall_spot(w, d)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, d / 2, yaw)
    base = (cx, cy, 0.0)
    top = b.surface_mat()
    b.add_part(base, yaw, BOX, (0, 0, h - 0.015), (w / 2, d / 2, 0.015), top)
    side = b.paint_mat(_neutral(b.rng)) if b.rng.random() < 0.5 else top
    b.add_part(base, yaw, BOX, (-w / 2 + 0.02, 0, (h - 0.03) / 2), (0.02, d / 2 - 0.02, (h - 0.03) / 2), side)
    if b.rng.random() < 0.6:  # drawer pedestal
        pw = 0.2
        drawers = b.mat(tx.PANELS, *_wood_colours(b.rng), scale=1 / (2 * pw), p1=0.004, p2=1.0)
        b.add_part(base, yaw, BOX, (w / 2 - pw - 0.02, 0, (h - 0.03) / 2), (pw, d / 2 - 0.03, (h - 0.03) / 2),
                   drawers)
    else:
        b.add_part(base, yaw, BOX, (w / 2 - 0.02, 0, (h - 0.03) / 2), (0.02, d / 2 - 0.02, (h - 0.03) / 2), side)
    # monitor and keyboard
    if b.rng.random() < 0.7:
        mw = b.rng.uniform(0.22, 0.35)
        dark = b.paint_mat(_hsv(0.6, 0.1, b.rng.uniform(0.04, 0.12)), amp=0.05)
        my = -d / 2 + 0.15
        b.add_part(base, yaw, BOX, (0, my, h + 0.12 + mw * 0.6), (mw, 0.015, mw * 0.6), dark)
        b.add_part(base, yaw, BOX, (0, my - 0.03, h + 0.07), (0.03, 0.02, 0.07), dark)
        b.add_part(base, yaw, BOX, (0, my - 0.03, h + 0.005), (0.1, 0.07, 0.005), dark)
        keys = b.mat(tx.TILES, _neutral(b.rng), _hsv(0, 0, 0.1), scale=55.0, p1=0.003)
        b.add_part(base, yaw, BOX, (b.rng.uniform(-0.1, 0.1), my + 0.3, h + 0.012), (0.22, 0.07, 0.012), keys)
    b.surfaces.append((cx, cy, h, w / 2 - 0.04, d / 2 - 0.04, yaw))
    if b.rng.random() < 0.6:
        _chair_at(b, base, yaw, (b.rng.uniform(-0.2, 0.2), d / 2 + 0.3), math.pi)
    return True


def _shelf(b: _Builder) -> bool:
    w, d, h = b.rng.uniform(0.6, 1.6), b.rng.uniform(0.28, 0.4), b.rng.uniform(1.0, min(2.2, b.H - 0.3))
    spot = b.wall_spot(w, d)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, d / 2, yaw)
    base = (cx, cy, 0.0)
    mat = b.surface_mat()
    back = b.paint_mat(_neutral(b.rng)) if b.rng.random() < 0.5 else mat
    t = 0.018
    b.add_part(base, yaw, BOX, (-w / 2 + t, 0, h / 2), (t, d / 2, h / 2), mat)
    b.add_part(base, yaw, BOX, (w / 2 - t, 0, h / 2), (t, d / 2, h / 2), mat)
    b.add_part(base, yaw, BOX, (0, -d / 2 + 0.005, h / 2), (w / 2 - 2 * t, 0.005, h / 2), back)
    n = max(2, int(h / b.rng.uniform(0.3, 0.42)))
    pitch = h / n
    for i in range(n + 1):
        z = min(max(i * pitch, t), h - t)
        b.add_part(base, yaw, BOX, (0, 0, z), (w / 2 - 2 * t, d / 2, t), mat)
        if i == n:
            b.surfaces.append((cx, cy, h, w / 2 - 0.05, d / 2 - 0.05, yaw))
            break
        # books filling parts of the shelf
        x = -w / 2 + 2 * t + b.rng.uniform(0.0, 0.1)
        while x < w / 2 - 2 * t - 0.08:
            if b.rng.random() < 0.75:
                bw = min(b.rng.uniform(0.1, 0.5), w / 2 - 2 * t - x)
                bh = min(pitch - 2 * t - 0.02, b.rng.uniform(0.17, 0.3)) / 2
                bd = b.rng.uniform(0.13, d / 2 - 0.005)
                books = b.mat(tx.BOOKS, (0, 0, 0), _hsv(0, 0, 0.06), scale=b.rng.uniform(25, 55), p1=bh)
                b.add_part(base, yaw, BOX, (x + bw / 2, d / 2 - bd - 0.01, z + t + bh), (bw / 2, bd, bh), books)
                x += bw + b.rng.uniform(0.0, 0.08)
            else:
                _ornament(b, base, yaw, x + 0.05, d / 2 - 0.12, z + t, min(pitch - 2 * t - 0.03, 0.25))
                x += 0.12 + b.rng.uniform(0.0, 0.1)
    return True


def _ornament(b: _Builder, base, yaw, x, y, z, max_h):
    r = b.rng.random()
    mat = b.paint_mat(_vivid(b.rng)) if b.rng.random() < 0.6 else b.mat(
        tx.MARBLE, _neutral(b.rng), _vivid(b.rng), scale=b.rng.uniform(4, 10))
    if r < 0.4:
        rad = b.rng.uniform(0.03, 0.05)
        hh = b.rng.uniform(0.05, max_h / 2)
        b.add_part(base, yaw, CYLINDER, (x, y, z + hh), (rad, rad, hh), mat)
    elif r < 0.7:
        rad = min(b.rng.uniform(0.04, 0.07), max_h / 2)
        b.add_part(base, yaw, ELLIPSOID, (x, y, z + rad), (rad, rad, rad), mat)
    else:
        hx, hh = b.rng.uniform(0.03, 0.06), b.rng.uniform(0.03, max_h / 2)
        b.add_part(base, yaw, BOX, (x, y, z + hh), (hx, hx, hh), mat)


def _cabinet(b: _Builder) -> bool:
    w, d = b.rng.uniform(0.5, 1.8), b.rng.uniform(0.35, 0.65)
    h = b.rng.choice([b.rng.uniform(0.45, 0.95), b.rng.uniform(1.6, min(2.2, b.H - 0.2))])
    spot = b.wall_spot(w, d)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, d / 2, yaw)
    base = (cx, cy, 0.0)
    n_doors = max(1, round(w / b.rng.uniform(0.35, 0.6)))
    if b.rng.random() < 0.6:
        a, c = _wood_colours(b.rng)
    else:
        a = _neutral(b.rng) if b.rng.random() < 0.6 else _muted(b.rng)
        c = _jitter(b.rng, a, 0.1)
    front = b.mat(tx.PANELS, a, c, scale=n_doors / w, p1=0.004, p2=float(h < 1.0 and b.rng.random() < 0.5))
    b.add_part(base, yaw, BOX, (0, 0, 0.05 + (h - 0.05) / 2), (w / 2, d / 2, (h - 0.05) / 2), front)
    plinth = b.paint_mat(_hsv(0, 0, 0.12))
    b.add_part(base, yaw, BOX, (0, 0.02, 0.025), (w / 2 - 0.02, d / 2 - 0.03, 0.025), plinth)
    handle = b.paint_mat(_neutral(b.rng))
    for i in range(n_doors):
        x = -w / 2 + (i + 0.5) * w / n_doors + (0.35 * w / n_doors) * (1 if i % 2 == 0 else -1)
        b.add_part(base, yaw, BOX, (x, d / 2 + 0.012, 0.05 + (h - 0.05) * 0.6), (0.01, 0.012, 0.06), handle)
    if h < 1.2:
        b.surfaces.append((cx, cy, h, w / 2 - 0.05, d / 2 - 0.05, yaw))
    return True


def _bed(b: _Builder) -> bool:
    w, l_ = b.rng.uniform(0.9, 1.8), b.rng.uniform(1.9, 2.1)
    spot = b.wall_spot(w, l_)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, l_ / 2, yaw)
    base = (cx, cy, 0.0)
    frame = b.surface_mat()
    b.add_part(base, yaw, BOX, (0, 0, 0.15), (w / 2, l_ / 2, 0.15), frame)
    sheet = b.fabric_mat()
    b.add_part(base, yaw, BOX, (0, 0.02, 0.38), (w / 2 - 0.03, l_ / 2 - 0.05, 0.08), sheet)
    duvet = b.fabric_mat()
    b.add_part(base, yaw, BOX, (0, 0.25, 0.47), (w / 2 - 0.01, l_ / 2 - 0.28, 0.03), duvet)
    head = b.surface_mat() if b.rng.random() < 0.6 else b.fabric_mat()
    b.add_part(base, yaw, BOX, (0, -l_ / 2 + 0.04, 0.55), (w / 2, 0.04, 0.55), head)
    pil = b.fabric_mat()
    n = 1 if w < 1.2 else 2
    for i in range(n):
        x = (i + 0.5) * w / n - w / 2
        b.add_part(base, yaw, ELLIPSOID, (x, -l_ / 2 + 0.3, 0.52), (min(0.3, w / (2 * n) - 0.05), 0.16, 0.07), pil)
    return True


def _sofa(b: _Builder) -> bool:
    w, d = b.rng.uniform(1.4, 2.4), b.rng.uniform(0.8, 1.0)
    spot = b.wall_spot(w, d) if b.rng.random() < 0.7 else b.floor_spot(w / 2, d / 2)
    if spot is None:
        return False
    cx, cy, yaw = spot
    b.claim(cx, cy, w / 2, d / 2, yaw)
    base = (cx, cy, 0.0)
    fab = b.fabric_mat()
    arm = 0.12
    b.add_part(base, yaw, BOX, (0, 0, 0.2), (w / 2, d / 2, 0.16), fab)
    b.add_part(base, yaw, BOX, (0, -d / 2 + 0.1, 0.6), (w / 2, 0.1, 0.25), fab)
    for sx in (-1, 1):
        b.add_part(base, yaw, BOX, (sx * (w / 2 - arm / 2), 0, 0.5), (arm / 2, d / 2, 0.15), fab)
    cush = fab if b.rng.random() < 0.5 else b.fabric_mat()
    n = max(2, round((w - 2 * arm) / 0.6))
    cw = (w - 2 * arm) / n
    for i in range(n):
        x = -w / 2 + arm + (i + 0.5) * cw
        b.add_part(base, yaw, BOX, (x, 0.08, 0.42), (cw / 2 - 0.01, d / 2 - 0.12, 0.06), cush)
    for _ in range(int(b.rng.integers(0, 3))):
        b.add_part(base, yaw, ELLIPSOID, (b.rng.uniform(-w / 3, w / 3), -d / 2 + 0.3, 0.6), (0.2, 0.08, 0.18),
                   b.fabric_mat())
    for leg_x in (-1, 1):
        for leg_y in (-1, 1):
            b.add_part(base, yaw, BOX, (leg_x * (w / 2 - 0.05), leg_y * (d / 2 - 0.05), 0.02), (0.025, 0.025, 0.02),
                       b.paint_mat(_hsv(0, 0, 0.1)))
    return True


def _floor_lamp(b: _Builder) -> bool:
    spot = b.floor_spot(0.2, 0.2, margin=0.15)
    if spot is None:
        return False
    cx, cy, _ = spot
    b.claim(cx, cy, 0.2, 0.2, 0.0)
    metal = b.paint_mat(_neutral(b.rng))
    h = b.rng.uniform(1.3, 1.75)
    b.add(CYLINDER, (cx, cy, 0.015), (0.15, 0.15, 0.015), 0.0, metal)
    b.add(CYLINDER, (cx, cy, h / 2), (0.012, 0.012, h / 2), 0.0, metal)
    shade_col = _hsv(b.rng.uniform(0.07, 0.14), b.rng.uniform(0.1, 0.45), b.rng.uniform(0.75, 0.95))
    shade = b.mat(tx.FABRIC, shade_col, shade_col, scale=120.0, emissive=b.rng.uniform(0.4, 0.9))
    r = b.rng.uniform(0.14, 0.22)
    b.add(CYLINDER, (cx, cy, h + 0.1), (r, r, 0.12), 0.0, shade)
    return True


def _plant(b: _Builder, base=None, scale: float = 1.0) -> bool:
    if base is None:
        spot = b.floor_spot(0.25, 0.25, margin=0.1)
        if spot is None:
            return False
        b.claim(spot[0], spot[1], 0.25, 0.25, 0.0)
        base = (spot[0], spot[1], 0.0)
    pot_r = b.rng.uniform(0.1, 0.18) * scale
    pot_h = b.rng.uniform(0.15, 0.35) * scale
    pot = b.paint_mat(_vivid(b.rng) if b.rng.random() < 0.5 else _neutral(b.rng))
    b.add(CYLINDER, (base[0], base[1], base[2] + pot_h / 2), (pot_r, pot_r, pot_h / 2), 0.0, pot)
    leaf_col = _hsv(b.rng.uniform(0.22, 0.38), b.rng.uniform(0.45, 0.8), b.rng.uniform(0.25, 0.55))
    leaf = b.mat(tx.CARPET, leaf_col, _jitter(b.rng, leaf_col, 0.4), scale=b.rng.uniform(25, 50))
    for _ in range(int(b.rng.integers(2, 5))):
        rr = b.rng.uniform(0.12, 0.25) * scale
        off = b.rng.uniform(-0.08, 0.08, size=2) * scale
        zc = base[2] + pot_h + rr * b.rng.uniform(0.6, 1.8)
        b.add(ELLIPSOID, (base[0] + off[0], base[1] + off[1], zc), (rr, rr * b.rng.uniform(0.7, 1.0), rr * 1.2),
              float(b.rng.uniform(0, math.pi)), leaf)
    return True


def _floor_clutter(b: _Builder) -> bool:
    r = b.rng.random()
    if r < 0.45:  # cardboard boxes / storage boxes, maybe stacked
        hx, hy = b.rng.uniform(0.15, 0.35), b.rng.uniform(0.15, 0.3)
        spot = b.floor_spot(hx, hy, margin=0.1)
        if spot is None:
            return False
        cx, cy, yaw = spot
        b.claim(cx, cy, hx, hy, yaw)
        z = 0.0
        for _ in range(int(b.rng.integers(1, 4))):
            hz = b.rng.uniform(0.1, 0.25)
            col = _hsv(b.rng.uniform(0.07, 0.1), b.rng.uniform(0.35, 0.55), b.rng.uniform(0.45, 0.7)) \
                if b.rng.random() < 0.6 else _vivid(b.rng)
            mat = b.mat(tx.STRIPES, col, _jitter(b.rng, col, 0.15), scale=b.rng.uniform(1, 4), p1=0.15,
                        col_c=_jitter(b.rng, col, 0.3))
            b.add(BOX, (cx, cy, z + hz), (hx, hy, hz), yaw + b.rng.uniform(-0.2, 0.2), mat)
            z += 2 * hz
            hx, hy = hx * b.rng.uniform(0.7, 1.0), hy * b.rng.uniform(0.7, 1.0)
        return True
    if r < 0.65:  # bin / basket
        rad = b.rng.uniform(0.12, 0.22)
        spot = b.floor_spot(rad, rad, margin=0.1)
        if spot is None:
            return False
        b.claim(spot[0], spot[1], rad, rad, 0.0)
        hh = b.rng.uniform(0.15, 0.3)
        mat = b.mat(tx.STRIPES, _vivid(b.rng), _muted(b.rng), scale=b.rng.uniform(20, 60), p1=0.5,
                    col_c=_neutral(b.rng)) if b.rng.random() < 0.5 else b.paint_mat(_vivid(b.rng))
        b.add(CYLINDER, (spot[0], spot[1], hh), (rad, rad, hh), 0.0, mat)
        return True
    if r < 0.8:  # ball
        rad = b.rng.uniform(0.08, 0.25)
        spot = b.floor_spot(rad, rad, margin=0.1)
        if spot is None:
            return False
        b.claim(spot[0], spot[1], rad, rad, 0.0)
        mat = b.mat(tx.CHECKER, _vivid(b.rng), _vivid(b.rng), scale=b.rng.uniform(4, 12))
        b.add(ELLIPSOID, (spot[0], spot[1], rad), (rad, rad, rad), 0.0, mat)
        return True
    return _plant(b)


def _rug(b: _Builder) -> None:
    hx, hy = b.rng.uniform(0.6, min(1.6, b.W / 2 - 0.4)), b.rng.uniform(0.5, min(1.2, b.D / 2 - 0.4))
    yaw = b.rng.uniform(-0.15, 0.15)  # roughly aligned with the room
    x0, y0, x1, y1 = _aabb_of_footprint(0.0, 0.0, hx, hy, yaw)
    cx, cy = b.rng.uniform(0.2 - x0, b.W - 0.2 - x1), b.rng.uniform(0.2 - y0, b.D - 0.2 - y1)
    if b.rng.random() < 0.5:
        mat = b.mat(tx.CARPET, _vivid(b.rng), _muted(b.rng), scale=b.rng.uniform(60, 120))
    else:
        mat = b.mat(tx.PAINTING, _muted(b.rng), _vivid(b.rng), scale=b.rng.uniform(1.0, 3.0), col_c=_vivid(b.rng))
    b.add(BOX, (cx, cy, 0.006), (hx, hy, 0.006), yaw, mat)


# -------------------------------------------------------------------------------------- wall fixtures
def _wall_point(b: _Builder, wall: int, s: float, depth: float):
    """Centre (x, y) and yaw of a thin object of half-depth ``depth`` hanging on ``wall`` at position s."""
    if wall == 0:
        return (s, depth), 0.0
    if wall == 1:
        return (s, b.D - depth), math.pi
    if wall == 2:
        return (depth, s), -math.pi / 2
    return (b.W - depth, s), math.pi / 2


def _wall_span_free(b: _Builder, wall: int, s: float, half_w: float, z0: float, z1: float) -> bool:
    """Whether a wall rectangle is clear of furniture standing against that wall (by footprints)."""
    (x, y), yaw = _wall_point(b, wall, s, 0.05)
    x0, y0, x1, y1 = _aabb_of_footprint(x, y, half_w, 0.05, yaw)
    for a0, b0, a1, b1 in b.footprints:
        if x0 < a1 and a0 < x1 and y0 < b1 and b0 < y1 and z0 < 2.3:
            return False
    return True


def _wall_items(b: _Builder, n: int) -> None:
    for _ in range(n):
        wall = int(b.rng.integers(0, 4))
        length = b.W if wall < 2 else b.D
        kind = b.rng.choice(["picture", "window", "door", "poster", "shelf", "board", "clock"],
                            p=[0.3, 0.15, 0.12, 0.13, 0.12, 0.1, 0.08])
        if kind == "door":
            hw, hh = b.rng.uniform(0.4, 0.48), b.rng.uniform(0.98, 1.05)
            z = hh
        elif kind == "window":
            hw, hh = b.rng.uniform(0.4, 0.9), b.rng.uniform(0.4, 0.7)
            z = b.rng.uniform(0.9 + hh, max(0.95 + hh, b.H - 0.2 - hh))
        elif kind == "shelf":
            hw, hh = b.rng.uniform(0.3, 0.6), 0.015
            z = b.rng.uniform(1.2, 1.8)
        elif kind == "clock":
            hw = hh = b.rng.uniform(0.12, 0.2)
            z = b.rng.uniform(1.7, b.H - 0.3)
        else:
            hw, hh = b.rng.uniform(0.15, 0.6), b.rng.uniform(0.15, 0.5)
            z = b.rng.uniform(1.1 + hh, max(1.2 + hh, b.H - 0.25 - hh))
        if 2 * hw > length - 0.3:
            continue
        s = b.rng.uniform(hw + 0.1, length - hw - 0.1)
        if kind == "door":
            (x, y), yaw = _wall_point(b, wall, s, 0.2)
            if not b.free(x, y, hw, 0.2, yaw, margin=0.1):
                continue
            b.claim(x, y, hw, 0.6, yaw)  # keep the door's swing area free
            frame = b.paint_mat(_neutral(b.rng))
            door = b.mat(tx.PANELS, *_wood_colours(b.rng), scale=1 / (2 * hw), p1=0.005, p2=1.0) \
                if b.rng.random() < 0.5 else b.paint_mat(_neutral(b.rng))
            (x, y), yaw = _wall_point(b, wall, s, 0.015)
            b.add(BOX, (x, y, hh), (hw + 0.05, 0.015, hh), yaw, frame)
            (x, y), yaw = _wall_point(b, wall, s, 0.03)
            b.add(BOX, (x, y, hh - 0.02), (hw - 0.02, 0.02, hh - 0.02), yaw, door)
            (x, y), _ = _wall_point(b, wall, s + 0.7 * hw * (1 if b.rng.random() < 0.5 else -1), 0.07)
            b.add(CYLINDER, (x, y, 1.0), (0.02, 0.02, 0.03), 0.0, b.paint_mat(_neutral(b.rng)))
            continue
        if not _wall_span_free(b, wall, s, hw, z - hh, z + hh):
            continue
        if kind == "window":
            sky = _hsv(b.rng.uniform(0.5, 0.62), b.rng.uniform(0.05, 0.35), 0.95)
            pane = b.mat(tx.PAINTING, sky, _hsv(b.rng.uniform(0.2, 0.35), 0.4, 0.6), scale=b.rng.uniform(1, 3),
                         emissive=b.rng.uniform(1.2, 2.5), col_c=_hsv(0.1, 0.1, 0.9))
            frame = b.paint_mat(_neutral(b.rng) if b.rng.random() < 0.7 else _wood_colours(b.rng)[0])
            (x, y), yaw = _wall_point(b, wall, s, 0.004)
            b.add(BOX, (x, y, z), (hw, 0.004, hh), yaw, pane)
            (x, y), yaw = _wall_point(b, wall, s, 0.03)
            for dz in (-hh, hh):
                b.add(BOX, (x, y, z + dz), (hw + 0.04, 0.03, 0.04), yaw, frame)
            for ds in (-hw, 0.0, hw):
                (x, y), yaw = _wall_point(b, wall, s + ds, 0.03)
                b.add(BOX, (x, y, z), (0.03, 0.03, hh), yaw, frame)
            (x, y), yaw = _wall_point(b, wall, s, 0.08)
            b.add(BOX, (x, y, z - hh - 0.05), (hw + 0.08, 0.08, 0.015), yaw, frame)  # sill
        elif kind == "picture":
            frame = b.wood_mat() if b.rng.random() < 0.5 else b.paint_mat(_neutral(b.rng))
            art = b.mat(tx.PAINTING, _vivid(b.rng), _muted(b.rng), scale=b.rng.uniform(2, 8), col_c=_vivid(b.rng))
            (x, y), yaw = _wall_point(b, wall, s, 0.015)
            b.add(BOX, (x, y, z), (hw, 0.015, hh), yaw, frame)
            (x, y), yaw = _wall_point(b, wall, s, 0.02)
            b.add(BOX, (x, y, z), (hw - 0.04, 0.02, hh - 0.04), yaw, art)
        elif kind == "poster":
            if b.rng.random() < 0.5:
                art = b.mat(tx.TEXT, _neutral(b.rng), _vivid(b.rng), scale=b.rng.uniform(15, 40), p1=0.8 * hw)
            else:
                art = b.mat(tx.PAINTING, _vivid(b.rng), _vivid(b.rng), scale=b.rng.uniform(3, 10),
                            col_c=_neutral(b.rng))
            (x, y), yaw = _wall_point(b, wall, s, 0.003)
            b.add(BOX, (x, y, z), (hw, 0.003, hh), yaw, art)
        elif kind == "board":
            (x, y), yaw = _wall_point(b, wall, s, 0.012)
            b.add(BOX, (x, y, z), (hw + 0.02, 0.012, hh + 0.02), yaw, b.paint_mat(_neutral(b.rng)))
            (x, y), yaw = _wall_point(b, wall, s, 0.015)
            if b.rng.random() < 0.5:
                face = b.mat(tx.TEXT, _hsv(0, 0, 0.93), _vivid(b.rng), scale=b.rng.uniform(8, 20), p1=0.8 * hw)
            else:
                face = b.paint_mat(_hsv(0.6, 0.1, 0.06), amp=0.05)  # a screen
            b.add(BOX, (x, y, z), (hw, 0.015, hh), yaw, face)
        elif kind == "clock":
            (x, y), yaw = _wall_point(b, wall, s, 0.02)
            face = b.mat(tx.TILES, _hsv(0, 0, 0.92), _hsv(0, 0, 0.1), scale=b.rng.uniform(8, 14), p1=0.005)
            b.add(ELLIPSOID, (x, y, z), (hw, 0.02, hw), yaw, face)
        else:  # wall shelf with items
            mat = b.surface_mat()
            d = b.rng.uniform(0.18, 0.25)
            (x, y), yaw = _wall_point(b, wall, s, d / 2)
            b.add(BOX, (x, y, z), (hw, d / 2, 0.015), yaw, mat)
            b.surfaces.append((x, y, z + 0.015, hw - 0.03, d / 2 - 0.03, yaw))


# Half footprints (metres) of clutter items of a fixed size: an A4 sheet, a laptop with its lid.
_FIXED_CLUTTER = {"paper": (0.105, 0.148), "laptop": (0.16, 0.125)}


def _clutter_on_surfaces(b: _Builder, density: float) -> None:
    for cx, cy, top, hx, hy, yaw in list(b.surfaces):
        n = int(b.rng.poisson(density * max(hx * hy * 4.0, 0.1) * 6.0))
        taken: list[tuple[float, float, float]] = []
        for _ in range(min(n, 10)):
            kind = b.rng.choice(["book", "mug", "bottle", "paper", "bowl", "box", "plant", "laptop"],
                                p=[0.2, 0.15, 0.12, 0.17, 0.1, 0.12, 0.06, 0.08])
            rx, ry = b.rng.uniform(0.05, 0.2), b.rng.uniform(0.05, 0.15)
            if kind in _FIXED_CLUTTER:
                rx, ry = _FIXED_CLUTTER[kind]
            r_ = math.hypot(rx, ry)  # the item is turned on the surface: keep its circumscribed circle on it
            if hx < r_ + 0.01 or hy < r_ + 0.01:
                continue
            lx, ly = b.rng.uniform(-hx + r_, hx - r_), b.rng.uniform(-hy + r_, hy - r_)
            if any((lx - a) ** 2 + (ly - c) ** 2 < (r_ + rr) ** 2 for a, c, rr in taken):
                continue
            taken.append((lx, ly, r_))
            dx, dy = _rot2(yaw, lx, ly)
            x, y = cx + dx, cy + dy
            iyaw = yaw + b.rng.uniform(-0.6, 0.6)
            if kind == "book":
                z = top
                for _ in range(int(b.rng.integers(1, 4))):
                    hz = b.rng.uniform(0.01, 0.03)
                    cover = b.mat(tx.PAINT, _vivid(b.rng), _muted(b.rng), scale=20.0, p1=0.3, amp=0.1) \
                        if b.rng.random() < 0.6 else b.mat(tx.TEXT, _neutral(b.rng), _vivid(b.rng), scale=30.0,
                                                           p1=0.08)
                    b.add(BOX, (x, y, z + hz), (min(rx, 0.12), min(ry, 0.09), hz), iyaw + b.rng.uniform(-0.2, 0.2),
                          cover)
                    z += 2 * hz
            elif kind == "mug":
                r = b.rng.uniform(0.03, 0.045)
                hz = b.rng.uniform(0.04, 0.055)
                b.add(CYLINDER, (x, y, top + hz), (r, r, hz), 0.0, b.paint_mat(_vivid(b.rng)))
            elif kind == "bottle":
                r = b.rng.uniform(0.03, 0.045)
                hz = b.rng.uniform(0.08, 0.14)
                mat = b.paint_mat(_vivid(b.rng))
                b.add(CYLINDER, (x, y, top + hz), (r, r, hz), 0.0, mat)
                b.add(CYLINDER, (x, y, top + 2 * hz + 0.03), (r * 0.4, r * 0.4, 0.03), 0.0, mat)
            elif kind == "paper":
                paper = b.mat(tx.TEXT, _hsv(0.1, 0.03, b.rng.uniform(0.85, 0.97)), _hsv(0.6, 0.3, 0.15),
                              scale=b.rng.uniform(60, 110), p1=0.09)
                b.add(BOX, (x, y, top + 0.002), (0.105, 0.148, 0.002), iyaw, paper)
            elif kind == "bowl":
                r = min(b.rng.uniform(0.06, 0.12), rx, ry)
                b.add(ELLIPSOID, (x, y, top + 0.01), (r, r, r * 0.45), 0.0,
                      b.mat(tx.MARBLE, _neutral(b.rng), _vivid(b.rng), scale=8.0))
                for _ in range(int(b.rng.integers(0, 4))):  # fruit
                    fr = b.rng.uniform(0.03, 0.045)
                    o = b.rng.uniform(-r / 2, r / 2, size=2)
                    b.add(ELLIPSOID, (x + o[0], y + o[1], top + r * 0.4 + fr * 0.6), (fr, fr, fr), 0.0,
                          b.paint_mat(_vivid(b.rng), amp=0.2))
            elif kind == "box":
                hz = b.rng.uniform(0.03, 0.1)
                b.add(BOX, (x, y, top + hz), (rx * 0.8, ry * 0.8, hz), iyaw, b.paint_mat(_vivid(b.rng)))
            elif kind == "plant":
                _plant(b, (x, y, top), scale=0.45)
            else:  # laptop: base with keys, open lid
                keys = b.mat(tx.TILES, _hsv(0, 0, 0.15), _neutral(b.rng), scale=60.0, p1=0.003)
                b.add(BOX, (x, y, top + 0.01), (0.16, 0.11, 0.01), iyaw, keys)
                lid = b.paint_mat(_hsv(0.6, 0.2, 0.08), amp=0.1)
                dx2, dy2 = _rot2(iyaw, 0.0, -0.115)
                b.add(BOX, (x + dx2, y + dy2, top + 0.12), (0.16, 0.006, 0.11), iyaw, lid)


def _room_materials(b: _Builder) -> list[int]:
    rng = b.rng
    r = rng.random()
    if r < 0.45:
        a, c = _wood_colours(rng)
        floor = b.mat(tx.PLANKS, a, c, scale=1.0 / rng.uniform(0.09, 0.22), p1=rng.uniform(0.8, 2.0))
    elif r < 0.65:
        floor = b.mat(tx.TILES, _neutral(rng) if rng.random() < 0.7 else _muted(rng), _neutral(rng),
                      scale=1.0 / rng.uniform(0.2, 0.6), p1=rng.uniform(0.003, 0.008), p2=float(rng.random() < 0.3),
                      col_c=_muted(rng))
    elif r < 0.87:
        floor = b.mat(tx.CARPET, _muted(rng), _muted(rng), scale=rng.uniform(60, 140))
    else:
        floor = b.mat(tx.MARBLE, _neutral(rng), _neutral(rng), scale=rng.uniform(1, 4))
    base_paint = _wall_paint(rng)

    def wall_mat() -> int:
        q = rng.random()
        if q < 0.7:
            col = base_paint if rng.random() < 0.8 else _wall_paint(rng)
            return b.mat(tx.PAINT, col, _jitter(rng, col, 0.1), scale=rng.uniform(1, 4), p1=rng.uniform(0, 0.6),
                         amp=rng.uniform(0.03, 0.1))
        if q < 0.9:
            col = _wall_paint(rng)
            return b.mat(tx.STRIPES, col, _jitter(rng, col, 0.15), scale=1.0 / rng.uniform(0.05, 0.3),
                         p1=rng.uniform(0.3, 0.6), col_c=_jitter(rng, col, 0.3))
        return b.mat(tx.TILES, _neutral(rng), _neutral(rng), scale=1.0 / rng.uniform(0.1, 0.3), p1=0.004)

    walls = [wall_mat() for _ in range(4)]
    ceil_col = _hsv(0.1, rng.uniform(0, 0.05), rng.uniform(0.85, 0.97))
    ceiling = b.mat(tx.PAINT, ceil_col, ceil_col, scale=3.0, amp=0.04)
    # faces: 0 x=lo, 1 x=hi, 2 y=lo, 3 y=hi, 4 floor, 5 ceiling
    return [walls[0], walls[1], walls[2], walls[3], floor, ceiling]


def _baseboards(b: _Builder) -> None:
    mat = b.paint_mat(_neutral(b.rng)) if b.rng.random() < 0.7 else b.wood_mat()
    h, t = b.rng.uniform(0.04, 0.1), 0.012
    b.add(BOX, (b.W / 2, t, h), (b.W / 2, t, h), 0.0, mat)
    b.add(BOX, (b.W / 2, b.D - t, h), (b.W / 2, t, h), 0.0, mat)
    b.add(BOX, (t, b.D / 2, h), (t, b.D / 2 - 2 * t, h), 0.0, mat)
    b.add(BOX, (b.W - t, b.D / 2, h), (t, b.D / 2 - 2 * t, h), 0.0, mat)


def _lights(b: _Builder):
    n = int(b.rng.integers(1, 4))
    pos, rgb = [], []
    for _ in range(n):
        x, y = b.rng.uniform(0.25, 0.75) * b.W, b.rng.uniform(0.25, 0.75) * b.D
        z = b.H - b.rng.uniform(0.12, 0.35)
        temp = b.rng.uniform(-1, 1)  # warm (-) to cool (+) white
        col = np.array([1.0 - 0.15 * temp, 1.0, 1.0 + 0.2 * temp]) * np.array([1.0, 0.95, 0.85])
        pos.append((x, y, z))
        rgb.append(col * b.rng.uniform(0.6, 1.4))
        fixture = b.mat(tx.PAINT, _hsv(0.1, 0.05, 0.95), _hsv(0.1, 0.05, 0.95), emissive=3.0, amp=0.02)
        r = b.rng.uniform(0.1, 0.25)
        if b.rng.random() < 0.5:
            b.add(ELLIPSOID, (x, y, b.H), (r, r, b.H - z - 0.03), 0.0, fixture)
        else:
            b.add(CYLINDER, (x, y, b.H - 0.02), (r, r, 0.02), 0.0, fixture)
    pos_a, rgb_a = np.array(pos), np.array(rgb)
    # exposure: scale the lights so that the unshadowed irradiance at the floor's centre is about 1.25,
    # which maps mid albedos to mid grey (a fixed per-scene exposure keeps frames photometrically consistent)
    centre = np.array([b.W / 2, b.D / 2, 0.0])
    d = pos_a - centre
    dist2 = (d**2).sum(-1)
    e = (rgb_a.mean(-1) * (d[:, 2] / np.sqrt(dist2)) / (dist2 + LIGHT_SOFTENING**2)).sum()
    rgb_a = rgb_a * (b.rng.uniform(0.9, 1.7) / e)
    amb = np.array([1.0, 1.0, 1.0]) * b.rng.uniform(0.25, 0.5) * np.array([0.95, 0.98, 1.05])
    return pos_a, rgb_a, amb


def _spread_lights(b: _Builder):
    """Ceiling lights on a jittered grid over the whole room (large rooms, corridors), exposed so that the
    mean unshadowed irradiance over the floor is what :func:`_lights` gives at a small room's centre."""
    n = int(np.clip(round(b.W * b.D / AREA_PER_LIGHT), 1, MAX_LIGHTS))
    nx = max(1, int(round(math.sqrt(n * b.W / b.D))))
    ny = max(1, int(math.ceil(n / nx)))
    pos, rgb = [], []
    for i in range(nx):
        for j in range(ny):
            if len(pos) == n:
                break
            x = (i + 0.5 + b.rng.uniform(-0.2, 0.2)) * b.W / nx
            y = (j + 0.5 + b.rng.uniform(-0.2, 0.2)) * b.D / ny
            z = b.H - b.rng.uniform(0.12, 0.35)
            temp = b.rng.uniform(-1, 1)
            col = np.array([1.0 - 0.15 * temp, 1.0, 1.0 + 0.2 * temp]) * np.array([1.0, 0.95, 0.85])
            pos.append((x, y, z))
            rgb.append(col * b.rng.uniform(0.7, 1.3))
            fixture = b.mat(tx.PAINT, _hsv(0.1, 0.05, 0.95), _hsv(0.1, 0.05, 0.95), emissive=3.0, amp=0.02)
            r = b.rng.uniform(0.1, 0.3)
            b.add(CYLINDER, (x, y, b.H - 0.02), (r, r, 0.02), 0.0, fixture)
    pos_a, rgb_a = np.array(pos), np.array(rgb)
    gx, gy = np.meshgrid((np.arange(5) + 0.5) / 5 * b.W, (np.arange(5) + 0.5) / 5 * b.D)
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    d = pos_a[None, :, :] - floor[:, None, :]
    dist2 = (d**2).sum(-1)
    e = (rgb_a.mean(-1)[None] * (d[..., 2] / np.sqrt(dist2)) / (dist2 + LIGHT_SOFTENING**2)).sum(-1).mean()
    rgb_a = rgb_a * (b.rng.uniform(0.9, 1.7) / e)
    amb = np.array([1.0, 1.0, 1.0]) * b.rng.uniform(0.25, 0.5) * np.array([0.95, 0.98, 1.05])
    return pos_a, rgb_a, amb


@dataclass(frozen=True)
class RoomSize:
    """Ranges (metres) from which a room's width (x), depth (y) and ceiling height are drawn."""

    width: tuple[float, float] = (3.0, 7.0)
    depth: tuple[float, float] = (3.0, 7.5)
    height: tuple[float, float] = (2.4, 3.1)


#: The rooms of data version 1 (and of every seed built without a size): 3-7 m, ceilings 2.4-3.1 m.
DEFAULT_ROOM = RoomSize()
# Floor area (m²) lit by one ceiling light in rooms with a non-default size, and the most lights drawn (each
# light costs a shadow ray per pixel).
AREA_PER_LIGHT = 16.0
MAX_LIGHTS = 6


def _partitions(b: _Builder, n: int) -> None:
    """n interior walls across the room, each with a doorway (1-2.5 m wide), full height (separate rooms) or
    1.2-2 m high (office partitions); their footprints are claimed so that furniture keeps off them."""
    for _ in range(n):
        along_x = b.rng.random() < 0.5
        span, across = (b.W, b.D) if along_x else (b.D, b.W)
        if across < 4.0 or span < 3.0:
            continue
        at = b.rng.uniform(0.35, 0.65) * across
        t = b.rng.uniform(0.05, 0.08)
        h = b.H if b.rng.random() < 0.6 else b.rng.uniform(1.2, 2.0)
        gap = b.rng.uniform(1.0, min(2.5, 0.5 * span))
        g0 = b.rng.uniform(0.3, span - gap - 0.3)
        mat = b.paint_mat(_wall_paint(b.rng), amp=0.06)
        for a0, a1 in ((0.0, g0), (g0 + gap, span)):
            if a1 - a0 < 0.2:
                continue
            c, half = 0.5 * (a0 + a1), 0.5 * (a1 - a0)
            cx, cy, hx, hy = (c, at, half, t) if along_x else (at, c, t, half)
            b.add(BOX, (cx, cy, h / 2), (hx, hy, h / 2), 0.0, mat)
            b.claim(cx, cy, hx + 0.05, hy + 0.05, 0.0)


#: The layouts of data version 2 (:func:`build_scene_v2`): name, probability, room size, partitions, clutter.
V2_LAYOUTS = (
    ("room", 0.3, RoomSize((3.0, 7.0), (3.0, 7.5), (2.4, 3.2)), 0, 1.0),
    ("large", 0.25, RoomSize((7.0, 15.0), (5.0, 12.0), (2.6, 4.0)), 0, 0.8),
    ("open-plan", 0.25, RoomSize((8.0, 15.0), (6.0, 12.0), (2.6, 4.0)), 2, 0.8),
    ("corridor", 0.2, RoomSize((1.6, 3.0), (6.0, 20.0), (2.4, 3.2)), 0, 0.3),
)


def layout_of_v2(seed: int) -> str:
    """The layout :func:`build_scene_v2` draws for ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1A70]))
    p = np.array([w for _, w, *_ in V2_LAYOUTS])
    return V2_LAYOUTS[int(rng.choice(len(V2_LAYOUTS), p=p / p.sum()))][0]


def build_scene_v2(seed: int) -> Scene:
    """A room of data version 2: a small furnished room (3-7 m), a large room (7-15 m), an open-plan space
    split by interior walls with doorways into more than one room, or a corridor (1.6-3 m x 6-20 m, few
    objects, doors along its walls); ceilings 2.4-4 m. See :data:`V2_LAYOUTS`."""
    name = layout_of_v2(seed)
    _, _, size, partitions, clutter = next(x for x in V2_LAYOUTS if x[0] == name)
    return build_scene(seed, clutter=clutter, room=size, partitions=partitions, wall_items_per_m=0.35)


def build_scene(seed: int, clutter: float = 1.0, room: RoomSize | None = None, partitions: int = 0,
                wall_items_per_m: float = 0.0, furniture: bool = True) -> Scene:
    """Draw a room from ``seed``. ``clutter`` scales the number of furniture and clutter items; ``room``
    (default :data:`DEFAULT_ROOM`) gives the ranges of its size. Rooms of another size get ceiling lights
    spread over the whole floor (one per AREA_PER_LIGHT m²) instead of 1-3 near the middle; a seed built
    without ``room`` is the same scene as before sizes could be chosen. ``partitions``: up to that many
    interior walls with doorways (1 or 2 with probability 1/2 each); ``wall_items_per_m``: further doors,
    windows, pictures and boards per metre of wall (large rooms and corridors need more than the default);
    ``furniture`` False: none on the floor (no furniture, tables or floor clutter; a corridor to walk along), the
    walls' items still there."""
    b = _Builder(seed)
    rng = b.rng
    size = room or DEFAULT_ROOM
    b.W, b.D, b.H = rng.uniform(*size.width), rng.uniform(*size.depth), rng.uniform(*size.height)
    room_mats = _room_materials(b)
    _baseboards(b)
    pos, rgb, amb = _lights(b) if room is None or room == DEFAULT_ROOM else _spread_lights(b)
    area = b.W * b.D
    if partitions > 0:
        _partitions(b, int(rng.integers(1, partitions + 1)))
    if rng.random() < 0.55 and min(b.W, b.D) > 2.2:  # (no rug in a corridor)
        _rug(b)
    _wall_items(b, int(rng.integers(1, 3)))  # a first few wall items (doors claim floor space)
    if furniture:
        makers = [(_shelf, 1.2), (_cabinet, 1.0), (_desk, 1.2), (_bed, 0.35), (_sofa, 0.5), (_floor_lamp, 0.4)]
        n_big = max(2, int(round(clutter * area / rng.uniform(3.5, 6.0))))
        weights = np.array([w for _, w in makers])
        for _ in range(n_big):
            maker = makers[int(rng.choice(len(makers), p=weights / weights.sum()))][0]
            maker(b)
        for _ in range(int(rng.integers(1, 3))):
            _table(b, against_wall=False)
        if rng.random() < 0.5:
            _table(b, against_wall=True)
        for _ in range(int(clutter * rng.integers(1, 5))):
            _floor_clutter(b)
    _wall_items(b, int(clutter * rng.integers(2, 7)))
    if wall_items_per_m > 0:
        _wall_items(b, int(round(wall_items_per_m * 2 * (b.W + b.D))))
    _clutter_on_surfaces(b, clutter * rng.uniform(0.6, 1.4))

    def prims(rows: list) -> Prims:
        if not rows:
            return Prims.empty()
        a = torch.tensor(rows, dtype=torch.float64)
        return Prims(a[:, 0:3].float(), a[:, 3:6].float(), a[:, 6].float(), a[:, 7].round().to(torch.int64))

    return Scene(
        room_lo=torch.zeros(3),
        room_hi=torch.tensor([b.W, b.D, b.H], dtype=torch.float32),
        room_material=torch.tensor(room_mats, dtype=torch.int64),
        prims=(prims(b.parts[BOX]), prims(b.parts[CYLINDER]), prims(b.parts[ELLIPSOID])),
        materials=torch.from_numpy(np.stack(b.materials)),
        light_pos=torch.tensor(pos, dtype=torch.float32),
        light_rgb=torch.tensor(rgb, dtype=torch.float32),
        ambient=torch.tensor(amb, dtype=torch.float32),
        seed=seed,
        surfaces=list(b.surfaces),
    )

