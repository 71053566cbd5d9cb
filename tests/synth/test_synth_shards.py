"""Training shards: round trip through read_shard, resumability, independence from the worker count."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from codeslam.errors import CodeSLAMError, DatasetError
from codeslam.geometry.camera import canonical_camera
from codeslam.synth.render import RenderConfig, render
from codeslam.synth.scene import build_scene
from codeslam.synth.shards import ShardSpec, _scene_seed, read_shard, render_shard, shard_path, write_shards


def _spec(**kw) -> ShardSpec:
    args = dict(views=10, camera=canonical_camera(32, 24), seed=7, views_per_scene=3, shard_size=4)
    args.update(kw)
    return ShardSpec(**args)


def test_shards_round_trip_through_read_shard(tmp_path: Path):
    spec = _spec()
    summary = write_shards(spec, tmp_path)
    assert summary["shards"] == 3 and summary["written"] == 3
    sizes = []
    for i in range(3):
        image, depth, camera = read_shard(shard_path(tmp_path, i))
        assert image.dtype == torch.uint8 and depth.dtype == torch.float32
        assert image.shape[1:] == (3, 24, 32) and depth.shape[1:] == (24, 32)
        assert camera == spec.camera
        assert float(depth.min()) > 0.05 and float(depth.max()) < 11.0
        assert float(image.float().std()) > 5.0  # rooms, not flat colour
        sizes.append(image.shape[0])
    assert sizes == [4, 4, 2]
    from safetensors import safe_open

    with safe_open(str(shard_path(tmp_path, 0)), "pt") as f:
        meta = f.metadata()
        raw = f.get_tensor("depth")
        poses = f.get_tensor("T_wc")
    assert meta["format"] == "codeslam-shard-v1" and meta["depth_factor"] == "5000" and meta["seed"] == "7"
    assert json.loads(meta["camera"]) == spec.camera.to_dict()
    assert raw.dtype == torch.uint16
    # the first view re-rendered from its stored pose gives the stored depth (1/5000 m quantisation)
    scene = build_scene(_scene_seed(7, 0, 0))
    _, d = render(scene, spec.camera, poses[0], RenderConfig())
    _, depth, _ = read_shard(shard_path(tmp_path, 0))
    assert torch.allclose(depth[0], d, atol=1.01 / 5000)


def test_resume_skips_complete_shards_and_redoes_missing_ones(tmp_path: Path):
    spec = _spec(views=6)
    write_shards(spec, tmp_path)
    before = {i: shard_path(tmp_path, i).read_bytes() for i in range(2)}
    shard_path(tmp_path, 1).unlink()
    summary = write_shards(spec, tmp_path)
    assert summary["skipped"] == 1 and summary["written"] == 1
    assert shard_path(tmp_path, 1).read_bytes() == before[1]
    # other settings do not count as complete: the shard is redone
    assert write_shards(_spec(views=6, seed=8), tmp_path)["written"] == 2


def test_shard_content_depends_only_on_seed_and_index():
    a = render_shard(_spec(views=8), 1)
    b = render_shard(_spec(views=12), 1)  # more shards in total: shard 1 unchanged
    c = render_shard(_spec(views=8, seed=8), 1)
    assert torch.equal(a["image"], b["image"]) and torch.equal(a["depth"], b["depth"])
    assert not torch.equal(a["image"], c["image"])


def test_two_workers_write_the_same_bytes(tmp_path: Path):
    spec = _spec(views=4, shard_size=2, views_per_scene=2)
    write_shards(spec, tmp_path / "one", workers=1)
    write_shards(spec, tmp_path / "two", workers=2)
    for i in range(2):
        assert shard_path(tmp_path / "one", i).read_bytes() == shard_path(tmp_path / "two", i).read_bytes()


def test_read_shard_rejects_bad_files(tmp_path: Path):
    with pytest.raises(DatasetError):
        read_shard(tmp_path / "missing.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    with pytest.raises(DatasetError):
        read_shard(bad)
    from safetensors.torch import save_file

    other = tmp_path / "other.safetensors"
    save_file({"image": torch.zeros(1, 3, 4, 4, dtype=torch.uint8)}, str(other), metadata={"format": "x"})
    with pytest.raises(DatasetError):
        read_shard(other)


def test_version_2_shards_are_marked_and_see_farther(tmp_path):
    from safetensors import safe_open

    from codeslam.synth.shards import V2_MAX_DEPTH

    cam = canonical_camera(32, 24)
    depths = {}
    for version in (1, 2):
        render = RenderConfig(max_depth=V2_MAX_DEPTH if version == 2 else 10.0)
        spec = ShardSpec(views=32, camera=cam, seed=5, views_per_scene=8, shard_size=32, render=render,
                         version=version)
        write_shards(spec, tmp_path / f"v{version}")
        _, depth, _ = read_shard(tmp_path / f"v{version}" / "shard_00000.safetensors")
        depths[version] = float(depth[depth > 0].median())
        with safe_open(str(tmp_path / f"v{version}" / "shard_00000.safetensors"), "pt") as f:
            meta = f.metadata()
        assert ("data_version" in meta) == (version == 2)  # version 1 shards keep their old metadata
    assert depths[2] > 1.3 * depths[1]  # larger rooms seen along their length
    with pytest.raises(CodeSLAMError, match="data-version"):
        ShardSpec(views=1, camera=cam, version=5)


def test_version_4_shards_hold_views_along_the_presets_paths(tmp_path):
    """Data version 4: marked, reproducible, views at a person's height (the presets' 1.1-1.8 m), rendered to the
    longer depth range of versions 2 and up."""
    from safetensors import safe_open

    from codeslam.synth.shards import V2_MAX_DEPTH

    cam = canonical_camera(32, 24)
    spec = ShardSpec(views=24, camera=cam, seed=5, views_per_scene=8, shard_size=24,
                     render=RenderConfig(max_depth=V2_MAX_DEPTH), version=4)
    for out in ("a", "b"):
        write_shards(spec, tmp_path / out)
    a, b = (tmp_path / out / "shard_00000.safetensors" for out in ("a", "b"))
    assert a.read_bytes() == b.read_bytes()
    _, depth, _ = read_shard(a)
    with safe_open(str(a), "pt") as f:
        assert f.metadata()["data_version"] == "4"
        T = f.get_tensor("T_wc")
    assert T.shape == (24, 4, 4) and bool(((T[:, 2, 3] > 0.9) & (T[:, 2, 3] < 2.0)).all())
    assert float((depth > 0).float().mean()) > 0.5
