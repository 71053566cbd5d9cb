"""Camera poses inside a synthetic room: handheld-like trajectories for sequences, random views for training.

Poses are ``T_wc`` (camera-to-world, OpenCV camera axes: x right, y down, z forward) in the scene's world
frame (z up). Every camera position keeps ``clearance`` metres from every object and wall.

Trajectories: keyframes (position, look direction, roll) a random 1-2.5 s apart, joined by Catmull-Rom
splines; a third of the stretches keep the position nearly fixed while the view turns (rotation-dominant,
which the paper says the code prior copes with); the rest walk 0.2-1 m, so speeds vary. Small smooth
"handheld" jitter (a few millimetres, a fraction of a degree, 0.5-3 Hz) is added on top. Written by hand
(Catmull-Rom) because the package does not depend on scipy.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from codeslam.errors import CodeSLAMError
from codeslam.synth.scene import Scene

# Smallest distance (metres) between a camera centre and any object, wall, floor or ceiling.
DEFAULT_CLEARANCE = 0.2
# Largest pitch magnitude (radians) of a look direction: keeps the look-at frame away from its singularity.
MAX_PITCH = math.radians(80.0)


def look_at(position: torch.Tensor, target: torch.Tensor, roll: torch.Tensor | float = 0.0) -> torch.Tensor:
    """Camera-to-world poses looking from ``position`` (..., 3) at ``target`` (..., 3) with world z up,
    rotated by ``roll`` (...) radians about the optical axis. Returns (..., 4, 4) float64 ``T_wc``."""
    p = torch.as_tensor(position, dtype=torch.float64)
    z = torch.as_tensor(target, dtype=torch.float64) - p
    z = z / z.norm(dim=-1, keepdim=True)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(z)
    x = torch.linalg.cross(z, up)
    x = x / x.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    y = torch.linalg.cross(z, x)  # points down in the image
    roll = torch.as_tensor(roll, dtype=torch.float64).expand(z.shape[:-1])
    c, s = torch.cos(roll)[..., None], torch.sin(roll)[..., None]
    x, y = c * x + s * y, -s * x + c * y
    T = torch.zeros(z.shape[:-1] + (4, 4), dtype=torch.float64)
    T[..., :3, 0], T[..., :3, 1], T[..., :3, 2], T[..., :3, 3] = x, y, z, p
    T[..., 3, 3] = 1.0
    return T


def matmul3(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Batched 3x3 (or 4x4) matrix product (..., n, n) as an explicit sum, so the result does not depend on
    the BLAS kernel or thread count (byte-identical outputs per seed)."""
    return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)


