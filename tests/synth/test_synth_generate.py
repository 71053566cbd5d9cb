"""Sequences in the TUM layout: the reader reads them, GT depth and poses are consistent, seeds repeat."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import torch

from codeslam.data.tum import TumSequence
from codeslam.geometry.camera import canonical_camera
from codeslam.synth.generate import generate_sequences, scene_seed
from codeslam.synth.render import RenderConfig
from codeslam.synth.scene import build_scene

FRAMES = 16


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    # anti-aliased like the CLI's sequences: at 64x48 aliased edges alone would dominate the warp error
    generate_sequences(out, scenes=2, frames=FRAMES, seed=3, camera=canonical_camera(64, 48),
                       config=RenderConfig(supersample=2))
    return out


def _warp_independent(img_src: np.ndarray, depth_dst: np.ndarray, K: np.ndarray, T_src_dst: np.ndarray):
    """Sample img_src (H, W, 3) at the projections of frame dst's pixels (unproject with depth_dst, move by
    T_src_dst, project, bilinear). Written here with numpy, independently of the package's geometry.
    Returns the warped image (H, W, 3) and the mask of pixels that land inside img_src with valid depth."""
    H, W = depth_dst.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = depth_dst.astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    P = np.stack([x, y, z], -1) @ T_src_dst[:3, :3].T + T_src_dst[:3, 3]
    zs = P[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        us = K[0, 0] * P[..., 0] / zs + K[0, 2]
        vs = K[1, 1] * P[..., 1] / zs + K[1, 2]
    ok = (z > 0) & (zs > 0.05) & (us >= 0) & (us <= W - 1) & (vs >= 0) & (vs <= H - 1)
    us, vs = np.where(ok, us, 0), np.where(ok, vs, 0)
    u0, v0 = np.clip(np.floor(us).astype(int), 0, W - 2), np.clip(np.floor(vs).astype(int), 0, H - 2)
    fu, fv = (us - u0)[..., None], (vs - v0)[..., None]
    out = (img_src[v0, u0] * (1 - fu) * (1 - fv) + img_src[v0, u0 + 1] * fu * (1 - fv)
           + img_src[v0 + 1, u0] * (1 - fu) * fv + img_src[v0 + 1, u0 + 1] * fu * fv)
    return out, ok


def test_reader_reads_sequences(seq_dir: Path):
    for name in ("scene_000", "scene_001"):
        seq = TumSequence(seq_dir / name)
        assert len(seq) == FRAMES
        assert seq.has_depth and seq.has_pose
        assert (seq.camera.width, seq.camera.height) == (64, 48)
        cam = canonical_camera(64, 48)
        assert seq.camera.fx == pytest.approx(cam.fx) and seq.camera.cx == pytest.approx(cam.cx)
        f = seq[3]
        assert f.image.shape == (3, 48, 64) and f.depth.shape == (48, 64)
        assert torch.isfinite(f.pose).all()
        assert float(f.image.std()) > 0.03  # not a flat colour


def test_warp_with_gt_depth_and_poses_cuts_photometric_error(seq_dir: Path):
    for name in ("scene_000", "scene_001"):
        seq = TumSequence(seq_dir / name)
        K = seq.camera.K(torch.float64).numpy()
        ratios = []
        for i in range(0, FRAMES - 5, 3):
            a, b = seq[i], seq[i + 5]
            img_a = a.image.permute(1, 2, 0).numpy().astype(np.float64)
            img_b = b.image.permute(1, 2, 0).numpy().astype(np.float64)
            T_a_b = np.linalg.inv(a.pose.numpy()) @ b.pose.numpy()
            warped, ok = _warp_independent(img_a, b.depth.numpy(), K, T_a_b)
            assert ok.mean() > 0.3
            err_warp = np.abs(warped - img_b).mean(-1)[ok].mean()
            err_none = np.abs(img_a - img_b).mean(-1)[ok].mean()
            ratios.append(err_warp / err_none)
        assert np.mean(ratios) < 0.5, ratios
        assert max(ratios) < 0.7, ratios


def test_depth_within_room(seq_dir: Path):
    """Every depth, unprojected with the ground-truth pose, lands on or inside the room's box."""
    room = build_scene(scene_seed(3, 0))
    seq = TumSequence(seq_dir / "scene_000")
    K = seq.camera.K(torch.float64)
    v, u = torch.meshgrid(torch.arange(48.0, dtype=torch.float64), torch.arange(64.0, dtype=torch.float64),
                          indexing="ij")
    for i in (0, FRAMES // 2, FRAMES - 1):
        f = seq[i]
        z = f.depth.double()
        assert bool((z > 0).all())
        xyz_c = torch.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
        xyz_w = xyz_c @ f.pose[:3, :3].T + f.pose[:3, 3]
        tol = 1e-3  # 1/5000 m depth quantisation, float32 poses
        assert bool((xyz_w >= room.room_lo.double() - tol).all())
        assert bool((xyz_w <= room.room_hi.double() + tol).all())
        # and the camera itself is inside the room, clear of every object
        assert float(room.free_distance(f.pose[:3, 3][None].float())[0]) > 0.15


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path):
    cam = canonical_camera(32, 24)
    generate_sequences(tmp_path / "a", scenes=1, frames=3, seed=11, camera=cam)
    generate_sequences(tmp_path / "b", scenes=1, frames=3, seed=11, camera=cam)
    generate_sequences(tmp_path / "c", scenes=1, frames=3, seed=12, camera=cam)
    da, db, dc = _digest(tmp_path / "a"), _digest(tmp_path / "b"), _digest(tmp_path / "c")
    assert da == db
    assert len(da) == 3 * 2 + 4
    differing = [k for k in da if da[k] != dc.get(k)]
    assert any(k.startswith("scene_000/rgb/") for k in differing)
    assert "scene_000/groundtruth.txt" in differing


def test_progress_counts_frames_over_all_sequences(tmp_path):
    """The progress callback counts frames (so a bar can show frames per second), batch by batch, to the total."""
    calls = []
    generate_sequences(tmp_path, scenes=2, frames=10, seed=1, camera=canonical_camera(16, 12),
                       progress=lambda done, total: calls.append((done, total)))
    from codeslam.synth.generate import FRAME_BATCH

    per_scene = [min(n, 10) for n in range(FRAME_BATCH, 10 + FRAME_BATCH, FRAME_BATCH)]  # after each batch
    assert calls == [(d, 20) for d in per_scene] + [(10 + d, 20) for d in per_scene]
