"""Analytic primitives of the synthetic scenes: ray intersection, signed distance and surface normals.

World frame: z up, metres. Every primitive has a centre, half-extents and a yaw (rotation about the world z
axis); its local frame is ``p_local = Rz(-yaw) (p - centre)``. Three kinds:

- box: ``|x| <= hx, |y| <= hy, |z| <= hz`` (slab test);
- cylinder: elliptic, axis along local z: ``x²/hx² + y²/hy² <= 1, |z| <= hz``;
- ellipsoid: ``x²/hx² + y²/hy² + z²/hz² <= 1``.

The room is the inside of an axis-aligned box. Rays are ``o + t d`` with ``d`` not necessarily unit (the
renderer uses camera-frame directions with z = 1, so ``t`` is z-depth). Functions are vectorised over R rays
x N primitives by broadcasting: rays (..., 3) against primitive parameter rows (..., 8) from
:meth:`Prims.params` (e.g. (R, 1, 3) against (N, 8) gives (R, N)); misses are ``inf``. The rays never
start inside a primitive (the camera keeps a clearance, shadow rays leave surfaces along the normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

BOX, CYLINDER, ELLIPSOID = 0, 1, 2
KIND_NAMES = ("box", "cylinder", "ellipsoid")
# Direction components smaller than this are replaced by it (keeps the slab test free of 0/0).
_TINY_DIR = 1e-12


@dataclass
class Prims:
    """N primitives of one kind.

    Attributes:
        center: (N, 3) float32 world position of the centre.
        half: (N, 3) float32 half-extents (radii) along the local axes.
        yaw: (N,) float32 rotation about world z (radians).
        material: (N,) int64 row index into the scene's material table.
    """

    center: torch.Tensor
    half: torch.Tensor
    yaw: torch.Tensor
    material: torch.Tensor

    def __len__(self) -> int:
        return int(self.center.shape[0])

    @staticmethod
    def empty() -> Prims:
        return Prims(torch.zeros(0, 3), torch.ones(0, 3), torch.zeros(0), torch.zeros(0, dtype=torch.int64))

    def bounding_radius(self) -> torch.Tensor:
        """(N,) radius of a sphere around the centre that contains the primitive."""
        return self.half.norm(dim=-1)

    def params(self, pad: bool = False) -> torch.Tensor:
        """(N, 8) rows ``(cx, cy, cz, hx, hy, hz, cos yaw, sin yaw)``, the form the ray and distance
        functions take; with ``pad`` an extra last row holds a tiny primitive far outside any room, which
        no ray hits (used to pad candidate lists)."""
        q = torch.cat([self.center, self.half, torch.cos(self.yaw)[:, None], torch.sin(self.yaw)[:, None]], -1)
        if pad:
            far = torch.tensor([[_FAR, _FAR, _FAR, 1e-3, 1e-3, 1e-3, 1.0, 0.0]])
            q = torch.cat([q, far], 0)
        return q


    def aligned_mask(self, round_symmetric: bool = False) -> torch.Tensor:
        """(N,) bool: primitives whose local axes are the world's up to a quarter turn (yaw a multiple of
        90 degrees; with ``round_symmetric``, for cylinders and ellipsoids, also any yaw when hx == hy),
        which the ray and distance functions can treat without rotating (``aligned=True``)."""
        s, c = torch.sin(self.yaw), torch.cos(self.yaw)
        mask = (s.abs() < _ALIGNED_EPS) | (c.abs() < _ALIGNED_EPS)
        if round_symmetric:
            mask |= self.half[:, 0] == self.half[:, 1]
        return mask

    def aligned_params(self, pad: bool = False) -> torch.Tensor:
        """Like :meth:`params` for primitives of :meth:`aligned_mask`, with the half-extents expressed
        along the world axes (swapped for a quarter turn) and yaw 0."""
        swap = ((torch.sin(self.yaw).abs() > 0.5) & (self.half[:, 0] != self.half[:, 1]))[:, None]
        half = torch.where(swap, self.half[:, [1, 0, 2]], self.half)
        q = torch.cat([self.center, half, torch.ones_like(self.yaw)[:, None], torch.zeros_like(self.yaw)[:, None]],
                      -1)
        if pad:
            q = torch.cat([q, torch.tensor([[_FAR, _FAR, _FAR, 1e-3, 1e-3, 1e-3, 1.0, 0.0]])], 0)
        return q

    def world_half_extents(self) -> torch.Tensor:
        """(N, 3) half-extents of the world-axis-aligned bounding box of each primitive."""
        c, s = torch.cos(self.yaw).abs(), torch.sin(self.yaw).abs()
        hx, hy, hz = self.half.unbind(-1)
        return torch.stack([c * hx + s * hy, s * hx + c * hy, hz], -1)


# Centre of the padding primitive (metres): farther than any room.
_FAR = 1e6
# |sin| or |cos| of a yaw below this counts as a quarter turn.
_ALIGNED_EPS = 1e-6


def _local_rays(o: torch.Tensor, d: torch.Tensor, q: torch.Tensor, aligned: bool):
    """Rays o, d (..., 3) in the frames of primitives q (..., 8) (shapes broadcast): six tensors. With
    ``aligned`` the rows are axis-aligned (see :func:`aligned_params`) and the rotation is skipped, and the
    direction components keep the rays' own shape (they do not depend on the primitive)."""
    cx, cy, cz, _, _, _, c, s = q.unbind(-1)
    ox, oy, oz = o[..., 0] - cx, o[..., 1] - cy, o[..., 2] - cz
    if aligned:
        return ox, oy, oz, d[..., 0], d[..., 1], d[..., 2]
    lox, loy = c * ox + s * oy, -s * ox + c * oy
    ldx, ldy = c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]
    return lox, loy, oz, ldx, ldy, d[..., 2]


