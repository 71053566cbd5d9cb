"""Fixtures for the network tests: a tiny architecture and tiny generator-format shards."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from codeslam.geometry.camera import canonical_camera
from codeslam.network.config import NetworkConfig
from codeslam.synth.shards import SHARD_FORMAT

TINY = dict(
    code_size=8, width=32, height=32, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
    full_res_channels=4, bottleneck_channels=4, fc_units=16,
)

TINY_YAML = """\
network:
  code_size: 8
  width: 32
  height: 32
  image_channels: [4, 8, 8, 8]
  depth_channels: [4, 8, 8, 8]
  full_res_channels: 4
  bottleneck_channels: 4
  fc_units: 16
train:
  batch_size: 4
  lr: 0.001
  log_every: 2
  val_every: 3
  checkpoint_every: 100
  kl_warmup_steps: 4
"""


def tiny_config(**overrides) -> NetworkConfig:
    return NetworkConfig(**{**TINY, **overrides})


def synthetic_frames(n: int, width: int, height: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """n frames of a tilted plane with a box in front, shaded by depth (so depth is predictable from the image)
    and 5% depth holes -> (n, 3, H, W) uint8, (n, H, W) float metres."""
    g = torch.Generator().manual_seed(seed)
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float32), torch.arange(width, dtype=torch.float32),
                          indexing="ij")
    images, depths = [], []
    for _ in range(n):
        a, b, c = torch.rand(3, generator=g)
        depth = 1.5 + 2.5 * a + (u / width - 0.5) * (b - 0.5) * 2 + (v / height - 0.5) * (c - 0.5) * 2
        x0 = int(torch.randint(0, width // 2, (1,), generator=g))
        y0 = int(torch.randint(0, height // 2, (1,), generator=g))
        depth[y0 : y0 + height // 4, x0 : x0 + width // 4] = 0.8 + float(torch.rand(1, generator=g))
        tex = 0.5 + 0.3 * torch.sin(u * 0.3 * (1 + a)) * torch.cos(v * 0.2)
        shade = (1.0 / depth).clamp(0, 1)
        img = torch.stack([tex * shade, shade, 0.5 * tex + 0.3 * shade]).clamp(0, 1)
        depth[torch.rand(height, width, generator=g) < 0.05] = 0.0
        images.append((img * 255).round().to(torch.uint8))
        depths.append(depth)
    return torch.stack(images), torch.stack(depths)


def write_shard(path: Path, images: torch.Tensor, depth_m: torch.Tensor, camera) -> None:
    """A shard in the generator's format: uint8 RGB, uint16 depth in 1/5000 m, camera JSON metadata."""
    depth = (depth_m * 5000).round().to(torch.int32).to(torch.uint16)
    save_file({"image": images.contiguous(), "depth": depth.contiguous()}, str(path),
              metadata={"format": SHARD_FORMAT, "camera": json.dumps(camera.to_dict()), "depth_factor": "5000"})


@pytest.fixture(autouse=True)
def _one_thread():
    """Tiny networks gain nothing from threads, and OpenMP threads on a busy 2-core machine can make their
    small ops ~50x slower (measured); one thread also matches the subprocesses' --threads 1."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session", name="tiny_config")
def tiny_config_fixture():
    """A factory of tiny network configs: ``tiny_config(linear_decoder=False)``."""
    return tiny_config


@pytest.fixture(scope="session", name="synthetic_frames")
def synthetic_frames_fixture():
    return synthetic_frames


@pytest.fixture(scope="session", name="write_shard")
def write_shard_fixture():
    return write_shard


@pytest.fixture(scope="session")
def tiny_shards(tmp_path_factory) -> Path:
    """Two shards of 16 frames each at the tiny network's canonical camera (32x32, 60 degrees)."""
    folder = tmp_path_factory.mktemp("shards")
    cam = canonical_camera(32, 32)
    for s in range(2):
        images, depth = synthetic_frames(16, 32, 32, seed=s)
        write_shard(folder / f"shard_{s:05d}.safetensors", images, depth, cam)
    return folder


@pytest.fixture(scope="session")
def tiny_yaml(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(TINY_YAML)
    return path
