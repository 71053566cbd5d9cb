"""A vectorised CPU ray caster for the synthetic scenes.

Why a ray caster in torch rather than an OpenGL/EGL renderer library:

- **exact depth**: every pixel's z-depth is the analytic ray/primitive intersection at the pixel centre (no
  depth-buffer quantisation, no anti-aliased depth mixing foreground and background);
- **determinism**: only element-wise tensor ops and exact min-reductions (no BLAS, no atomics), so one seed
  gives byte-identical images whatever the thread count, batch size or worker split (GPU rasterisers
  differ between drivers);
- **headless and dependency-free**: torch is already a dependency; nothing to install in CI, no display;
- **speed**: scenes hold ~50-250 analytic primitives. Rays are traced in 8x8-pixel tiles, and each tile
  (and each tile's shadow rays and occlusion probes) is tested only against the primitives whose bounding
  sphere and box can touch it (conservative culling, so the result equals testing every primitive);
  axis-aligned primitives skip the rotation. Work is done in cache-sized chunks, which also sit below
  torch's intra-op parallel grain: run one torch thread per process and parallelise over processes, as
  ``codeslam synth --workers`` does (``benchmarks/bench_synth.py`` prints frames per second).

Shading is view-independent, so a surface point has the same colour in every frame: Lambertian diffuse from
point lights with hard shadows (shadow rays), an ambient term attenuated by ambient occlusion computed from
the scene's signed distance field along the normal, and emissive surfaces (windows, lamp shades).
Texture colour is a function of the 3D surface point (:mod:`codeslam.synth.textures`). The only
per-frame, view-dependent effects are the optional sensor effects (Gaussian noise and blur), off by default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera
from codeslam.synth import textures as tx
from codeslam.synth.primitives import (
    BOX,
    RAY_FUNCS,
    SDF_FUNCS,
    local_frame,
    local_normal,
    normal_to_world,
    ray_room,
    room_normal,
    sdf_room,
)
from codeslam.synth.scene import LIGHT_SOFTENING, Scene

# Rays start this far (metres along the normal) off a surface for shadow and occlusion queries.
SURFACE_OFFSET = 2e-3
# Intersections nearer than this ray parameter are ignored (self-intersection guard).
T_MIN = 1e-4
# Rays are traced in square tiles of this many pixels a side; each tile is tested only against the
# primitives that can touch it (culling), which is what makes the ray caster fast.
TILE = 8
# Most (group x ray x candidate) pairs evaluated in one tensor op, and rays shaded together: sized so that
# the tensors of one op stay in a CPU's L2/L3 cache (measured ~2x faster than whole-image tensors).
PAIR_BUDGET = 1 << 18
RAY_CHUNK = 1 << 14
# Angular margin (radians) added to tile cones against round-off.
_CONE_MARGIN = 1e-3


@dataclass(frozen=True)
class RenderConfig:
    """How frames are rendered.

    Attributes:
        shadows: trace shadow rays to every light (hard shadows); off gives unshadowed Lambertian light.
        ao_samples: number of signed-distance samples along the normal for ambient occlusion (0 = none).
        ao_radius: largest distance (metres) probed for ambient occlusion.
        supersample: colour is the mean of ``s x s`` sub-pixel rays (anti-aliasing); depth always comes
            from the pixel centre ray.
        noise_std: standard deviation of additive Gaussian sensor noise on [0, 1] colours (0 = none).
        blur_sigma: standard deviation (pixels) of a Gaussian sensor blur (0 = none).
        max_depth: depths beyond this (metres) are written as 0 (invalid), like a depth sensor's range.
    """

    shadows: bool = True
    ao_samples: int = 4
    ao_radius: float = 0.3
    supersample: int = 1
    noise_std: float = 0.0
    blur_sigma: float = 0.0
    max_depth: float = 10.0

    def __post_init__(self) -> None:
        if self.supersample < 1:
            raise CodeSLAMError(f"supersample must be >= 1, got {self.supersample}")
        # written as "not x >= 0" so that NaN (which compares false with everything) is refused too
        if not (self.noise_std >= 0 and self.blur_sigma >= 0 and self.ao_samples >= 0 and self.ao_radius >= 0):
            raise CodeSLAMError("noise_std, blur_sigma, ao_samples and ao_radius must be non-negative")
        if not (math.isfinite(self.noise_std) and math.isfinite(self.blur_sigma) and math.isfinite(self.ao_radius)):
            raise CodeSLAMError(f"noise_std, blur_sigma and ao_radius must be finite, got {self.noise_std}, "
                                f"{self.blur_sigma}, {self.ao_radius}")
        if not self.max_depth > 0:
            raise CodeSLAMError(f"max_depth must be positive, got {self.max_depth}")


# ------------------------------------------------------------------------------------------------ rays
def tile_pixels(camera: PinholeCamera, supersample: int = 1, tile: int = TILE):
    """Sample positions of the image grouped by tiles.

    Returns u, v (T, G) float64 pixel coordinates, with T tiles and G = (tile * s)² samples per tile (tiles
    at the right/bottom border repeat the last column/row), and ``slot`` (H, W) int64: the flat index
    ``tile * G + k`` of each pixel's sample at sub-index s // 2 in both axes (its centre when s is odd),
    to read results back.
    Sub-pixel offsets are ``(k + 0.5) / s - 0.5`` (s = 1 gives the pixel centres).
    """
    s, H, W = supersample, camera.height, camera.width
    ty, tx = -(-H // tile), -(-W // tile)
    off = (torch.arange(s, dtype=torch.float64) + 0.5) / s - 0.5
    py = torch.arange(ty * tile).clamp_max(H - 1).to(torch.float64)
    px = torch.arange(tx * tile).clamp_max(W - 1).to(torch.float64)
    v = (py[:, None] + off[None, :]).reshape(ty, tile * s)  # (ty, tile*s) rows of samples
    u = (px[:, None] + off[None, :]).reshape(tx, tile * s)
    vv = v[:, None, :, None].expand(ty, tx, tile * s, tile * s).reshape(ty * tx, -1)
    uu = u[None, :, None, :].expand(ty, tx, tile * s, tile * s).reshape(ty * tx, -1)
    G = (tile * s) ** 2
    yy = torch.arange(H)[:, None].expand(H, W)
    xx = torch.arange(W)[None, :].expand(H, W)
    c = s // 2
    slot = ((yy // tile) * tx + xx // tile) * G + ((yy % tile) * s + c) * (tile * s) + (xx % tile) * s + c
    return uu, vv, slot


def camera_rays(camera: PinholeCamera, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Camera-frame directions (..., 3) float64 with z = 1 (the ray parameter is z-depth) through pixel
    positions u, v (...)."""
    return torch.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, torch.ones_like(u)], -1)


