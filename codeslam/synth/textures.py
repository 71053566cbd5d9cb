"""Procedural surface textures: colour as a function of the 3D surface point, never of the pixel.

Every texture takes the hit point in its primitive's own (local) coordinates, the local surface normal and
the material's parameter row, and returns an sRGB albedo in [0, 1]. Because nothing here depends on the
camera, a surface point has the same albedo in every view; the renderer's shading is view-independent too,
so frames of one scene are photometrically consistent (what SfM and tracking tests rely on).

Noise is hash-based value noise (integer lattice hashed with 32-bit arithmetic held in int64, so it is exact
and platform-independent) summed over octaves (fractal Brownian motion). Written by hand because neither
torch nor kornia has 3D procedural noise.

Material parameter row (``MATERIAL_PARAMS`` floats), see :func:`material`:
``[kind, a_r, a_g, a_b, b_r, b_g, b_b, scale, p1, p2, salt, emissive, c_r, c_g, c_b, amp]``.
"""

from __future__ import annotations

import numpy as np
import torch

# Texture kinds (column 0 of a material row).
PAINT, WOOD, PLANKS, TILES, CARPET, MARBLE, STRIPES, PAINTING, BOOKS, TEXT, FABRIC, CHECKER, PANELS = range(13)
KIND_NAMES = (
    "paint", "wood", "planks", "tiles", "carpet", "marble", "stripes", "painting", "books", "text", "fabric",
    "checker", "panels",
)
MATERIAL_PARAMS = 16
_MASK32 = 0xFFFFFFFF


def material(
    kind: int,
    col_a,
    col_b=(0.0, 0.0, 0.0),
    scale: float = 1.0,
    p1: float = 0.0,
    p2: float = 0.0,
    salt: int = 0,
    emissive: float = 0.0,
    col_c=(0.0, 0.0, 0.0),
    amp: float = 0.1,
) -> np.ndarray:
    """One material row (``MATERIAL_PARAMS``,) float32.

    ``col_*`` are sRGB colours in [0, 1]; ``scale`` is the pattern frequency (1/metres); ``p1``, ``p2`` are
    kind-specific (grout width, stripe duty, plank length, ...); ``salt`` decorrelates the noise of
    materials; ``emissive > 0`` makes the surface a light-independent emitter of ``emissive * albedo``;
    ``amp`` is the amplitude of the low-frequency colour variation.
    """
    row = np.zeros(MATERIAL_PARAMS, dtype=np.float32)
    row[0] = kind
    row[1:4] = col_a
    row[4:7] = col_b
    row[7] = scale
    row[8] = p1
    row[9] = p2
    row[10] = salt % 100003
    row[11] = emissive
    row[12:15] = col_c
    row[15] = amp
    return row


# ----------------------------------------------------------------------------------------------- noise
def hash01(*coords: torch.Tensor) -> torch.Tensor:
    """Hash integer lattice coordinates (int64 tensors of one shape) to floats in [0, 1).

    All products stay below 2**63 (32-bit values times 31-bit primes), so the arithmetic is exact.
    """
    primes = (73856093, 19349663, 83492791, 49979687, 15485863)
    h = torch.zeros_like(coords[0])
    for c, p in zip(coords, primes):
        h = (h ^ ((c & _MASK32) * p)) & _MASK32
    h = ((h ^ (h >> 15)) * 0x2C1B3C6D) & _MASK32
    h = ((h ^ (h >> 12)) * 0x297A2D39) & _MASK32
    h = h ^ (h >> 15)
    return h.to(torch.float32) * (1.0 / 4294967296.0)


#: Lattice of the value noise: LATTICE^3 random values (period LATTICE cells), 128 KB, cache-resident.
LATTICE = 32
_LATTICE_VALUES = torch.from_numpy(np.random.default_rng(0xC0DE51A).random(LATTICE**3).astype(np.float32))