def _safe(d: torch.Tensor) -> torch.Tensor:
    return torch.where(d.abs() < _TINY_DIR, torch.full_like(d, _TINY_DIR), d)


def ray_box(
    o: torch.Tensor, d: torch.Tensor, q: torch.Tensor, t_min: float, aligned: bool = False
) -> torch.Tensor:
    """Entry distance of rays o + t d (..., 3) into boxes q (..., 8) (slab test; shapes broadcast).
    Returns the broadcast shape, inf on a miss."""
    lox, loy, loz, ldx, ldy, ldz = _local_rays(o, d, q, aligned)
    t_near = t_far = None
    for lo_, ld_, h in ((lox, ldx, q[..., 3]), (loy, ldy, q[..., 4]), (loz, ldz, q[..., 5])):
        inv = 1.0 / _safe(ld_)
        t1 = (-h - lo_) * inv
        t2 = (h - lo_) * inv
        lo_t, hi_t = torch.minimum(t1, t2), torch.maximum(t1, t2)
        t_near = lo_t if t_near is None else torch.maximum(t_near, lo_t)
        t_far = hi_t if t_far is None else torch.minimum(t_far, hi_t)
    hit = (t_near <= t_far) & (t_near > t_min)
    return torch.where(hit, t_near, torch.full_like(t_near, float("inf")))