def world_rays(dirs_c: torch.Tensor, T_wc: torch.Tensor):
    """World rays of camera rays dirs_c (T, G, 3) for poses T_wc (V, 4, 4): origins (V * T, 3) (one per
    tile) and directions (V * T, G, 3), float32. Written as explicit products rather than a matmul so that
    results do not depend on BLAS blocking or thread count."""
    T = T_wc.to(torch.float64)
    R, t = T[:, :3, :3], T[:, :3, 3]
    dc = dirs_c.to(torch.float64)[None]  # (1, T, G, 3)
    Rb = R[:, None, None]  # (V, 1, 1, 3, 3)
    d = Rb[..., :, 0] * dc[..., 0:1] + Rb[..., :, 1] * dc[..., 1:2] + Rb[..., :, 2] * dc[..., 2:3]
    V, Tn, G = d.shape[:3]
    o = t[:, None, :].expand(V, Tn, 3)
    return o.reshape(V * Tn, 3).to(torch.float32), d.reshape(V * Tn, G, 3).to(torch.float32)


# ------------------------------------------------------------------------------------------- culling
@dataclass
class _PrimSet:
    """Primitives of one kind that share a code path (axis-aligned or rotated), ready for culling."""

    kind: int
    aligned: bool
    q: torch.Tensor  # (n + 1, 8) parameter rows, the last one never hit
    centre: torch.Tensor  # (n, 3)
    radius: torch.Tensor  # (n,) bounding-sphere radius
    lo: torch.Tensor  # (n, 3) world bounding box
    hi: torch.Tensor  # (n, 3)
    index: torch.Tensor  # (n,) index of each primitive within its kind

    def ray_fn(self):
        f, aligned = RAY_FUNCS[self.kind], self.aligned
        return lambda o, d, q: f(o, d, q, T_MIN, aligned)

    def sdf_fn(self):
        f, aligned = SDF_FUNCS[self.kind], self.aligned
        return lambda p, q: f(p, q, aligned)


