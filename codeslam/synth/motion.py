"""Camera paths as people move a camera: the motion presets ``handheld``, ``walk``, ``fast-turn`` and ``corridor``.

The default sequences (:func:`codeslam.synth.trajectory.random_trajectory`) drift a few millimetres per
frame. A preset instead simulates a person carrying the camera, in continuous time at ``SIM_HZ``, and samples
the path at the frame times, so the motion between frames follows from the speeds and the frame rate:

- ``handheld``: strolling at 0.3-0.6 m/s between spots of the room while pointing the camera at objects
  (yaw rate up to 45 deg/s), hand held at 1.1-1.7 m, with hand shake;
- ``walk``: walking along a large room (8-15 m x 6-12 m, ceilings 2.6-3.6 m) at 0.8-1.5 m/s, camera at eye
  height 1.45-1.8 m looking where the walker goes, with glances to the side, turns of up to 60 deg/s (plus
  shake), a head bob at the walker's step frequency and a sway at half of it;
- ``fast-turn``: standing at 1.4-1.8 m, panning by 45-180 deg at a time at up to 60-90 deg/s with pauses,
  the body swaying by a few centimetres;
- ``corridor``: the walk along a bare corridor (1.8-3 m wide, 10-20 m long, doors, windows and pictures on its
  walls, nothing on its floor) at 0.8-1.4 m/s: forward motion, the focus of expansion in view, where a direct
  method has the least parallax; turning back at its ends.

Each path is a rate- and acceleration-limited follower of targets (way points, look directions, pan angles)
drawn from the sequence's random generator, so it is continuous (no teleports) and its speeds and turn rates
stay inside the preset's limits before the shake is added. Shake: rotation jitter as three sinusoids per
camera axis of 1-7 Hz (a few tenths of a degree each, about 0.5-2 deg peak), translation jitter of a few
millimetres (0.5-4 Hz) and, when walking, the head bob (1-2.5 cm) with a pitch nod at the step frequency.
The walker's body keeps ``body_radius`` from furniture at knee and hip height (nobody walks through a table)
and the camera keeps ``clearance`` from every surface; a path that does not is drawn again.

Measured per-frame motion (``python scripts/motion_stats.py``: 24 seeds x 300 frames per preset and rate, no
rendering; median / 95th percentile / maximum of the translation and rotation between consecutive frames, the
mean speed and the 95th percentile of the angular speed):

=========  ===  ========================  =====================  =========  =========
preset     fps  translation (cm)          rotation (deg)         speed m/s  deg/s p95
=========  ===  ========================  =====================  =========  =========
handheld   10   3.7 / 5.8 / 6.8           1.6 / 5.2 / 6.7        0.35       52
handheld   30   1.2 / 1.9 / 2.3           0.6 / 1.8 / 2.5        0.35       55
walk       10   9.2 / 14.2 / 15.9         1.6 / 5.9 / 7.8        0.84       59
walk       30   3.1 / 4.7 / 5.2           0.6 / 2.0 / 2.7        0.88       61
fast-turn  10   0.6 / 1.1 / 1.9           6.1 / 9.0 / 11.0       0.06       90
fast-turn  30   0.2 / 0.4 / 0.7           2.0 / 3.1 / 3.8        0.07       93
corridor   10   10.3 / 13.8 / 14.9        1.3 / 5.9 / 7.9        0.88       59
corridor   30   3.3 / 4.5 / 4.8           0.5 / 1.9 / 2.9        0.90       56
=========  ===  ========================  =====================  =========  =========

The walk's mean speed sits at the low end of its cruise range because the walker slows down for turns at way
points; at 10 frames/s its 95th percentile (14 cm, 6 deg) is issue 11's "15 cm and 6 deg apart" basin.
``tests/synth/test_synth_motion.py`` checks these ranges on fewer seeds. :func:`codeslam.synth.generate_sequence`
builds each preset's sequences in a room of the preset's size (:attr:`MotionPreset.room`).

Library use: ``generate_sequence(out, seed, frames, motion="walk", fps=10)``, or
``preset_trajectory(scene, frames, rng, "walk", fps=10)`` for the poses alone.

Training data version 4 (``codeslam synth --train --data-version 4``, :func:`preset_path_views`) draws its views
from these paths: each room is one preset's room, and its views are frames of that preset's path through it, so
the network sees rooms and views as the presets (and people walking with a camera) do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from codeslam.errors import CodeSLAMError
from codeslam.synth.scene import RoomSize, Scene, build_scene
from codeslam.synth.trajectory import _small_rotation, _unit, look_at, matmul3

#: Rate (Hz) of the continuous-time simulation; a multiple of 10 and 30 so those frame rates sample it exactly.
SIM_HZ = 120.0
#: Heights (metres) at which the walker's body must keep ``body_radius`` from objects (knee and hip).
BODY_HEIGHTS = (0.5, 1.0)
#: Distance (m) at which the walker counts a way point as reached and heads for the next.
WAYPOINT_REACHED = 0.3
#: A handheld camera swings to objects at most this far (radians) from where it points now.
MAX_LOOK_SWING = math.radians(80.0)
#: Largest pitch (radians) of a look direction, up or down.
MAX_LOOK_PITCH = math.radians(60.0)


@dataclass(frozen=True)
class MotionPreset:
    """How a person moves the camera (see the module docstring for the measured per-frame motion)."""

    # Name on the command line (``--motion``).
    name: str
    # Range (m/s) of the walking speed, drawn per leg between way points ((0, 0): standing).
    speed: tuple[float, float]
    # Largest yaw/pitch rate (deg/s) of the deliberate camera motion (the shake comes on top).
    max_rate_deg: float
    # Largest angular acceleration (deg/s²) of the camera's yaw and pitch.
    max_ang_accel_deg: float
    # Largest linear acceleration (m/s²) of the walker.
    max_accel: float
    # Range (m) of the camera's height above the floor, drawn per sequence.
    height: tuple[float, float]
    # What the camera looks at: "ahead" (where the walker goes, with glances), "objects", or "pan".
    look: str
    # Range (m) of the vertical head bob at 1.2 m/s (scaled with the speed); 0 for no bob.
    bob: tuple[float, float]
    # Range (deg) of the amplitude of each of the three rotation-shake sinusoids per axis.
    shake_deg: tuple[float, float]
    # Range (m) of the amplitude of each of the two translation-shake sinusoids per axis.
    shake_m: tuple[float, float]
    # Smallest distance (m) of the camera centre to any surface.
    clearance: float
    # Smallest distance (m) of the walker's body (at BODY_HEIGHTS) to any object or wall.
    body_radius: float
    # Length range (m) of a leg between way points.
    leg: tuple[float, float]
    # Size ranges of the room the preset builds when the caller gives no scene.
    room: RoomSize
    # Further doors, windows and pictures per metre of wall of that room (``build_scene``'s ``wall_items_per_m``):
    # a corridor has many doors.
    wall_items_per_m: float = 0.0
    # Whether the room has furniture on its floor (a corridor's would block the way).
    furniture: bool = True

    def scene(self, seed: int) -> Scene:
        """The room this preset walks through for ``seed``."""
        return build_scene(seed, room=self.room, wall_items_per_m=self.wall_items_per_m, furniture=self.furniture)


PRESETS: dict[str, MotionPreset] = {
    "handheld": MotionPreset(
        name="handheld", speed=(0.3, 0.6), max_rate_deg=45.0, max_ang_accel_deg=150.0, max_accel=0.6,
        height=(1.1, 1.7), look="objects", bob=(0.003, 0.008), shake_deg=(0.12, 0.4), shake_m=(0.001, 0.004),
        clearance=0.3, body_radius=0.25, leg=(0.8, 4.0), room=RoomSize((5.0, 10.0), (4.5, 9.0), (2.5, 3.2)),
    ),
    "walk": MotionPreset(
        name="walk", speed=(0.8, 1.5), max_rate_deg=60.0, max_ang_accel_deg=200.0, max_accel=1.0,
        height=(1.45, 1.8), look="ahead", bob=(0.01, 0.025), shake_deg=(0.1, 0.35), shake_m=(0.001, 0.003),
        clearance=0.4, body_radius=0.3, leg=(2.5, 14.0), room=RoomSize((8.0, 15.0), (6.0, 12.0), (2.6, 3.6)),
    ),
    "fast-turn": MotionPreset(
        name="fast-turn", speed=(0.0, 0.0), max_rate_deg=90.0, max_ang_accel_deg=400.0, max_accel=0.3,
        height=(1.4, 1.8), look="pan", bob=(0.0, 0.0), shake_deg=(0.12, 0.4), shake_m=(0.001, 0.004),
        clearance=0.4, body_radius=0.25, leg=(0.0, 0.0), room=RoomSize((4.0, 9.0), (4.0, 9.0), (2.4, 3.2)),
    ),
    # The walk along a corridor (data version 2's corridor layout): forward motion, the focus of expansion in view.
    "corridor": MotionPreset(
        name="corridor", speed=(0.8, 1.4), max_rate_deg=60.0, max_ang_accel_deg=200.0, max_accel=1.0,
        height=(1.45, 1.8), look="ahead", bob=(0.01, 0.025), shake_deg=(0.1, 0.35), shake_m=(0.001, 0.003),
        clearance=0.4, body_radius=0.3, leg=(4.0, 18.0), room=RoomSize((1.8, 3.0), (10.0, 20.0), (2.4, 3.2)),
        wall_items_per_m=0.5, furniture=False,
    ),
}


def get_preset(motion: str | MotionPreset) -> MotionPreset:
    """The preset named ``motion`` (or ``motion`` itself); CodeSLAMError naming the choices otherwise."""
    if isinstance(motion, MotionPreset):
        return motion
    try:
        return PRESETS[motion]
    except KeyError:
        raise CodeSLAMError(f"unknown motion preset {motion!r}; choose one of {', '.join(PRESETS)}") from None


# --------------------------------------------------------------------------------------------- helpers
def _wrap(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def _follow(x: float, rate: float, target: float, max_rate: float, max_acc: float, dt: float) -> tuple[float, float]:
    """One step of a follower that moves x towards target with |rate| <= max_rate and |d rate/dt| <= max_acc,
    braking in time to stop at the target (a trapezoidal velocity profile). Returns (x, rate)."""
    err = target - x
    want = math.copysign(min(max_rate, math.sqrt(2.0 * max_acc * abs(err)) * 0.95, 8.0 * abs(err)), err)
    rate += float(np.clip(want - rate, -max_acc * dt, max_acc * dt))
    return x + rate * dt, rate


def _body_free(scene: Scene, xy: np.ndarray, z_cam: float, radius: float, clearance: float) -> np.ndarray:
    """(N,) bool: a walker at floor positions xy (N, 2) keeps ``radius`` from the walls and from every object
    at BODY_HEIGHTS, and its camera at height z_cam keeps ``clearance`` from every surface."""
    n = len(xy)
    W, D, _ = scene.size
    wall = np.minimum(np.minimum(xy[:, 0], W - xy[:, 0]), np.minimum(xy[:, 1], D - xy[:, 1]))
    body = [np.concatenate([xy, np.full((n, 1), z)], -1) for z in BODY_HEIGHTS]
    d_obj = scene.object_distance(torch.from_numpy(np.concatenate(body)).float()).numpy().reshape(len(body), n)
    cam = np.concatenate([xy, np.full((n, 1), z_cam)], -1)
    d_cam = scene.free_distance(torch.from_numpy(cam).float()).numpy()
    return (wall >= radius) & (d_obj >= radius).all(0) & (d_cam >= clearance)


def _leg_free(scene: Scene, a: np.ndarray, b: np.ndarray, z_cam: float, p: MotionPreset) -> bool:
    """Whether the straight walk from a to b (2,) keeps the body and camera clear (with a 10 cm margin)."""
    steps = max(2, int(np.linalg.norm(b - a) / 0.15) + 1)
    xy = a + np.linspace(0.0, 1.0, steps)[:, None] * (b - a)
    return bool(_body_free(scene, xy, z_cam, p.body_radius + 0.1, p.clearance + 0.1).all())


def _random_spots(scene: Scene, rng: np.random.Generator, n: int, z_cam: float, p: MotionPreset) -> np.ndarray:
    """Up to n random floor positions (k, 2) where the walker can stand (with a 20 cm margin)."""
    W, D, _ = scene.size
    m = p.body_radius + 0.2
    cand = np.stack([rng.uniform(m, W - m, n), rng.uniform(m, D - m, n)], -1)
    return cand[_body_free(scene, cand, z_cam, m, p.clearance + 0.2)]


def _next_waypoint(scene: Scene, rng: np.random.Generator, here: np.ndarray, heading: float, z_cam: float,
                   p: MotionPreset) -> np.ndarray | None:
    """A reachable way point (2,) a leg's length away from ``here``, preferring long legs that do not turn
    back; shorter legs where the room leaves no long one."""
    cand = _random_spots(scene, rng, 128, z_cam, p)
    if len(cand) == 0:
        return None
    v = cand - here
    dist = np.linalg.norm(v, axis=-1)
    turn = np.cos(np.arctan2(v[:, 1], v[:, 0]) - heading)
    score = dist * (1.3 + turn) * rng.uniform(0.3, 1.0, len(cand))
    for lo in (p.leg[0], 0.5 * p.leg[0], 0.6):
        idx = np.nonzero((dist >= lo) & (dist <= p.leg[1]))[0]
        for i in idx[np.argsort(-score[idx])][:16]:
            if _leg_free(scene, here, cand[i], z_cam, p):
                return cand[i]
    return None


# ------------------------------------------------------------------------------------------ simulation
def _simulate(scene: Scene, rng: np.random.Generator, p: MotionPreset, duration: float):
    """The deliberate motion at SIM_HZ: floor positions (N, 2), speed (N,), body heading (N,), camera yaw
    (N,) and pitch (N,), camera height (scalar), or None when the room leaves no way to walk."""
    dt = 1.0 / SIM_HZ
    n = int(math.ceil(duration * SIM_HZ)) + 1
    z_cam = float(rng.uniform(*p.height))
    spots = _random_spots(scene, rng, 256, z_cam, p)
    if len(spots) == 0:
        return None
    here = spots[rng.integers(len(spots))].astype(np.float64)
    heading = float(rng.uniform(-math.pi, math.pi))
    walking = p.speed[1] > 0
    way = way_next = None
    if walking:
        way = _next_waypoint(scene, rng, here, heading, z_cam, p)
        if way is None:
            return None
        heading = math.atan2(way[1] - here[1], way[0] - here[0])
        way_next = _next_waypoint(scene, rng, way, heading, z_cam, p)
        if way_next is None:
            return None
    cruise = float(rng.uniform(*p.speed)) if walking else 0.0
    speed = 0.5 * cruise
    max_rate, max_acc = math.radians(p.max_rate_deg), math.radians(p.max_ang_accel_deg)
    yaw, yaw_rate = heading, 0.0
    pitch, pitch_rate = float(rng.uniform(-0.35, 0.0)), 0.0
    # look targets: an offset from the heading ("ahead"), a point ("objects") or a pan angle ("pan")
    glance, glance_until = 0.0, float(rng.uniform(1.0, 3.0))
    pitch_target, pitch_until = pitch, float(rng.uniform(1.0, 3.0))
    interest = _look_points(scene)
    look_pt, look_until = None, 0.0
    pan_target, pan_rate, pan_pause = yaw, max_rate, float(rng.uniform(0.2, 0.8))
    out = np.zeros((n, 6))
    for k in range(n):
        t = k * dt
        if walking:
            to = way - here
            dist = float(np.linalg.norm(to))
            if dist < WAYPOINT_REACHED:
                leg_heading = math.atan2(way_next[1] - way[1], way_next[0] - way[0])
                new = _next_waypoint(scene, rng, way_next, leg_heading, z_cam, p)
                if new is None:  # a dead end: walk back the way that is known to be clear
                    new = way
                way, way_next, cruise = way_next, new, float(rng.uniform(*p.speed))
                to = way - here
                dist = float(np.linalg.norm(to))
            err = _wrap(math.atan2(to[1], to[0]) - heading)
            # turn the body at most at 80% of the camera's rate; slow down while the way point is off to the
            # side, and before a way point in time to take its turn (people slow down to turn)
            w = float(np.clip(3.0 * err, -0.8 * max_rate, 0.8 * max_rate))
            heading = _wrap(heading + w * dt)
            corner = abs(_wrap(math.atan2(way_next[1] - way[1], way_next[0] - way[0]) - math.atan2(to[1], to[0])))
            v_corner = cruise * max(0.1, math.cos(0.5 * corner)) ** 2
            ahead = max(0.0, dist - WAYPOINT_REACHED)
            want = min(cruise * max(0.0, math.cos(err)) ** 2, math.sqrt(v_corner**2 + 2 * p.max_accel * ahead))
            speed += float(np.clip(want - speed, -p.max_accel * dt, p.max_accel * dt))
            here = here + speed * dt * np.array([math.cos(heading), math.sin(heading)])
        # where the camera looks
        if p.look == "ahead":
            if t >= glance_until:
                glance = float(np.clip(rng.normal(0.0, 0.35), -0.8, 0.8)) if rng.random() < 0.4 else 0.0
                glance_until = t + float(rng.uniform(1.0, 3.5))
            yaw_target = heading + glance
        elif p.look == "objects":
            if t >= look_until:
                look_pt = None
                if len(interest) and rng.random() < 0.75:
                    v = interest[:, :2] - here
                    d = np.linalg.norm(v, axis=-1)
                    off = np.abs(np.angle(np.exp(1j * (np.arctan2(v[:, 1], v[:, 0]) - yaw))))
                    ok = np.nonzero((d > 0.8) & (d < 6.0) & (off < MAX_LOOK_SWING))[0]
                    if len(ok):
                        look_pt = interest[ok[rng.integers(len(ok))]]
                look_until = t + float(rng.uniform(1.5, 4.0))
            if look_pt is not None:
                v = look_pt - np.array([here[0], here[1], z_cam])
                yaw_target = math.atan2(v[1], v[0])
                pitch_target = float(np.clip(math.atan2(v[2], math.hypot(v[0], v[1])), -MAX_LOOK_PITCH, 0.35))
            else:
                yaw_target = heading
        else:  # pan
            if abs(_wrap(pan_target - yaw)) < 0.01 and abs(yaw_rate) < 0.05:
                pan_pause -= dt
                if pan_pause <= 0:
                    pan_target = yaw + float(rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(45), math.pi))
                    pan_rate = float(rng.uniform(2.0 / 3.0, 1.0)) * max_rate
                    pan_pause = float(rng.uniform(0.2, 1.2))
            yaw_target = pan_target
        if p.look != "objects" and t >= pitch_until:
            pitch_target = float(np.clip(rng.normal(-0.15, 0.15), -0.5, 0.15))
            pitch_until = t + float(rng.uniform(1.5, 4.0))
        rate = pan_rate if p.look == "pan" else max_rate
        yaw, yaw_rate = _follow(yaw, yaw_rate, yaw + _wrap(yaw_target - yaw), rate, max_acc, dt)
        pitch, pitch_rate = _follow(pitch, pitch_rate, pitch_target, 0.5 * max_rate, 0.5 * max_acc, dt)
        out[k] = (here[0], here[1], speed, heading, yaw, pitch)
    return out, z_cam


def _look_points(scene: Scene) -> np.ndarray:
    """(N, 3) things worth pointing a camera at: furniture and clutter centres, table and shelf tops."""
    centres = torch.cat([pr.center for pr in scene.prims]).numpy().astype(np.float64)
    radii = torch.cat([pr.bounding_radius() for pr in scene.prims]).numpy()
    pts = [centres[(radii > 0.05) & (radii < 1.5) & (centres[:, 2] < scene.size[2] - 0.5)]]
    if scene.surfaces:
        pts.append(np.array([(s[0], s[1], s[2]) for s in scene.surfaces], dtype=np.float64))
    return np.concatenate(pts).reshape(-1, 3)


def _sines(rng: np.random.Generator, t: np.ndarray, k: int, freq: tuple[float, float],
           amp: tuple[float, float]) -> np.ndarray:
    """A sum of k sinusoids at times t (N,) with random frequencies, amplitudes and phases. Returns (N,)."""
    f, a, ph = rng.uniform(*freq, k), rng.uniform(*amp, k), rng.uniform(0.0, 2 * math.pi, k)
    return (a[:, None] * np.sin(2 * math.pi * f[:, None] * t[None] + ph[:, None])).sum(0)


def preset_trajectory(scene: Scene, n_frames: int, rng: np.random.Generator, motion: str | MotionPreset,
                      fps: float = 30.0, max_attempts: int = 30) -> torch.Tensor:
    """Camera poses (n_frames, 4, 4) float64 ``T_wc`` of a person moving a camera through ``scene`` as the
    preset ``motion`` says, sampled at ``fps`` frames per second (the path in time does not depend on fps)."""
    p = get_preset(motion)
    if n_frames < 1:
        raise CodeSLAMError(f"a trajectory needs at least one frame, got {n_frames}")
    if not (math.isfinite(fps) and fps > 0):
        raise CodeSLAMError(f"--fps must be positive, got {fps}")
    duration = (n_frames - 1) / fps
    for _attempt in range(max_attempts):
        # one stream for the deliberate motion, one for the shake: a path of the same duration is the same
        # path in time at any frame rate
        sim_rng, rng_shake = (np.random.default_rng(int(x)) for x in rng.integers(0, 2**63 - 1, 2))
        sim = _simulate(scene, sim_rng, p, duration)
        if sim is None:
            continue
        states, z_cam = sim
        t_sim = np.arange(len(states)) / SIM_HZ
        t = np.arange(n_frames) / fps
        # sample the simulation at the frame times (exact for fps dividing SIM_HZ)
        x, y, speed, heading = (np.interp(t, t_sim, states[:, i]) for i in range(4))
        yaw, pitch = np.interp(t, t_sim, states[:, 4]), np.interp(t, t_sim, states[:, 5])
        # head bob and sway at the step frequency (cadence grows with speed), as phases integrated over time
        cadence = np.where(states[:, 2] > 0.05, 1.3 + 0.5 * states[:, 2], 0.0)
        phase = np.interp(t, t_sim, 2 * math.pi * np.cumsum(cadence) / SIM_HZ)
        gait = np.clip(speed / 1.2, 0.0, 1.25)
        bob_a = float(rng_shake.uniform(*p.bob)) if p.bob[1] > 0 else 0.0
        z = z_cam + _sines(rng_shake, t, 2, (0.05, 0.2), (0.005, 0.02)) + bob_a * gait * np.sin(phase)
        sway = 0.6 * bob_a * gait * np.sin(0.5 * phase)
        x = x - sway * np.sin(heading) + _sines(rng_shake, t, 2, (0.5, 4.0), p.shake_m)
        y = y + sway * np.cos(heading) + _sines(rng_shake, t, 2, (0.5, 4.0), p.shake_m)
        z = z + _sines(rng_shake, t, 2, (0.5, 4.0), p.shake_m)
        if p.look == "pan":  # a standing person's body sways slowly by a few centimetres
            x = x + _sines(rng_shake, t, 2, (0.05, 0.3), (0.005, 0.015))
            y = y + _sines(rng_shake, t, 2, (0.05, 0.3), (0.005, 0.015))
        pos = np.stack([x, y, z], -1)
        if not (scene.free_distance(torch.from_numpy(pos).float()).numpy() >= p.clearance).all():
            continue
        if p.speed[1] > 0 and not _body_free(scene, pos[:, :2], float(z_cam), 0.7 * p.body_radius, 0.0).all():
            continue
        pitch = np.clip(pitch, -MAX_LOOK_PITCH, MAX_LOOK_PITCH)
        look = _unit(np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], -1))
        roll = _sines(rng_shake, t, 2, (0.05, 0.3), (0.01, 0.04))
        T = look_at(torch.from_numpy(pos), torch.from_numpy(pos + look), torch.from_numpy(roll))
        # rotation shake about the camera axes (x: nod, y: yaw, z: roll), plus the walker's nod at the cadence
        nod = math.radians(float(rng_shake.uniform(0.3, 0.8))) * gait * np.sin(phase + 0.5) if p.bob[1] > 0 else 0.0
        shake = [np.radians(_sines(rng_shake, t, 3, (1.0, 7.0), p.shake_deg)) for _ in range(3)]
        shake[0] = shake[0] + nod
        T[:, :3, :3] = matmul3(T[:, :3, :3], _small_rotation(*(torch.from_numpy(a) for a in shake)))
        return T
    raise CodeSLAMError(f"could not fit a {p.name!r} camera path into the synthetic room; try another seed "
                        f"or a larger room")


#: Data version 4: the share of rooms walked through as each preset does (the presets' own rooms), the length of
#: each room's path (seconds) and the rate it is sampled at before views are drawn from it.
PATH_VIEW_SHARES = {"handheld": 0.3, "walk": 0.3, "corridor": 0.2, "fast-turn": 0.2}
PATH_VIEW_SECONDS = 30.0
PATH_VIEW_FPS = 10.0


def preset_path_views(seed: int, n: int, rng: np.random.Generator) -> tuple[Scene, torch.Tensor]:
    """Training data version 4: a room and ``n`` views (n, 4, 4) float64 ``T_wc`` of it as people move a camera.
    A preset is drawn (:data:`PATH_VIEW_SHARES`), its room built for ``seed`` (:meth:`MotionPreset.scene`) and its
    path over :data:`PATH_VIEW_SECONDS` simulated; the views are frames of that path at distinct random times
    (:data:`PATH_VIEW_FPS`), in time order. A room the drawn preset fits no path into is passed to the next
    preset (in :data:`PATH_VIEW_SHARES`' order) with a room of its own."""
    names = list(PATH_VIEW_SHARES)
    first = int(rng.choice(len(names), p=np.array(list(PATH_VIEW_SHARES.values()))))
    frames = int(round(PATH_VIEW_SECONDS * PATH_VIEW_FPS)) + 1
    for k in range(len(names)):
        preset = PRESETS[names[(first + k) % len(names)]]
        scene = preset.scene(seed)
        try:
            T = preset_trajectory(scene, frames, rng, preset, fps=PATH_VIEW_FPS)
        except CodeSLAMError:  # no path fits this room: another preset's
            continue
        return scene, T[torch.from_numpy(np.sort(rng.choice(frames, size=n, replace=n > frames)))]
    raise CodeSLAMError(f"no motion preset fits a camera path into the rooms of seed {seed}")


__all__ = ["MotionPreset", "PATH_VIEW_SHARES", "PRESETS", "SIM_HZ", "get_preset", "preset_path_views",
           "preset_trajectory"]