def _first_root(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor):
    """Smaller root of a t² + b t + c = 0 (a > 0, c > 0: the ray starts outside) and whether it is real.

    Uses the cancellation-free form q = -(b + sign(b) sqrt(disc)) / 2, roots q / a and c / q: the
    textbook (-b - sqrt(disc)) / 2a loses ~4 digits in float32 for the near root of an approaching ray."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    sq = torch.sqrt(disc.clamp_min(0.0))
    q = -0.5 * (b + torch.where(b < 0, -sq, sq))
    t1 = q / a.clamp_min(1e-20)
    t2 = c / torch.where(q.abs() < 1e-30, torch.full_like(q, 1e-30), q)
    return torch.minimum(t1, t2), ok


def ray_cylinder(
    o: torch.Tensor, d: torch.Tensor, q: torch.Tensor, t_min: float, aligned: bool = False
) -> torch.Tensor:
    """Entry distance into capped elliptic cylinders q (axis local z). Returns (...), inf on a miss."""
    lox, loy, loz, ldx, ldy, ldz = _local_rays(o, d, q, aligned)
    rx, ry, hz = q[..., 3], q[..., 4], q[..., 5]
    qx, qy, dqx, dqy = lox / rx, loy / ry, ldx / rx, ldy / ry
    a = dqx * dqx + dqy * dqy
    b = 2.0 * (qx * dqx + qy * dqy)
    c = qx * qx + qy * qy - 1.0
    t_side, ok = _first_root(a, b, c)
    z_side = loz + t_side * ldz
    side = ok & (a > 1e-12) & (t_side > t_min) & (z_side.abs() <= hz)
    inf = torch.full_like(lox, float("inf"))
    t = torch.where(side, t_side, inf)
    # the cap facing the ray: z = -sign(dz) hz
    sdz = _safe(ldz)
    zc = torch.where(sdz > 0, -hz, hz)
    t_cap = (zc - loz) / sdz
    cx = (lox + t_cap * ldx) / rx
    cy = (loy + t_cap * ldy) / ry
    cap = (t_cap > t_min) & (cx * cx + cy * cy <= 1.0)
    return torch.minimum(t, torch.where(cap, t_cap, inf))


def ray_ellipsoid(
    o: torch.Tensor, d: torch.Tensor, q: torch.Tensor, t_min: float, aligned: bool = False
) -> torch.Tensor:
    """Entry distance into ellipsoids q. Returns (...), inf on a miss."""
    lox, loy, loz, ldx, ldy, ldz = _local_rays(o, d, q, aligned)
    hx, hy, hz = q[..., 3], q[..., 4], q[..., 5]
    qx, qy, qz = lox / hx, loy / hy, loz / hz
    dx, dy, dz = ldx / hx, ldy / hy, ldz / hz
    a = dx * dx + dy * dy + dz * dz
    b = 2.0 * (qx * dx + qy * dy + qz * dz)
    c = qx * qx + qy * qy + qz * qz - 1.0
    t, ok = _first_root(a, b, c)
    return torch.where(ok & (t > t_min), t, torch.full_like(t, float("inf")))


RAY_FUNCS = (ray_box, ray_cylinder, ray_ellipsoid)


def ray_room(o: torch.Tensor, d: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor):
    """Exit of rays starting inside the room box [lo, hi] (3,). Returns t (R,) and the face index (R,) int64,
    ``2 * axis + (1 if the face is at hi)``."""
    sd = _safe(d)
    t_axes = torch.where(sd > 0, (hi - o) / sd, (lo - o) / sd)  # (R, 3)
    t, axis = t_axes.min(dim=-1)
    face = 2 * axis + (sd.gather(-1, axis.unsqueeze(-1)).squeeze(-1) > 0).to(torch.int64)
    return t, face


def room_normal(face: torch.Tensor) -> torch.Tensor:
    """Inward normals (K, 3) of room faces (K,) int64."""
    n = torch.zeros(face.shape[0], 3)
    sign = torch.where(face % 2 == 1, -1.0, 1.0)
    n.scatter_(1, (face // 2).unsqueeze(-1), sign.unsqueeze(-1))
    return n


# ------------------------------------------------------------------------------------- signed distance
def _local_points(p: torch.Tensor, q: torch.Tensor, aligned: bool):
    cx, cy, cz, _, _, _, c, s = q.unbind(-1)
    x, y, z = p[..., 0] - cx, p[..., 1] - cy, p[..., 2] - cz
    if aligned:
        return x, y, z
    return c * x + s * y, -s * x + c * y, z


def sdf_box(p: torch.Tensor, q: torch.Tensor, aligned: bool = False) -> torch.Tensor:
    """Exact signed distance of points p (..., 3) to boxes q (..., 8) (shapes broadcast)."""
    lx, ly, lz = _local_points(p, q, aligned)
    qx, qy, qz = lx.abs() - q[..., 3], ly.abs() - q[..., 4], lz.abs() - q[..., 5]
    outside = torch.sqrt(qx.clamp_min(0) ** 2 + qy.clamp_min(0) ** 2 + qz.clamp_min(0) ** 2)
    inside = torch.maximum(torch.maximum(qx, qy), qz).clamp_max(0.0)
    return outside + inside


def sdf_cylinder(p: torch.Tensor, q: torch.Tensor, aligned: bool = False) -> torch.Tensor:
    """Signed distance to capped elliptic cylinders (exact for circular ones, a close bound otherwise)."""
    lx, ly, lz = _local_points(p, q, aligned)
    rx, ry = q[..., 3], q[..., 4]
    r = torch.minimum(rx, ry)
    k = torch.sqrt((lx / rx) ** 2 + (ly / ry) ** 2)
    dr = (k - 1.0) * r
    dz = lz.abs() - q[..., 5]
    outside = torch.sqrt(dr.clamp_min(0) ** 2 + dz.clamp_min(0) ** 2)
    return outside + torch.maximum(dr, dz).clamp_max(0.0)


def sdf_ellipsoid(p: torch.Tensor, q: torch.Tensor, aligned: bool = False) -> torch.Tensor:
    """Approximate signed distance to ellipsoids (the k0 (k0 - 1) / k1 bound)."""
    lx, ly, lz = _local_points(p, q, aligned)
    hx, hy, hz = q[..., 3], q[..., 4], q[..., 5]
    k0 = torch.sqrt((lx / hx) ** 2 + (ly / hy) ** 2 + (lz / hz) ** 2)
    k1 = torch.sqrt((lx / hx**2) ** 2 + (ly / hy**2) ** 2 + (lz / hz**2) ** 2)
    return k0 * (k0 - 1.0) / k1.clamp_min(1e-9)


SDF_FUNCS = (sdf_box, sdf_cylinder, sdf_ellipsoid)


def sdf_room(p: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Distance (R,) of points inside the room box to its nearest face (negative outside)."""
    return torch.minimum(p - lo, hi - p).amin(dim=-1)


