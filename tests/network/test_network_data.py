"""Training data: shard and dataset-folder reading at the canonical camera, split, order, augmentation."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera, canonical_camera
from codeslam.geometry.resample import resample_depth
from codeslam.network.config import TrainConfig
from codeslam.network.data import (
    DataOrder,
    FrameStore,
    augment_batch,
    depth_metres,
    load_training_data,
    quantise_depth,
    split_train_val,
)


def test_shards_at_the_canonical_camera_load_unchanged(tiny_shards, synthetic_frames):
    store = load_training_data([tiny_shards], canonical_camera(32, 32))
    assert len(store) == 32 and [g[1:] for g in store.groups] == [(0, 16), (16, 32)]
    images, depth = synthetic_frames(16, 32, 32, seed=1)
    assert torch.equal(store.images[16:], images)
    assert store.images.dtype == torch.uint8 and store.depth.dtype == torch.uint16
    torch.testing.assert_close(depth_metres(store.depth[16:]), depth, atol=1.01e-4, rtol=0)  # half a 1/5000 m step


def test_shard_of_another_camera_is_resampled(tmp_path, synthetic_frames, write_shard):
    src = PinholeCamera(fx=40.0, fy=40.0, cx=31.5, cy=23.5, width=64, height=48)  # wider than 60 degrees
    images, depth = synthetic_frames(3, 64, 48)
    write_shard(tmp_path / "shard_00000.safetensors", images, depth, src)
    dst = canonical_camera(32, 32)
    store = load_training_data([tmp_path], dst)
    assert store.images.shape == (3, 3, 32, 32) and store.depth.shape == (3, 32, 32)
    expected = resample_depth(quantise_depth(depth).float()[:, None] / 5000.0, src, dst)[:, 0]
    torch.testing.assert_close(depth_metres(store.depth), expected, atol=1e-3, rtol=0)


def test_dataset_folder_is_read_and_resampled(tmp_path):
    root = tmp_path / "seq"
    (root / "images").mkdir(parents=True)
    (root / "depth").mkdir()
    (root / "camera.yaml").write_text("fx: 35.0\nfy: 35.0\ncx: 31.5\ncy: 23.5\n")  # covers 60 deg
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(root / "images" / f"{i:04d}.png")
        np.save(root / "depth" / f"{i:04d}.npy", np.full((48, 64), 1.0 + i, dtype=np.float32))
    store = load_training_data([root], canonical_camera(32, 32), workers=2)
    assert store.images.shape == (3, 3, 32, 32)
    for i in range(3):  # constant depth survives resampling wherever the canonical ray sees the source image
        d = depth_metres(store.depth[i])
        assert (d > 0).all() and torch.allclose(d[d > 0], torch.tensor(1.0 + i))


def test_bad_sources_are_dataset_errors(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        load_training_data([tmp_path / "nope"], canonical_camera(32, 32))
    (tmp_path / "shard_00000.safetensors").write_bytes(b"not a shard at all")
    with pytest.raises(DatasetError, match="cannot read shard"):
        load_training_data([tmp_path], canonical_camera(32, 32))


def test_quantise_depth():
    d = torch.tensor([0.0, 1.0, 13.0, 14.0, float("nan"), -1.0, float("inf")])
    q = quantise_depth(d)
    assert q.dtype == torch.uint16
    assert q.to(torch.int32).tolist() == [0, 5000, 65000, 0, 0, 0, 0]


def _store(group_sizes: list[int]) -> FrameStore:
    n = sum(group_sizes)
    starts = np.cumsum([0, *group_sizes])
    groups = [(f"g{i}", int(starts[i]), int(starts[i + 1])) for i in range(len(group_sizes))]
    return FrameStore(torch.zeros(n, 3, 2, 2, dtype=torch.uint8), torch.zeros(n, 2, 2, dtype=torch.uint16), groups)


def test_split_holds_out_the_end_of_every_group():
    train, val = split_train_val(_store([20, 10]), 0.1, 100)
    assert val.tolist() == [18, 19, 29]
    assert sorted(train.tolist() + val.tolist()) == list(range(30))
    _, val = split_train_val(_store([1000]), 0.1, 7)
    assert len(val) == 7 and val.min() >= 900
    train, val = split_train_val(_store([10]), 0.0, 7)
    assert len(train) == 10 and len(val) == 0


def test_data_order_is_deterministic_and_sharded():
    idx = torch.arange(100, 150)
    a, b = DataOrder(idx, 4, seed=3), DataOrder(idx, 4, seed=3)
    assert a.steps_per_epoch == 12
    epoch0 = torch.cat([a.batch(s) for s in range(12)])
    assert len(set(epoch0.tolist())) == 48 and set(epoch0.tolist()) <= set(idx.tolist())
    assert torch.equal(b.batch(13), a.batch(13)) and torch.equal(b.batch(5), a.batch(5))  # any order of calls
    assert not torch.equal(a.batch(0), a.batch(12))  # a new permutation every epoch
    ranks = [DataOrder(idx, 4, seed=3, rank=r, world=2) for r in range(2)]
    seen = [set(torch.cat([o.batch(s) for s in range(o.steps_per_epoch)]).tolist()) for o in ranks]
    assert not seen[0] & seen[1] and len(seen[0]) == len(seen[1]) == 24
    with pytest.raises(DatasetError, match="training frames"):
        DataOrder(torch.arange(3), 4, seed=0)


def test_augmentation_flips_image_and_depth_together():
    images = torch.zeros(2, 3, 4, 8, dtype=torch.uint8)
    images[..., :4] = 200  # bright left half
    depth = torch.full((2, 4, 8), 20000, dtype=torch.uint16)
    depth[..., :4] = 5000  # near left half
    cfg = TrainConfig(flip_prob=1.0, brightness=0, contrast=0, gamma=0, noise_std=0)
    x, d = augment_batch(images, depth, cfg, 1, torch.Generator().manual_seed(0))
    assert x.shape == (2, 1, 4, 8) and d.shape == (2, 1, 4, 8)
    assert torch.allclose(x[..., 4:], torch.tensor(200 / 255)) and torch.all(x[..., :4] == 0)
    assert torch.all(d[..., 4:] == 1.0) and torch.all(d[..., :4] == 4.0)
    jitter = TrainConfig()
    x1, _ = augment_batch(images, depth, jitter, 3, torch.Generator().manual_seed(5))
    x2, _ = augment_batch(images, depth, jitter, 3, torch.Generator().manual_seed(5))
    assert torch.equal(x1, x2) and x1.shape == (2, 3, 4, 8)  # reproducible from the generator
    assert 0 <= x1.min() and x1.max() <= 1


def test_weighted_sources_and_their_share_of_an_epoch(tmp_path):
    from pathlib import Path

    from codeslam.network.data import FrameStore, parse_source, split_train_val

    assert parse_source("/data/real:8") == (Path("/data/real"), 8.0)
    assert parse_source("/data/real") == (Path("/data/real"), 1.0)
    odd = tmp_path / "run:3"
    odd.mkdir()
    assert parse_source(str(odd)) == (odd, 1.0)  # an existing folder is taken as named
    with pytest.raises(DatasetError, match="positive"):
        parse_source("/data/real:0")
    store = FrameStore(torch.zeros(30, 3, 4, 4, dtype=torch.uint8), torch.zeros(30, 4, 4, dtype=torch.uint16),
                       [("synth", 0, 20), ("real", 20, 30)], [1.0, 3.0])
    train, val = split_train_val(store, 0.1, 100)
    assert len(val) == 3  # the last 10% of each group
    real = train[train >= 20]
    assert len(real) == 27 and set(real.tolist()) == set(range(20, 29))  # 9 training frames, 3 times each
    store.group_weights = [1.0, 0.5]
    train, _ = split_train_val(store, 0.1, 100)
    assert int((train >= 20).sum()) == 4  # round(0.5 * 9) of them