def _small_rotation(rx: torch.Tensor, ry: torch.Tensor, rz: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of small rotation vectors (rx, ry, rz) (Rodrigues)."""
    w = torch.stack([rx, ry, rz], -1)
    th = w.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    k = w / th
    K = torch.zeros(w.shape[:-1] + (3, 3), dtype=w.dtype)
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    th = th[..., None]
    eye = torch.eye(3, dtype=w.dtype).expand_as(K)
    return eye + torch.sin(th) * K + (1 - torch.cos(th)) * matmul3(K, K)


def _free(scene: Scene, points: np.ndarray, clearance: float) -> np.ndarray:
    """(N,) bool: points (N, 3) at least ``clearance`` from every surface."""
    return (scene.free_distance(torch.from_numpy(points).float()) >= clearance).numpy()


def _random_free_points(scene: Scene, rng: np.random.Generator, n: int, clearance: float,
                        z_range: tuple[float, float]) -> np.ndarray:
    """n random free positions (n, 3) with heights in z_range (clipped to the room)."""
    W, D, H = scene.size
    lo = np.array([clearance, clearance, max(z_range[0], clearance)])
    hi = np.array([W - clearance, D - clearance, min(z_range[1], H - clearance)])
    out: list[np.ndarray] = []
    for _ in range(100):
        cand = lo + rng.random((max(4 * n, 64), 3)) * (hi - lo)
        out.extend(cand[_free(scene, cand, clearance)])
        if len(out) >= n:
            return np.stack(out[:n])
    raise CodeSLAMError("the synthetic room has no free space for the camera (clearance too large?)")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _direction(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], -1)


# ------------------------------------------------------------------------------------------ training views
def random_views(scene: Scene, n: int, rng: np.random.Generator, clearance: float = 0.15) -> torch.Tensor:
    """n diverse camera poses (n, 4, 4) float64 ``T_wc`` inside the room: close-ups of table tops and
    shelves, views of furniture, walls and corners from varied heights, with pitch and some roll.
    """
    W, D, H = scene.size
    centres = torch.cat([p.center for p in scene.prims]).numpy().astype(np.float64)
    radii = torch.cat([p.bounding_radius() for p in scene.prims]).numpy()
    big = centres[(radii > 0.12) & (radii < 2.0)]
    surf = np.array([s[:6] for s in scene.surfaces], dtype=np.float64).reshape(-1, 6)
    poses = []
    while len(poses) < n:
        m = 4 * (n - len(poses)) + 8
        mode = rng.choice(4, size=m, p=[0.3, 0.3, 0.25, 0.15])
        target = np.empty((m, 3))
        dist = np.empty(m)
        elev = np.empty(m)
        for i in range(m):
            if mode[i] == 0 and len(surf):  # close-up of a table / shelf top
                cx, cy, top, hx, hy, yaw = surf[rng.integers(len(surf))]
                lx, ly = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
                c, s = math.cos(yaw), math.sin(yaw)
                target[i] = (cx + c * lx - s * ly, cy + s * lx + c * ly, top)
                dist[i], elev[i] = rng.uniform(0.35, 1.3), rng.uniform(0.35, 1.3)
            elif mode[i] <= 1 and len(big):  # a piece of furniture
                target[i] = big[rng.integers(len(big))] + rng.normal(0, 0.1, 3)
                dist[i], elev[i] = rng.uniform(0.6, 3.0), rng.uniform(-0.2, 0.9)
            elif mode[i] <= 2:  # a wall point, often near a corner
                wall = rng.integers(4)
                s_ = rng.beta(0.6, 0.6)
                x = s_ * W if wall < 2 else (0.0 if wall == 2 else W)
                y = s_ * D if wall >= 2 else (0.0 if wall == 0 else D)
                target[i] = (x, y, rng.uniform(0.2, H - 0.2))
                dist[i], elev[i] = rng.uniform(0.8, 5.0), rng.uniform(-0.4, 0.5)
            else:  # the floor
                target[i] = (rng.uniform(0, W), rng.uniform(0, D), 0.0)
                dist[i], elev[i] = rng.uniform(0.7, 3.0), rng.uniform(0.3, 1.3)
        azim = rng.uniform(-math.pi, math.pi, m)
        pos = target + dist[:, None] * _direction(azim, np.minimum(elev, MAX_PITCH))
        ok = _free(scene, pos, clearance)
        for i in np.nonzero(ok)[0]:
            if len(poses) == n:
                break
            roll = float(np.clip(rng.normal(0.0, math.radians(7.0)), -0.45, 0.45))
            poses.append(look_at(torch.from_numpy(pos[i]), torch.from_numpy(target[i]), roll))
    return torch.stack(poses)


#: Data version 2 views: share looking along the room from standing or sitting height (the rest are the
#: version 1 views of furniture, walls and the floor), standing and sitting camera heights (metres), the share
#: of sitting, the nearest look-at distance (metres) and the pitch range (radians) of the along-room views.
ALONG_ROOM_SHARE = 0.55
STANDING_HEIGHT = (1.4, 1.8)
SITTING_HEIGHT = (1.0, 1.3)
SITTING_SHARE = 0.35
ALONG_MIN_DISTANCE = 2.5
ALONG_PITCH = (math.radians(-30.0), math.radians(15.0))


def _take_views(poses: list, n: int, pos: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, ok: np.ndarray,
                rng: np.random.Generator) -> None:
    """Append to ``poses`` (until it holds ``n``) a camera at each accepted candidate ``pos[i]`` (``ok``) looking
    along ``yaw[i]``, ``pitch[i]``, with a small random roll (one draw of ``rng`` per pose taken)."""
    for i in np.nonzero(ok)[0]:
        if len(poses) == n:
            break
        roll = float(np.clip(rng.normal(0.0, math.radians(3.0)), -0.2, 0.2))
        look = _direction(np.array(yaw[i]), np.array(pitch[i]))
        poses.append(look_at(torch.from_numpy(pos[i]), torch.from_numpy(pos[i] + look), roll))


def _along_room_views(scene: Scene, n_along: int, rng: np.random.Generator, clearance: float = 0.25) -> list:
    """n_along poses looking along the room from standing or sitting height (see :func:`random_views_v2`)."""
    W, D, H = scene.size
    poses = []
    while len(poses) < n_along:
        m = 4 * (n_along - len(poses)) + 16
        sit = rng.random(m) < SITTING_SHARE
        z = np.where(sit, rng.uniform(*SITTING_HEIGHT, m), rng.uniform(*STANDING_HEIGHT, m))
        z = np.minimum(z, H - clearance - 0.05)
        pos = np.stack([rng.uniform(clearance, W - clearance, m), rng.uniform(clearance, D - clearance, m), z], -1)
        target = np.stack([rng.uniform(0.0, W, m), rng.uniform(0.0, D, m), rng.uniform(0.3, min(2.2, H), m)], -1)
        v = target - pos
        flat = np.linalg.norm(v[:, :2], axis=-1)
        pitch = np.clip(np.arctan2(v[:, 2], np.maximum(flat, 1e-6)) + rng.normal(0.0, math.radians(5.0), m),
                        *ALONG_PITCH)
        yaw = np.arctan2(v[:, 1], v[:, 0])
        ok = _free(scene, pos, clearance) & (flat >= ALONG_MIN_DISTANCE)
        _take_views(poses, n_along, pos, yaw, pitch, ok, rng)
    return poses


def random_views_v2(scene: Scene, n: int, rng: np.random.Generator, clearance: float = 0.25) -> torch.Tensor:
    """n camera poses (n, 4, 4) float64 ``T_wc`` of data version 2: ALONG_ROOM_SHARE of them as a person sees a
    room, from standing (1.4-1.8 m) or sitting (1.0-1.3 m) height looking along it at a point at least
    2.5 m away (pitch -30 to +15 deg, a little roll), the rest :func:`random_views`' close-ups of furniture,
    walls and the floor. The order of the two kinds is shuffled."""
    n_along = int(rng.binomial(n, ALONG_ROOM_SHARE))
    poses = _along_room_views(scene, n_along, rng, clearance)
    out = poses + ([] if n == n_along else list(random_views(scene, n - n_along, rng, clearance=0.15)))
    order = rng.permutation(n)
    return torch.stack([out[i] for i in order])


#: Data version 3 views: shares looking along the room (as version 2) and looking at things (furniture, table and
#: shelf tops, walls, the floor) from a person's height; the rest are version 1's close-ups. Horizontal distance
#: (metres) from a person to what they look at, and the pitch range (radians) of those views.
V3_ALONG_SHARE = 0.4
V3_LOOK_AT_SHARE = 0.45
LOOK_AT_DISTANCE = (0.7, 4.0)
LOOK_AT_PITCH = (math.radians(-70.0), math.radians(20.0))


def _person_height(rng: np.random.Generator, m: int) -> np.ndarray:
    """(m,) camera heights of people standing (1.4-1.8 m) or, SITTING_SHARE of them, sitting (1.0-1.3 m)."""
    sit = rng.random(m) < SITTING_SHARE
    return np.where(sit, rng.uniform(*SITTING_HEIGHT, m), rng.uniform(*STANDING_HEIGHT, m))


def look_at_views(scene: Scene, n: int, rng: np.random.Generator, clearance: float = 0.25) -> torch.Tensor:
    """n poses (n, 4, 4) of a person looking at something from standing or sitting height: a piece of furniture
    or clutter, a table or shelf top, a wall point or the floor, 0.7-4 m away horizontally, so tables are seen
    from above at the distances people keep (where :func:`random_views` puts the camera 0.35-1.3 m from a table
    top, looking down)."""
    W, D, H = scene.size
    things = _interest_points(scene)
    poses = []
    while len(poses) < n:
        m = 4 * (n - len(poses)) + 16
        kind = rng.choice(3, size=m, p=[0.6, 0.25, 0.15])  # thing, wall, floor
        target = np.empty((m, 3))
        pick = rng.integers(0, max(len(things), 1), m)
        wall = rng.integers(0, 4, m)
        s_ = rng.random(m)
        for i in range(m):
            if kind[i] == 0 and len(things):
                target[i] = things[pick[i]]
            elif kind[i] <= 1:
                x = s_[i] * W if wall[i] < 2 else (0.0 if wall[i] == 2 else W)
                y = s_[i] * D if wall[i] >= 2 else (0.0 if wall[i] == 0 else D)
                target[i] = (x, y, rng.uniform(0.3, min(2.2, H - 0.2)))
            else:
                target[i] = (rng.uniform(0, W), rng.uniform(0, D), 0.0)
        dist = rng.uniform(*LOOK_AT_DISTANCE, m)
        azim = rng.uniform(-math.pi, math.pi, m)
        z = np.minimum(_person_height(rng, m), H - clearance - 0.05)
        pos = np.stack([target[:, 0] + dist * np.cos(azim), target[:, 1] + dist * np.sin(azim), z], -1)
        v = target - pos
        pitch = np.arctan2(v[:, 2], np.linalg.norm(v[:, :2], axis=-1)) + rng.normal(0.0, math.radians(4.0), m)
        yaw = np.arctan2(v[:, 1], v[:, 0]) + rng.normal(0.0, math.radians(6.0), m)
        inside = (pos[:, 0] > clearance) & (pos[:, 0] < W - clearance) & (pos[:, 1] > clearance) \
            & (pos[:, 1] < D - clearance)
        ok = inside & (pitch >= LOOK_AT_PITCH[0]) & (pitch <= LOOK_AT_PITCH[1])
        ok[ok] = _free(scene, pos[ok], clearance)
        _take_views(poses, n, pos, yaw, pitch, ok, rng)
    return torch.stack(poses) if poses else torch.zeros(0, 4, 4, dtype=torch.float64)


def random_views_v3(scene: Scene, n: int, rng: np.random.Generator) -> torch.Tensor:
    """n poses (n, 4, 4) of data version 3, shuffled: V3_ALONG_SHARE along the room (:func:`random_views_v2`'s
    kind), V3_LOOK_AT_SHARE looking at things from a person's height (:func:`look_at_views`), the rest
    :func:`random_views`' close-ups."""
    counts = rng.multinomial(n, [V3_ALONG_SHARE, V3_LOOK_AT_SHARE, 1 - V3_ALONG_SHARE - V3_LOOK_AT_SHARE])
    none = torch.zeros(0, 4, 4, dtype=torch.float64)
    along = _along_room_views(scene, int(counts[0]), rng)
    parts = [torch.stack(along) if along else none, look_at_views(scene, int(counts[1]), rng),
             random_views(scene, int(counts[2]), rng, clearance=0.15) if counts[2] else none]
    out = torch.cat(parts)
    return out[torch.from_numpy(rng.permutation(n))]


# ------------------------------------------------------------------------------------------- trajectories
def _catmull_rom(keys: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Uniform Catmull-Rom spline through keys (K, C) at parameters s (N,) in [0, K - 1]. Returns (N, C)."""
    K = len(keys)
    ext = np.concatenate([2 * keys[:1] - keys[1:2], keys, 2 * keys[-1:] - keys[-2:-1]])  # end tangents
    i = np.clip(np.floor(s).astype(int), 0, K - 2)
    u = (s - i)[:, None]
    p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
    return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3)


def _segment_free(scene: Scene, a: np.ndarray, b: np.ndarray, clearance: float, steps: int = 12) -> bool:
    pts = a + np.linspace(0.0, 1.0, steps)[:, None] * (b - a)
    return bool(_free(scene, pts, clearance).all())


def _interest_points(scene: Scene) -> np.ndarray:
    """(N, 3) points worth looking at: centres of objects that are neither tiny nor room-sized, and the
    centres of table/shelf tops."""
    centres = torch.cat([p.center for p in scene.prims]).numpy().astype(np.float64)
    radii = torch.cat([p.bounding_radius() for p in scene.prims]).numpy()
    pts = [centres[(radii > 0.05) & (radii < 1.5)]]
    if scene.surfaces:
        pts.append(np.array([(s[0], s[1], s[2]) for s in scene.surfaces], dtype=np.float64))
    return np.concatenate(pts).reshape(-1, 3)


def _keyframes(scene: Scene, rng: np.random.Generator, n_keys: int, clearance: float):
    """Key positions (K, 3), unit look directions (K, 3) and rolls (K,)."""
    interest = _interest_points(scene)
    pos = [_random_free_points(scene, rng, 1, clearance + 0.1, (0.8, 1.9))[0]]
    yaw0 = rng.uniform(-math.pi, math.pi)
    look = [_direction(np.array(yaw0), np.array(rng.uniform(-0.6, 0.1)))]
    for _ in range(1, n_keys):
        p = pos[-1]
        turn_in_place = rng.random() < 0.35  # rotation-dominant stretch
        if turn_in_place:
            new = p + rng.normal(0.0, 0.01, 3)
            if not _free(scene, new[None], clearance)[0]:
                new = p.copy()
        else:
            new = None
            for _ in range(40):
                step = rng.uniform(0.2, 1.0)
                ang = rng.uniform(-math.pi, math.pi)
                cand = p + np.array([step * math.cos(ang), step * math.sin(ang), rng.uniform(-0.25, 0.25)])
                cand[2] = np.clip(cand[2], 0.5, scene.size[2] - 0.5)
                if _free(scene, cand[None], clearance + 0.05)[0] and _segment_free(scene, p, cand, clearance + 0.05):
                    new = cand
                    break
            if new is None:
                new = p + rng.normal(0.0, 0.01, 3) * _free(scene, p[None], clearance)[0]
        # the new view: mostly towards a piece of furniture or clutter, else a random turn; at most ~70
        # degrees from the previous one, and at least ~25 degrees when turning in place
        prev = look[-1]
        lo_cos, hi_cos = (math.cos(math.radians(70)), math.cos(math.radians(25))) if turn_in_place else (0.35, 1.0)
        to = interest - new
        dist = np.linalg.norm(to, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cosang = (to @ prev) / dist
        ok = np.nonzero((dist > 0.5) & (dist < 4.5) & (cosang > lo_cos) & (cosang < hi_cos)
                        & (np.abs(to[:, 2]) < 0.9 * dist))[0]
        if len(ok) and rng.random() < 0.7:
            d = _unit(to[ok[rng.integers(len(ok))]])
            yaw, pitch = math.atan2(d[1], d[0]), float(np.clip(math.asin(d[2]), -1.0, 0.35))
        else:
            turn = rng.uniform(0.45, 1.2) if turn_in_place else rng.uniform(0.0, 1.0)
            yaw = math.atan2(prev[1], prev[0]) + turn * rng.choice([-1.0, 1.0])
            pitch = float(np.clip(math.asin(np.clip(prev[2], -1, 1)) + rng.uniform(-0.35, 0.35), -1.0, 0.35))
        pos.append(new)
        look.append(_direction(np.array(yaw), np.array(pitch)))
    rolls = np.clip(rng.normal(0.0, math.radians(5.0), n_keys), -0.3, 0.3)
    return np.stack(pos), np.stack(look), rolls


def random_trajectory(scene: Scene, n_frames: int, rng: np.random.Generator, fps: float = 30.0,
                      clearance: float = DEFAULT_CLEARANCE, jitter: bool = True) -> torch.Tensor:
    """A smooth handheld-like camera path of ``n_frames`` poses (n_frames, 4, 4) float64 ``T_wc`` sampled at
    ``fps``, never closer than ``clearance`` to any surface."""
    if n_frames < 1:
        raise CodeSLAMError(f"a trajectory needs at least one frame, got {n_frames}")
    duration = n_frames / fps
    for _attempt in range(30):
        gaps = rng.uniform(1.0, 2.5, size=int(duration / 1.0) + 3)
        key_t = np.concatenate([[0.0], np.cumsum(gaps)])
        pos_k, look_k, roll_k = _keyframes(scene, rng, len(key_t), clearance)
        t = np.arange(n_frames) / fps
        s = np.interp(t, key_t, np.arange(len(key_t)))
        pos = _catmull_rom(pos_k, s)
        aim = _catmull_rom(pos_k + 2.0 * look_k, s)  # look-at points 2 m ahead of the keys
        roll = _catmull_rom(roll_k[:, None], s)[:, 0]
        if jitter:
            for k in range(3):
                f = rng.uniform(0.5, 3.0, 3)
                ph = rng.uniform(0, 2 * math.pi, 3)
                amp = rng.uniform(0.001, 0.004, 3)
                pos[:, k] += (amp[:, None] * np.sin(2 * math.pi * f[:, None] * t[None] + ph[:, None])).sum(0)
        look = _unit(aim - pos)
        if not _free(scene, pos, clearance).all():
            continue
        pitch = np.arcsin(np.clip(look[:, 2], -1.0, 1.0))
        if (np.abs(pitch) > MAX_PITCH).any():
            continue
        T = look_at(torch.from_numpy(pos), torch.from_numpy(pos + look), torch.from_numpy(roll))
        if jitter:
            tt = torch.from_numpy(t)
            ang = []
            for _k in range(3):
                f = torch.from_numpy(rng.uniform(0.5, 3.0, 2))
                ph = torch.from_numpy(rng.uniform(0, 2 * math.pi, 2))
                amp = torch.from_numpy(rng.uniform(0.001, 0.005, 2))  # radians
                ang.append((amp[:, None] * torch.sin(2 * math.pi * f[:, None] * tt[None] + ph[:, None])).sum(0))
            T[:, :3, :3] = matmul3(T[:, :3, :3], _small_rotation(*ang))
        return T
    raise CodeSLAMError("could not fit a camera trajectory into the synthetic room; try another seed")