# ---------------------------------------------------------------------------------------------- normals
def local_frame(p: torch.Tensor, pr: Prims, idx: torch.Tensor):
    """Local coordinates of surface points p (K, 3) lying on primitives ``idx`` (K,) of ``pr``, with the
    cos/sin of their yaw. Returns p_local (K, 3), cos (K,), sin (K,)."""
    c = torch.cos(pr.yaw)[idx]
    s = torch.sin(pr.yaw)[idx]
    q = p - pr.center[idx]
    lx, ly = c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]
    return torch.stack([lx, ly, q[:, 2]], -1), c, s


def local_normal(kind: int, p_local: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """Outward unit normals (K, 3) in the local frame at surface points p_local (K, 3) of primitives of one
    kind with half-extents half (K, 3)."""
    if kind == BOX:
        r = p_local.abs() / half
        axis = r.argmax(dim=-1, keepdim=True)
        n = torch.zeros_like(p_local)
        n.scatter_(1, axis, torch.sign(p_local.gather(1, axis)))
        return n
    if kind == CYLINDER:
        k = torch.sqrt((p_local[:, 0] / half[:, 0]) ** 2 + (p_local[:, 1] / half[:, 1]) ** 2)
        on_cap = (p_local[:, 2].abs() / half[:, 2] - 1.0).abs() < (k - 1.0).abs()
        side = torch.stack([p_local[:, 0] / half[:, 0] ** 2, p_local[:, 1] / half[:, 1] ** 2,
                            torch.zeros_like(p_local[:, 0])], -1)
        cap = torch.stack([torch.zeros_like(p_local[:, 0]), torch.zeros_like(p_local[:, 0]),
                           torch.sign(p_local[:, 2])], -1)
        n = torch.where(on_cap.unsqueeze(-1), cap, side)
    else:
        n = p_local / half**2
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def normal_to_world(n_local: torch.Tensor, c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Rotate local normals (K, 3) by +yaw (cos c, sin s (K,)) into the world."""
    return torch.stack([c * n_local[:, 0] - s * n_local[:, 1], s * n_local[:, 0] + c * n_local[:, 1],
                        n_local[:, 2]], -1)