def _prim_sets(scene: Scene) -> list[_PrimSet]:
    """Split every kind into axis-aligned primitives (no rotation needed: cheaper) and rotated ones."""
    sets = []
    for kind, pr in enumerate(scene.prims):
        if len(pr) == 0:
            continue
        mask = pr.aligned_mask(round_symmetric=kind != BOX)
        ext = pr.world_half_extents()
        for aligned in (True, False):
            idx = torch.nonzero(mask if aligned else ~mask).squeeze(-1)
            if idx.numel() == 0:
                continue
            q = (pr.aligned_params(pad=True) if aligned else pr.params(pad=True))
            q = torch.cat([q[idx], q[-1:]], 0)
            c = pr.center[idx]
            sets.append(_PrimSet(kind, aligned, q, c, pr.bounding_radius()[idx], c - ext[idx], c + ext[idx], idx))
    return sets


def _box_overlap(lo: torch.Tensor, hi: torch.Tensor, ps: _PrimSet, pad: float = 0.0) -> torch.Tensor:
    """Whether group boxes [lo, hi] (B, 3), grown by ``pad``, overlap the primitives' boxes: (B, n) bool."""
    return ((lo[:, None, :] - pad <= ps.hi[None]) & (hi[:, None, :] + pad >= ps.lo[None])).all(-1)


@dataclass
class _Cone:
    """The cone around a group of rays sharing an origin: apex o (B, 3), unit axis (B, 3), cos/sin of the
    half-angle (B,), and the box (lo, hi (B, 3)) of the rays' segments up to the room's walls."""

    o: torch.Tensor
    axis: torch.Tensor
    cos: torch.Tensor
    sin: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor

    @staticmethod
    def of(o: torch.Tensor, d: torch.Tensor, t_exit: torch.Tensor) -> _Cone:
        dn = d / d.norm(dim=-1, keepdim=True)
        axis = dn.mean(dim=1)
        axis = axis / axis.norm(dim=-1, keepdim=True)  # (B, 3)
        cos_a = (dn * axis[:, None, :]).sum(-1).amin(dim=1).clamp(-1.0, 1.0)
        ang = (torch.acos(cos_a) + _CONE_MARGIN).clamp_max(torch.pi / 2)
        ends = o[:, None, :] + t_exit[..., None] * d
        lo = torch.minimum(ends.amin(dim=1), o)
        hi = torch.maximum(ends.amax(dim=1), o)
        return _Cone(o, axis, torch.cos(ang), torch.sin(ang), lo, hi)


def _cone_candidates(cone: _Cone, ps: _PrimSet) -> torch.Tensor:
    """Which primitives can the rays of each group touch: (B, n) bool. Conservative: bounding spheres
    against the group's cone, and bounding boxes against the box of the rays' segments."""
    v = ps.centre[None, :, :] - cone.o[:, None, :]  # (B, n, 3)
    along = (v * cone.axis[:, None, :]).sum(-1)
    vv = (v * v).sum(-1)
    perp = (vv - along * along).clamp_min(0.0).sqrt()
    r = ps.radius[None, :]
    inside = (perp * cone.cos[:, None] - along * cone.sin[:, None] <= r) | (vv <= r * r)
    return inside & _box_overlap(cone.lo, cone.hi, ps, pad=1e-3)