def value_noise3(p: torch.Tensor, salt: torch.Tensor | int = 0) -> torch.Tensor:
    """Smooth value noise in [0, 1]: random values on the integer lattice, blended trilinearly with a
    smoothstep fade. p: (..., 3) float; salt: int or (...) int64, shifts the lattice (decorrelates
    materials). Returns (...).

    The lattice is a fixed table of ``LATTICE^3`` values indexed with wrapped coordinates (period 32
    cells; octaves and salts shift it, which hides the repetition). One table lookup per corner was
    measured 2x faster than hashing or Perlin's nested permutation lookups on CPU."""
    pf = torch.floor(p)
    f = p - pf
    u = f * f * (3.0 - 2.0 * f)  # smoothstep fade
    i = pf.to(torch.int32)
    salt_t = torch.as_tensor(salt).to(torch.int32)
    m = LATTICE - 1
    ix, iy, iz = i[..., 0] + salt_t * 7, i[..., 1] + salt_t * 13, i[..., 2] + salt_t * 3
    ax = ((ix & m) * (LATTICE * LATTICE), ((ix + 1) & m) * (LATTICE * LATTICE))
    ay = ((iy & m) * LATTICE, ((iy + 1) & m) * LATTICE)
    az = (iz & m, (iz + 1) & m)
    ux, uy, uz = u.unbind(-1)
    tab = _LATTICE_VALUES
    c = {}
    for dx in (0, 1):
        for dy in (0, 1):
            axy = ax[dx] + ay[dy]
            v0 = tab[axy + az[0]]
            c[dx, dy] = v0 + (tab[axy + az[1]] - v0) * uz
    cx0 = c[0, 0] + (c[0, 1] - c[0, 0]) * uy
    cx1 = c[1, 0] + (c[1, 1] - c[1, 0]) * uy
    return cx0 + (cx1 - cx0) * ux


def fbm3(p: torch.Tensor, octaves: int = 4, salt: torch.Tensor | int = 0) -> torch.Tensor:
    """Fractal sum of value noise, normalised to [0, 1]. p: (..., 3). Returns (...)."""
    total = torch.zeros(p.shape[:-1], dtype=p.dtype)
    amp, norm = 1.0, 0.0
    for k in range(octaves):
        total = total + amp * value_noise3(p * (2.0**k) + 17.13 * k, salt + 101 * k)
        norm += amp
        amp *= 0.5
    return total / norm


