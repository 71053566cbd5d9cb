"""The ray caster: exact depth, culling equal to brute force, surface consistency, sensor effects."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from codeslam.geometry.camera import canonical_camera
from codeslam.synth import textures as tx
from codeslam.synth.primitives import BOX, CYLINDER, ELLIPSOID, RAY_FUNCS, SDF_FUNCS, Prims, ray_room
from codeslam.synth.render import RenderConfig, render, tonemap, trace
from codeslam.synth.scene import Scene, build_scene
from codeslam.synth.trajectory import look_at


def _prims(rows) -> Prims:
    if not rows:
        return Prims.empty()
    a = torch.tensor(rows, dtype=torch.float64)
    return Prims(a[:, 0:3].float(), a[:, 3:6].float(), a[:, 6].float(), a[:, 7].long())


def _simple_scene(boxes=(), cylinders=(), ellipsoids=(), size=(4.0, 5.0, 3.0)) -> Scene:
    mats = torch.from_numpy(np.stack([tx.material(tx.PAINT, (0.6, 0.5, 0.4), scale=3.0),
                                      tx.material(tx.CHECKER, (0.9, 0.9, 0.9), (0.1, 0.2, 0.3), scale=5.0)]))
    return Scene(
        room_lo=torch.zeros(3), room_hi=torch.tensor(size),
        room_material=torch.tensor([0, 0, 0, 0, 1, 0]),
        prims=(_prims(list(boxes)), _prims(list(cylinders)), _prims(list(ellipsoids))),
        materials=mats, light_pos=torch.tensor([[2.0, 2.5, 2.8]]), light_rgb=torch.tensor([[2.0, 2.0, 2.0]]),
        ambient=torch.tensor([0.3, 0.3, 0.3]),
    )


def test_depth_of_a_fronto_parallel_wall_is_exact():
    scene = _simple_scene(size=(10.0, 5.0, 10.0))
    cam = canonical_camera(32, 24)
    # at (5, 1, 5) looking along +y at the wall y = 5 (the side walls are out of view): every z-depth is 4 m
    T = look_at(torch.tensor([5.0, 1.0, 5.0]), torch.tensor([5.0, 5.0, 5.0]))
    _, depth = render(scene, cam, T)
    assert torch.allclose(depth, torch.full_like(depth, 4.0), atol=1e-5)


def test_depth_of_a_box_face_and_a_sphere_are_exact():
    scene = _simple_scene(boxes=[(2.0, 3.0, 1.5, 0.5, 0.25, 0.5, 0.0, 0)],
                          ellipsoids=[(3.2, 3.0, 1.5, 0.3, 0.3, 0.3, 0.0, 0)])
    cam = canonical_camera(64, 48)
    T = look_at(torch.tensor([2.0, 1.0, 1.5]), torch.tensor([2.0, 5.0, 1.5]))
    _, depth = render(scene, cam, T)
    # the image centre sees the box face y = 2.75, 1.75 m ahead
    assert float(depth[23:25, 31:33].mean()) == pytest.approx(1.75, abs=1e-5)
    # every pixel on the sphere: its camera-frame point lies on the sphere's surface
    K = cam.K(torch.float64)
    v, u = torch.meshgrid(torch.arange(48.0), torch.arange(64.0), indexing="ij")
    z = depth.double()
    xyz_c = torch.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
    xyz_w = xyz_c @ T[:3, :3].T + T[:3, 3]
    r = (xyz_w - torch.tensor([3.2, 3.0, 1.5], dtype=torch.float64)).norm(dim=-1)
    on_sphere = r < 0.35
    assert on_sphere.sum() > 20
    assert torch.allclose(r[on_sphere], torch.full_like(r[on_sphere], 0.3), atol=1e-4)


def _brute_force(scene: Scene, o: torch.Tensor, d: torch.Tensor):
    """Nearest hit over all primitives without culling. o (R, 3), d (R, 3)."""
    t, _ = ray_room(o, d, scene.room_lo, scene.room_hi)
    for k, pr in enumerate(scene.prims):
        if len(pr):
            tk = RAY_FUNCS[k](o[:, None, :], d[:, None, :], pr.params(), 1e-4).amin(-1)
            t = torch.minimum(t, tk)
    return t


@pytest.mark.parametrize("seed", [0, 5])
def test_culled_trace_equals_brute_force(seed):
    scene = build_scene(seed)
    rng = np.random.default_rng(seed)
    W, D, H = scene.size
    # groups of rays from free points, fanning out in random directions
    origins = []
    while len(origins) < 24:
        p = rng.uniform([0.3, 0.3, 0.3], [W - 0.3, D - 0.3, H - 0.3])
        if float(scene.free_distance(torch.tensor(p[None], dtype=torch.float32))[0]) > 0.1:
            origins.append(p)
    o = torch.tensor(np.array(origins), dtype=torch.float32)  # (B, 3)
    axis = torch.tensor(rng.normal(size=(24, 1, 3)), dtype=torch.float32)
    d = axis + 0.2 * torch.tensor(rng.normal(size=(24, 40, 3)), dtype=torch.float32)  # (B, G, 3)
    t, _, _ = trace(scene, o, d)
    t_ref = _brute_force(scene, o[:, None, :].expand_as(d).reshape(-1, 3), d.reshape(-1, 3)).reshape(24, 40)
    # equal up to float round-off (the renderer treats axis-aligned primitives without the rotation); a
    # primitive wrongly culled would show as a difference of centimetres or more
    assert float((t - t_ref).abs().max()) < 1e-5


@pytest.mark.parametrize("kind", [BOX, CYLINDER, ELLIPSOID])
def test_ray_hits_lie_on_the_surface_and_yaw_is_respected(kind):
    rng = np.random.default_rng(kind)
    pr = _prims([(0.0, 0.0, 0.0, 0.4, 0.2, 0.3, 0.7, 0)])
    o = torch.tensor(rng.normal(size=(500, 3)) * 0.2 + [3.0, 0.0, 0.0], dtype=torch.float32)
    d = torch.tensor(rng.normal(size=(500, 3)) * 0.08 + [-1.0, 0.0, 0.0], dtype=torch.float32)
    t = RAY_FUNCS[kind](o[:, None, :], d[:, None, :], pr.params(), 1e-4)[:, 0]
    hit = torch.isfinite(t)
    assert hit.sum() > 100
    p = o + t[:, None] * d
    sdf = SDF_FUNCS[kind](p[hit][:, None, :], pr.params())[:, 0]
    assert sdf.abs().max() < 2e-3
    # the axis-aligned code path agrees with the rotated one for a quarter-turn yaw
    pq = _prims([(0.0, 0.0, 0.0, 0.4, 0.2, 0.3, math.pi / 2, 0)])
    t_rot = RAY_FUNCS[kind](o[:, None, :], d[:, None, :], pq.params(), 1e-4)[:, 0]
    t_al = RAY_FUNCS[kind](o[:, None, :], d[:, None, :], pq.aligned_params(), 1e-4, True)[:, 0]
    assert torch.equal(torch.isfinite(t_rot), torch.isfinite(t_al))
    fin = torch.isfinite(t_rot)
    # equal up to round-off, which is amplified only for grazing rays (where t is ill-conditioned)
    assert float((t_rot[fin] - t_al[fin]).abs().median()) < 1e-6
    assert torch.allclose(t_rot[fin], t_al[fin], atol=1e-3)


def test_supersampling_keeps_centre_depth_and_sensor_effects_are_seeded():
    scene = build_scene(2)
    cam = canonical_camera(24, 16)
    W, D, H = scene.size
    T = look_at(torch.tensor([W / 2, 0.4, 1.5]), torch.tensor([W / 2, D, 1.0]))
    img1, d1 = render(scene, cam, T)
    img3, d3 = render(scene, cam, T, RenderConfig(supersample=3))
    img2, d2 = render(scene, cam, T, RenderConfig(supersample=2))
    assert torch.equal(d1, d3) and torch.equal(d1, d2)
    assert not torch.equal(img1, img3)
    assert (img1 - img3).abs().mean() < 0.1  # anti-aliasing changes edges and fine texture only
    cfg = RenderConfig(noise_std=0.02, blur_sigma=0.8)
    a, _ = render(scene, cam, T, cfg, noise_seed=4)
    b, _ = render(scene, cam, T, cfg, noise_seed=4)
    c, _ = render(scene, cam, T, cfg, noise_seed=5)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_tonemap_is_continuous_monotone_and_bounded():
    x = torch.linspace(0.0, 20.0, 20001)
    y = tonemap(x)
    assert torch.all(y[1:] >= y[:-1])
    assert float(y.max()) <= 1.0 and float(tonemap(torch.tensor(2.0))) < 1.0
    assert torch.equal(y[x < 0.6], x[x < 0.6])
    dy = (y[1:] - y[:-1]) / (x[1] - x[0])
    assert float((dy[1:] - dy[:-1]).abs().max()) < 1e-2  # no kink at the knee


def test_colour_is_a_function_of_the_surface_point_only():
    """The same world points get the same albedo whatever the ray that found them."""
    scene = build_scene(4)
    W, D, H = scene.size
    o1 = torch.tensor([[W / 2, D / 2, 1.2]])
    d = torch.tensor(np.random.default_rng(0).normal(size=(1, 64, 3)), dtype=torch.float32)
    t, kind, idx = trace(scene, o1, d)
    p = o1[:, None, :] + t[..., None] * d
    # a second camera, elsewhere, looking at exactly the same points
    o2 = torch.tensor([[W / 2 + 0.05, D / 2 - 0.04, 1.25]])
    d2 = p - o2[:, None, :]
    t2, kind2, idx2 = trace(scene, o2, d2)
    seen = (t2 - 1.0).abs() < 1e-4  # not occluded from the second centre
    assert seen.sum() > 10
    from codeslam.synth.render import surface

    def col(pts, k, i):
        pl, nl, _, m = surface(scene, pts.reshape(-1, 3), k.reshape(-1), i.reshape(-1))
        return tx.albedo(pl, nl, scene.materials[m])

    c1 = col(p, kind, idx)[seen.reshape(-1)]
    p2 = o2[:, None, :] + t2[..., None] * d2
    c2 = col(p2, kind2, idx2)[seen.reshape(-1)]
    assert torch.allclose(c1, c2, atol=2e-3)