@dataclass
class _Bounds:
    """Bounding ball (centre a (B, 3), radius ra (B,)) and box (lo, hi (B, 3)) of point groups (B, G, 3)."""

    a: torch.Tensor
    ra: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor

    @staticmethod
    def of(p: torch.Tensor) -> _Bounds:
        lo, hi = p.amin(dim=1), p.amax(dim=1)
        a = 0.5 * (lo + hi)  # box centre: its ball holds the group as surely as the mean's
        return _Bounds(a, (p - a[:, None, :]).norm(dim=-1).amax(dim=1), lo, hi)


def _capsule_candidates(b: _Bounds, light: torch.Tensor, ps: _PrimSet) -> torch.Tensor:
    """Primitives that can block segments from point groups with bounds b to ``light`` (3,): (B, n) bool
    (bounding spheres against the capsule from the points' ball to the light, and bounding boxes)."""
    ab = light[None, :] - b.a
    ac = ps.centre[None, :, :] - b.a[:, None, :]  # (B, n, 3)
    t = ((ac * ab[:, None, :]).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)[:, None]).clamp(0.0, 1.0)
    dist = (ac - t[..., None] * ab[:, None, :]).norm(dim=-1)
    caps = dist <= ps.radius[None, :] + b.ra[:, None]
    return caps & _box_overlap(torch.minimum(b.lo, light), torch.maximum(b.hi, light), ps, pad=1e-3)


def _near_candidates(b: _Bounds, reach: float, ps: _PrimSet) -> torch.Tensor:
    """Primitives within ``reach`` of some point of groups with bounds b (conservative): (B, n) bool."""
    gap = (ps.centre[None, :, :] - b.a[:, None, :]).norm(dim=-1)
    near = gap <= ps.radius[None, :] + b.ra[:, None] + reach
    return near & _box_overlap(b.lo, b.hi, ps, pad=reach)


def _reduce_min(fn, args: tuple[torch.Tensor, ...], q: torch.Tensor, cand: torch.Tensor):
    """Min over candidate primitives of ``fn(*args, q)`` for every ray of every group.

    args: tensors (B, G_i, 3) with G_i = G or 1 (broadcast, e.g. one origin per group); q: (n + 1, 8)
    parameter rows (the last one never hit); cand: (B, n) bool. Groups are sorted by candidate count and
    processed in buckets padded to the bucket's largest count.
    Returns the value (B, G) (inf where no candidate) and the primitive's row in q (B, G) int64.
    """
    B, n = cand.shape
    G = max(a.shape[1] for a in args)
    value = torch.full((B, G), float("inf"))
    index = torch.zeros((B, G), dtype=torch.int64)
    if n == 0 or B == 0:
        return value, index
    counts = cand.sum(dim=1)
    order = torch.argsort(counts, stable=True)
    key = torch.where(cand, torch.arange(n)[None, :], torch.full_like(cand, n, dtype=torch.int64))
    cand_idx = torch.sort(key, dim=1, stable=True).values  # candidates first, padded with n
    counts_sorted = counts[order].tolist()
    start = next((i for i, c in enumerate(counts_sorted) if c > 0), B)
    while start < B:
        end = start + 1
        k0 = counts_sorted[start]
        while end < B:
            k = counts_sorted[end]
            if (end - start + 1) * G * k > PAIR_BUDGET or k > max(2 * k0, k0 + 4):
                break
            end += 1
        K = counts_sorted[end - 1]
        sel = order[start:end]
        idx = cand_idx[sel, :K]  # (b, K)
        qg = q[idx][:, None, :, :]  # (b, 1, K, 8)
        vals = fn(*[a[sel][:, :, None, :] for a in args], qg)  # (b, G, K)
        vmin, arg = vals.min(dim=-1)
        value[sel] = vmin.expand(len(sel), G)
        index[sel] = idx.gather(1, arg.expand(len(sel), G))
        start = end
    return value, index