def _mix(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Linear blend of colours a, b (K, 3) by t (K,)."""
    return a + (b - a) * t.unsqueeze(-1)


def _smoothstep(e0: float, e1: float, x: torch.Tensor) -> torch.Tensor:
    t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _hsv_to_rgb(h: torch.Tensor, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """h, s, v (K,) in [0, 1] -> (K, 3)."""
    k = torch.stack([(5.0 + h * 6.0) % 6.0, (3.0 + h * 6.0) % 6.0, (1.0 + h * 6.0) % 6.0], -1)
    return v.unsqueeze(-1) - (v * s).unsqueeze(-1) * torch.clamp(torch.minimum(k, 4.0 - k), 0.0, 1.0)


# -------------------------------------------------------------------------------------------- textures
def face_uv(p: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """2D coordinates on a surface from the local point p (K, 3) and normal n (K, 3): the two coordinates
    across the normal's dominant axis (x-y for horizontal faces, the horizontal one and z for vertical
    faces, so that ``v`` points up on walls). Returns (K, 2)."""
    a = n.abs()
    on_x = (a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2])
    on_y = ~on_x & (a[:, 1] >= a[:, 2])
    u = torch.where(on_x, p[:, 1], p[:, 0])
    v = torch.where(on_x | on_y, p[:, 2], p[:, 1])
    return torch.stack([u, v], -1)


def _uvw(uv: torch.Tensor, w: float = 0.0) -> torch.Tensor:
    return torch.cat([uv, torch.full_like(uv[:, :1], w)], -1)


def tex_paint(p, uv, m, salt):
    """Painted / plastic surface: base colour with soft mottling and faint blotches of the second colour."""
    s = m[:, 7:8]
    n = fbm3(p * s, 3, salt)
    blot = _smoothstep(0.55, 0.8, fbm3(p * s * 0.35 + 3.1, 2, salt + 7)) * m[:, 8]
    col = _mix(m[:, 1:4], m[:, 4:7], blot)
    return col * (1.0 + m[:, 15:16] * 2.0 * (n.unsqueeze(-1) - 0.5))


def tex_wood(p, uv, m, salt):
    """Solid wood: growth rings around the local axis chosen by p2 (x or y), distorted by noise, with
    fine streaks along the grain."""
    along_y = m[:, 9] > 0.5
    a = torch.where(along_y, p[:, 1], p[:, 0])
    b = torch.where(along_y, p[:, 0], p[:, 1])
    c = p[:, 2]
    q = torch.stack([a * 0.6, b * 4.0, c * 4.0], -1)
    warp = fbm3(q * m[:, 7:8] * 0.25, 3, salt)
    r = torch.sqrt((b + 0.37) ** 2 + (c + 0.71) ** 2) * m[:, 7] + 4.0 * warp
    ring = torch.frac(r)
    late = _smoothstep(0.55, 0.95, ring)
    streak = fbm3(torch.stack([a * 2.0, b * 60.0, c * 60.0], -1), 2, salt + 3)
    t = (0.75 * late + 0.35 * streak).clamp(0.0, 1.0)
    return _mix(m[:, 1:4], m[:, 4:7], t) * (1.0 + m[:, 15:16] * (warp.unsqueeze(-1) - 0.5))


def tex_planks(p, uv, m, salt):
    """Floorboards on the face plane: rows of width 1/scale, staggered plank ends (length p1), per-plank
    tint, grain streaks along the plank and dark gaps."""
    u, v = uv[:, 0], uv[:, 1]
    w = 1.0 / m[:, 7]
    row_f = v / w
    row = torch.floor(row_f).to(torch.int64)
    off = hash01(row, salt) * m[:, 8]
    col_f = (u + off) / m[:, 8]
    col_i = torch.floor(col_f).to(torch.int64)
    h = hash01(row, col_i, salt + 1)
    tint = 0.78 + 0.4 * h
    grain = fbm3(torch.stack([u * 3.0, v * 90.0, h * 50.0], -1), 3, salt + 2)
    knots = _smoothstep(0.72, 0.85, fbm3(torch.stack([u * 6.0, v * 12.0, h * 30.0], -1), 2, salt + 5))
    t = (0.8 * grain + 0.6 * knots).clamp(0.0, 1.0)
    col = _mix(m[:, 1:4], m[:, 4:7], t) * tint.unsqueeze(-1)
    fv = torch.frac(row_f)
    fu = torch.frac(col_f)
    gap_w = 0.004 / w
    gap = torch.minimum(fv, 1.0 - fv) < gap_w
    gap = gap | (torch.minimum(fu, 1.0 - fu) * m[:, 8] < 0.004)
    return torch.where(gap.unsqueeze(-1), col * 0.35, col)


def tex_tiles(p, uv, m, salt):
    """Tiles of size 1/scale with grout lines (p1 metres wide each side, colour b); p2 > 0.5 gives a checker of
    colours a and c; per-tile brightness jitter and speckle."""
    q = uv * m[:, 7:8]
    cell = torch.floor(q).to(torch.int64)
    f = q - torch.floor(q)
    d = torch.minimum(f, 1.0 - f).amin(-1)
    h = hash01(cell[:, 0], cell[:, 1], salt)
    checker = ((cell[:, 0] + cell[:, 1]) % 2 == 1) & (m[:, 9] > 0.5)
    base = torch.where(checker.unsqueeze(-1), m[:, 12:15], m[:, 1:4])
    speck = fbm3(_uvw(uv * 40.0, 0.5), 2, salt + 9)
    tile = base * (0.9 + 0.2 * h + 0.15 * (speck - 0.5)).unsqueeze(-1)
    groutc = m[:, 4:7] * (0.9 + 0.2 * speck).unsqueeze(-1)
    # grout with soft edges (_SOFT_EDGE metres), which aliases less than a hard threshold
    g = 1.0 - _smoothstep(0.0, 1.0, (d / m[:, 7] - m[:, 8]) / _SOFT_EDGE + 0.5)
    return _mix(tile, groutc, g)


def tex_carpet(p, uv, m, salt):
    """Carpet / rug: high-frequency pile noise over a low-frequency two-colour mottle."""
    s = m[:, 7:8]
    pile = fbm3(p * s, 2, salt)
    mottle = _smoothstep(0.3, 0.7, fbm3(p * s * 0.08, 3, salt + 4))
    col = _mix(m[:, 1:4], m[:, 4:7], mottle)
    return col * (0.7 + 0.6 * pile).unsqueeze(-1)


def tex_marble(p, uv, m, salt):
    """Marble / stone: turbulent sine veins of colour b through colour a."""
    s = m[:, 7:8]
    turb = fbm3(p * s, 5, salt)
    x = (p[:, 0] + 0.5 * p[:, 1] + 0.3 * p[:, 2]) * m[:, 7] * 2.0 + 8.0 * turb
    vein = 1.0 - torch.abs(torch.sin(x)) ** 0.25
    cloud = fbm3(p * s * 0.5 + 11.0, 3, salt + 1)
    col = m[:, 1:4] * (0.85 + 0.3 * cloud).unsqueeze(-1)
    return _mix(col, m[:, 4:7], vein.clamp(0.0, 1.0))


# Width (metres) of the wallpaper's pinstripes: wide enough not to alias into moire at 128x96.
_PINSTRIPE = 0.006
# Width (metres) over which thin line features (grout) fade into their surroundings.
_SOFT_EDGE = 0.004


def tex_stripes(p, uv, m, salt):
    """Wallpaper: vertical stripes (period 1/scale, duty p1) of colours a/b with thin c pinstripes and a
    faint damask-like noise."""
    s = torch.frac(uv[:, 0] * m[:, 7])
    band = s < m[:, 8]
    col = torch.where(band.unsqueeze(-1), m[:, 4:7], m[:, 1:4])
    w = _PINSTRIPE * m[:, 7]  # as a fraction of the period
    pin = (torch.abs(s - m[:, 8]) < w) | (s < w)
    col = torch.where(pin.unsqueeze(-1), m[:, 12:15], col)
    pattern = fbm3(_uvw(uv * 25.0), 3, salt)
    return col * (0.92 + 0.16 * pattern).unsqueeze(-1)


def tex_painting(p, uv, m, salt):
    """A picture: a soft landscape/abstract composition of three colours plus random hue blobs."""
    s = m[:, 7:8]
    q = _uvw(uv * s)
    col = _mix(m[:, 1:4], m[:, 4:7], _smoothstep(0.42, 0.58, fbm3(q, 4, salt)))
    col = _mix(col, m[:, 12:15], _smoothstep(0.5, 0.62, fbm3(q * 1.7 + 5.0, 4, salt + 1)))
    hue = fbm3(q * 0.7 + 9.0, 2, salt + 2)
    blob = _smoothstep(0.6, 0.7, fbm3(q * 2.3 + 2.0, 3, salt + 3))
    accent = _hsv_to_rgb(hue, torch.full_like(hue, 0.7), torch.full_like(hue, 0.8))
    col = _mix(col, accent, blob)
    stroke = fbm3(_uvw(uv * 60.0, 2.0), 2, salt + 4)
    return col * (0.85 + 0.3 * stroke).unsqueeze(-1)


def tex_books(p, uv, m, salt):
    """A row of book spines along u (mean width 1/scale): random muted colours, random heights (the block's
    half height is p1; above a book, the dark colour b of the shelf's back), a light title label."""
    u, v = uv[:, 0], uv[:, 1]
    q = u * m[:, 7]
    k = torch.floor(q + 0.35 * torch.sin(torch.floor(q * 0.37) * 2.1)).to(torch.int64)
    h1 = hash01(k, salt)
    h2 = hash01(k, salt + 1)
    h3 = hash01(k, salt + 2)
    col = _hsv_to_rgb(h1, 0.25 + 0.55 * h2, 0.25 + 0.6 * h3)
    height = 2.0 * m[:, 8] * (0.62 + 0.38 * hash01(k, salt + 3))
    above = (v + m[:, 8]) > height
    rel = (v + m[:, 8]) / height.clamp_min(1e-3)
    label = (rel > 0.55) & (rel < 0.72) & (hash01(k, salt + 4) > 0.4)
    col = torch.where(label.unsqueeze(-1), 0.85 - 0.2 * col, col)
    fq = torch.frac(q)
    edge = (fq < 0.06) | (fq > 0.94)
    col = torch.where(edge.unsqueeze(-1), col * 0.55, col)
    return torch.where(above.unsqueeze(-1), m[:, 4:7], col)


def tex_text(p, uv, m, salt):
    """Printed paper / poster text: lines (pitch 1/scale) of word-like ink runs of colour b on colour a,
    within margins of p1 metres from the block's centre."""
    u, v = uv[:, 0], uv[:, 1]
    row_f = v * m[:, 7]
    row = torch.floor(row_f).to(torch.int64)
    fr = torch.frac(row_f)
    ch = torch.floor(u * m[:, 7] * 1.8).to(torch.int64)
    word = torch.floor(u * m[:, 7] * 0.35).to(torch.int64)
    ink = (hash01(ch, row, salt) > 0.3) & (hash01(word, row, salt + 1) > 0.2)
    ink = ink & (fr > 0.35) & (fr < 0.75) & (hash01(row, salt + 2) > 0.15)
    inside = (u.abs() < m[:, 8]) & (v.abs() < m[:, 8])
    ink = ink & inside
    paper = m[:, 1:4] * (0.95 + 0.08 * fbm3(p * 30.0, 2, salt)).unsqueeze(-1)
    return torch.where(ink.unsqueeze(-1), m[:, 4:7], paper)


def tex_fabric(p, uv, m, salt):
    """Woven fabric: a fine weave, low-frequency folds, and with p1 > 0.5 a plaid of colour b."""
    s = m[:, 7]
    # the weave is near the pixel size at a distance: keep its contrast low so that it cannot alias into moire
    weave = 0.5 + 0.25 * (torch.sin(uv[:, 0] * s * 6.283) + torch.sin(uv[:, 1] * s * 6.283))
    folds = fbm3(p * 3.0, 3, salt)
    col = m[:, 1:4] * (0.9 + 0.07 * weave + 0.35 * (folds - 0.5)).unsqueeze(-1)
    plaid_u = torch.frac(uv[:, 0] * s * 0.05) < 0.25
    plaid_v = torch.frac(uv[:, 1] * s * 0.05) < 0.25
    plaid = (plaid_u ^ plaid_v) & (m[:, 8] > 0.5)
    return torch.where(plaid.unsqueeze(-1), _mix(col, m[:, 4:7], torch.full_like(s, 0.6)), col)


def tex_checker(p, uv, m, salt):
    """A 3D checkerboard of colours a and b with cell size 1/scale."""
    c = torch.floor(p * m[:, 7:8]).to(torch.int64).sum(-1) % 2 == 1
    n = fbm3(p * 20.0, 2, salt)
    col = torch.where(c.unsqueeze(-1), m[:, 4:7], m[:, 1:4])
    return col * (0.9 + 0.2 * n).unsqueeze(-1)


def tex_panels(p, uv, m, salt):
    """Cabinet fronts / doors: panels of width 1/scale separated by dark seams (width p1 metres), each
    panel with a slightly different wood/paint tone from colour a, b streaks."""
    q = uv[:, 0] * m[:, 7]
    k = torch.floor(q).to(torch.int64)
    f = torch.frac(q) / m[:, 7]
    w = 1.0 / m[:, 7]
    seam = (f < m[:, 8]) | (f > w - m[:, 8])
    hv = uv[:, 1] * 3.0
    seam = seam | (torch.abs(torch.frac(hv) - 0.5) < m[:, 8] * 3.0 * (m[:, 9] > 0.5))
    streak = fbm3(torch.stack([uv[:, 0] * 40.0, uv[:, 1] * 2.0, k.to(torch.float32)], -1), 3, salt)
    tint = (0.9 + 0.2 * hash01(k, salt)).unsqueeze(-1)
    col = _mix(m[:, 1:4], m[:, 4:7], streak * 0.6) * tint
    return torch.where(seam.unsqueeze(-1), col * 0.3, col)


_TEXTURES = (
    tex_paint, tex_wood, tex_planks, tex_tiles, tex_carpet, tex_marble, tex_stripes, tex_painting,
    tex_books, tex_text, tex_fabric, tex_checker, tex_panels,
)


def albedo(p_local: torch.Tensor, n_local: torch.Tensor, mat: torch.Tensor) -> torch.Tensor:
    """sRGB albedo of surface points. p_local, n_local: (K, 3) in the primitive's frame; mat: (K, P)
    material rows of the points. Returns (K, 3) in [0, 1]."""
    out = torch.zeros(p_local.shape[0], 3, dtype=torch.float32)
    kinds = mat[:, 0].round().to(torch.int64)
    for kind in torch.unique(kinds).tolist():
        idx = torch.nonzero(kinds == kind).squeeze(-1)
        p = p_local.index_select(0, idx)
        n = n_local.index_select(0, idx)
        m = mat.index_select(0, idx)
        salt = m[:, 10].round().to(torch.int64)
        out.index_copy_(0, idx, _TEXTURES[kind](p, face_uv(p, n), m, salt))
    return out.clamp(0.0, 1.0)


def srgb_to_linear(c: torch.Tensor) -> torch.Tensor:
    """sRGB in [0, 1] -> linear (IEC 61966-2-1 curve); kornia has it for images only, this works on any shape."""
    return torch.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: torch.Tensor) -> torch.Tensor:
    """Linear -> sRGB in [0, 1] (inputs clamped to [0, 1])."""
    c = c.clamp(0.0, 1.0)
    return torch.where(c <= 0.0031308, c * 12.92, 1.055 * c.clamp_min(1e-8) ** (1.0 / 2.4) - 0.055)