# ----------------------------------------------------------------------------------------------- trace
def trace(scene: Scene, o: torch.Tensor, d: torch.Tensor, sets: list[_PrimSet] | None = None):
    """Nearest surface along groups of rays o + t d: origins o (B, 3) (one per group), directions d (B, G, 3).

    Returns t (B, G), kind (B, G) int64 (-1 = room, else the primitive kind) and index (B, G) int64 (room
    face or primitive index within its kind).
    """
    sets = _prim_sets(scene) if sets is None else sets
    B, G = d.shape[:2]
    t, idx = ray_room(o[:, None, :].expand(B, G, 3).reshape(-1, 3), d.reshape(-1, 3), scene.room_lo,
                      scene.room_hi)
    t, idx = t.reshape(B, G), idx.reshape(B, G)
    kind = torch.full_like(idx, -1)
    cone = _Cone.of(o, d, t)
    for ps in sets:
        cand = _cone_candidates(cone, ps)
        tk, row = _reduce_min(ps.ray_fn(), (o[:, None, :], d), ps.q, cand)
        closer = tk < t
        t = torch.where(closer, tk, t)
        idx = torch.where(closer, ps.index[row.clamp_max(len(ps.index) - 1)], idx)
        kind = torch.where(closer, torch.full_like(kind, ps.kind), kind)
    return t, kind, idx


def occluded(scene: Scene, p: torch.Tensor, light: torch.Tensor, sets: list[_PrimSet] | None = None):
    """Whether any object blocks the segments from points p (B, G, 3) to the point ``light`` (3,).
    Returns (B, G) bool."""
    sets = _prim_sets(scene) if sets is None else sets
    seg = light - p
    bounds = _Bounds.of(p)
    blocked = torch.zeros(p.shape[:2], dtype=torch.bool)
    for ps in sets:
        cand = _capsule_candidates(bounds, light, ps)
        tk, _ = _reduce_min(ps.ray_fn(), (p, seg), ps.q, cand)
        blocked |= tk < 1.0
    return blocked


def scene_sdf(scene: Scene, p: torch.Tensor, reach: float, sets: list[_PrimSet] | None = None):
    """Distance (B, G) of point groups p (B, G, 3) to the nearest surface, exact wherever it is below
    ``reach`` metres (primitives farther than that from a group are skipped)."""
    sets = _prim_sets(scene) if sets is None else sets
    dist = sdf_room(p, scene.room_lo, scene.room_hi)
    bounds = _Bounds.of(p)
    for ps in sets:
        dk, _ = _reduce_min(ps.sdf_fn(), (p,), ps.q, _near_candidates(bounds, reach, ps))
        dist = torch.minimum(dist, dk)
    return dist


def surface(scene: Scene, p: torch.Tensor, kind: torch.Tensor, idx: torch.Tensor):
    """Geometry and material at hit points p (R, 3) on surfaces (kind, idx) (R,).

    Returns p_local (R, 3), n_local (R, 3), n_world (R, 3) and the material row index (R,) int64.
    """
    p_local = p.clone()
    n_local = torch.zeros_like(p)
    n_world = torch.zeros_like(p)
    mat = torch.zeros_like(idx)
    room = torch.nonzero(kind < 0).squeeze(-1)
    if room.numel():
        face = idx[room]
        n = room_normal(face)
        n_local[room] = n
        n_world[room] = n
        mat[room] = scene.room_material[face]
    for k, pr in enumerate(scene.prims):
        sel = torch.nonzero(kind == k).squeeze(-1)
        if sel.numel() == 0:
            continue
        i = idx[sel]
        pl, c, s = local_frame(p[sel], pr, i)
        nl = local_normal(k, pl, pr.half[i])
        p_local[sel] = pl
        n_local[sel] = nl
        n_world[sel] = normal_to_world(nl, c, s)
        mat[sel] = pr.material[i]
    return p_local, n_local, n_world, mat


def ambient_occlusion(scene: Scene, p: torch.Tensor, n: torch.Tensor, samples: int, radius: float,
                      sets: list[_PrimSet] | None = None):
    """Ambient occlusion in [0, 1] (1 = open) at surface points p with normals n (B, G, 3), from the scene's
    distance field at ``samples`` distances along the normal (a point at distance h from its surface with
    nothing nearer than h is unoccluded). Returns (B, G)."""
    if samples == 0:
        return torch.ones(p.shape[:2])
    occ = torch.zeros(p.shape[:2])
    total = 0.0
    for i in range(1, samples + 1):
        h = radius * i / samples
        w = 0.5 ** (i - 1)
        # the distance at p + h n only matters below h: primitives farther than h are culled
        dist = scene_sdf(scene, p + n * h, h, sets)
        occ = occ + w * (h - dist).clamp_min(0.0) / h
        total += w
    return (1.0 - 1.6 * occ / total).clamp(0.0, 1.0)


def shade(scene: Scene, o: torch.Tensor, d: torch.Tensor, config: RenderConfig, sets: list[_PrimSet] | None = None):
    """Linear radiance (B, G, 3) and ray parameter t (B, G) of ray groups o + t d (origins o (B, 3),
    directions d (B, G, 3))."""
    sets = _prim_sets(scene) if sets is None else sets
    B, G = d.shape[:2]
    t, kind, idx = trace(scene, o, d, sets)
    p = o[:, None, :] + t.unsqueeze(-1) * d
    p_local, n_local, n, mat_idx = surface(scene, p.reshape(-1, 3), kind.reshape(-1), idx.reshape(-1))
    mat = scene.materials[mat_idx]
    alb = tx.srgb_to_linear(tx.albedo(p_local, n_local, mat)).reshape(B, G, 3)
    n = n.reshape(B, G, 3)
    ao = ambient_occlusion(scene, p, n, config.ao_samples, config.ao_radius, sets)
    # hemispherical ambient: surfaces facing down see the lit floor less than those facing up see the ceiling
    hemi = 0.8 + 0.2 * n[..., 2]
    irr = scene.ambient * (ao * hemi).unsqueeze(-1)
    p_off = p + n * SURFACE_OFFSET
    for li in range(scene.light_pos.shape[0]):
        to_l = scene.light_pos[li] - p_off
        dist2 = (to_l * to_l).sum(-1)
        cos = ((n * to_l).sum(-1) / dist2.sqrt().clamp_min(1e-6)).clamp_min(0.0)
        lit = cos > 0
        if config.shadows:
            lit = lit & ~occluded(scene, p_off, scene.light_pos[li], sets)
        e = cos * lit.to(cos.dtype) / (dist2 + LIGHT_SOFTENING**2)
        # direct light also dimmed a little by AO (contact shadows under objects)
        irr = irr + scene.light_rgb[li] * (e * (0.6 + 0.4 * ao)).unsqueeze(-1)
    emissive = mat[:, 11].reshape(B, G, 1)
    radiance = torch.where(emissive > 0, alb * emissive, alb * irr)
    return radiance, t


# ---------------------------------------------------------------------------------------------- render
# Linear radiance above this knee is compressed smoothly towards 1 (a camera's highlight roll-off) instead of
# clipping, so bright lamps and white surfaces keep some texture.
TONE_KNEE = 0.6


def tonemap(radiance: torch.Tensor) -> torch.Tensor:
    """Identity below TONE_KNEE, then an exponential shoulder (C1-continuous) that approaches 1."""
    k = TONE_KNEE
    shoulder = k + (1.0 - k) * (1.0 - torch.exp(-(radiance - k) / (1.0 - k)))
    return torch.where(radiance < k, radiance, shoulder)


def _gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of (V, C, H, W) with replicate borders, written as explicit shifted sums over
    a few taps: deterministic whatever the thread count (a conv2d backend may pick different algorithms)."""
    r = max(1, int(round(3 * sigma)))
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    H, W = img.shape[-2:]
    pad = torch.nn.functional.pad(img, (r, r, r, r), mode="replicate")
    horiz = sum(k[j] * pad[..., :, j:j + W] for j in range(2 * r + 1))
    return sum(k[j] * horiz[..., j:j + H, :] for j in range(2 * r + 1))


def render(
    scene: Scene,
    camera: PinholeCamera,
    T_wc: torch.Tensor,
    config: RenderConfig = RenderConfig(),
    noise_seed: int | None = None,
):
    """Render views of a scene.

    Args:
        scene: the room.
        camera: ideal pinhole camera (distortion ignored).
        T_wc: (V, 4, 4) or (4, 4) camera-to-world poses (OpenCV camera axes).
        config: shading and sensor settings.
        noise_seed: seed of the sensor noise (used only when ``config.noise_std > 0``).

    Returns:
        image (V, 3, H, W) float32 sRGB in [0, 1] and depth (V, H, W) float32 z-depth in metres
        (0 beyond ``config.max_depth``); without the leading V for a single (4, 4) pose.
    """
    T = torch.as_tensor(T_wc, dtype=torch.float64)
    single = T.ndim == 2
    T = T.reshape(-1, 4, 4)
    V, H, W, s = T.shape[0], camera.height, camera.width, config.supersample
    sets = _prim_sets(scene)
    u, v, slot = tile_pixels(camera, s)
    o, d = world_rays(camera_rays(camera, u, v), T)
    Tn, G = u.shape
    step = max(1, RAY_CHUNK // G)  # tiles per chunk: keeps every tensor op cache-sized
    colours, ts = [], []
    for a in range(0, o.shape[0], step):
        radiance, t_ = shade(scene, o[a:a + step], d[a:a + step], config, sets)
        colours.append(tx.linear_to_srgb(tonemap(radiance)))  # (b, G, 3)
        ts.append(t_)
    colour, t = torch.cat(colours), torch.cat(ts)
    if s % 2 == 0:  # depth from the pixel centres, which are not among the samples
        uc, vc, slot = tile_pixels(camera, 1)
        oc, dc = world_rays(camera_rays(camera, uc, vc), T)
        step = max(1, RAY_CHUNK // uc.shape[1])
        t = torch.cat([trace(scene, oc[a:a + step], dc[a:a + step], sets)[0] for a in range(0, oc.shape[0], step)])
    depth = t.reshape(V, -1)[:, slot.reshape(-1)].reshape(V, H, W)
    if s > 1:  # box-filter the s x s samples of every pixel
        colour = colour.reshape(V * Tn, TILE, s, TILE, s, 3).mean(dim=(2, 4)).reshape(V * Tn, TILE * TILE, 3)
    _, _, slot1 = tile_pixels(camera, 1)
    image = colour.reshape(V, -1, 3)[:, slot1.reshape(-1)].reshape(V, H, W, 3).permute(0, 3, 1, 2).contiguous()
    depth = torch.where(depth <= config.max_depth, depth, torch.zeros_like(depth))
    if config.blur_sigma > 0:
        image = _gaussian_blur(image, config.blur_sigma)
    if config.noise_std > 0:
        g = torch.Generator().manual_seed(int(noise_seed or 0))
        image = image + config.noise_std * torch.randn(image.shape, generator=g)
    image = image.clamp(0.0, 1.0)
    if single:
        return image[0], depth[0]
    return image, depth


def to_uint8(image: torch.Tensor) -> torch.Tensor:
    """[0, 1] float image -> uint8 (round to nearest)."""
    return (image.clamp(0.0, 1.0) * 255.0 + 0.5).floor().to(torch.uint8)


def depth_to_uint16(depth: torch.Tensor, factor: float = 5000.0) -> torch.Tensor:
    """Metres -> 16-bit depth units (TUM factor 5000); 0 stays 0, values past the 16-bit range become 0."""
    q = (depth.to(torch.float64) * factor + 0.5).floor()
    q = torch.where((q > 65535) | (depth <= 0), torch.zeros_like(q), q)
    return q.to(torch.int32).to(torch.uint16)
