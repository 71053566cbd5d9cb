"""Training data for the code network: frames held in memory at the canonical camera, the train/validation
split, the deterministic data order and the batch augmentation.

Sources (``codeslam train --data DIR ...``):

* **generator shard folders**: files ``shard_*.safetensors`` written by :mod:`codeslam.synth.shards`
  (uint8 RGB and 1/5000 m uint16 depth of a pinhole camera), or single shard files.
* **any dataset folder the readers know** (:func:`codeslam.data.registry.open_dataset`) whose frames have depth.

Every frame is resampled to the network's canonical camera (:mod:`codeslam.geometry.resample`) and kept as
uint8 RGB and uint16 depth in 1/``DEPTH_UNITS_PER_M`` m (50k frames at 128x96 are ~1.8 GB).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.image import rgb_to_gray
from codeslam.geometry.resample import resample_depth, resample_image
from codeslam.network.camera_effects import CameraEffects, apply_camera_effects
from codeslam.network.config import TrainConfig

#: depth units per metre of the in-memory store (the TUM / generator convention): 0.2 mm steps, max 13.1 m
DEPTH_UNITS_PER_M = 5000.0
_UINT16_MAX = 65535
#: frames resampled per call when a shard's camera differs from the canonical one
_RESAMPLE_CHUNK = 256

ProgressFn = Callable[[str], None]


@dataclass
class FrameStore:
    """Training frames in memory at the canonical camera.

    Attributes:
        images: (N, 3, H, W) uint8 RGB.
        depth: (N, H, W) uint16 depth in 1/DEPTH_UNITS_PER_M m, 0 = invalid.
        groups: one (source name, start, stop) per shard / sequence, contiguous blocks of frames.
        group_weights: per group, the times its training frames appear in an epoch (:func:`split_train_val`).
    """

    images: torch.Tensor
    depth: torch.Tensor
    groups: list[tuple[str, int, int]]
    # per group: how many times its training frames appear per epoch (None: once each)
    group_weights: list[float] | None = None

    def __len__(self) -> int:
        return self.images.shape[0]

    def to(self, device: torch.device | str) -> FrameStore:
        depth = self.depth
        if torch.device(device).type != "cpu" and depth.dtype == torch.uint16:
            # CUDA cannot index uint16 tensors (seen with torch 2.11: "index_cuda" not implemented for 'UInt16'):
            # there the depth is held as int32, same values (depth_metres reads either).
            depth = depth.to(torch.int32)
        return FrameStore(self.images.to(device), depth.to(device), self.groups, self.group_weights)


def _same_camera(a: PinholeCamera, b: PinholeCamera, rtol: float = 1e-6) -> bool:
    if (a.width, a.height) != (b.width, b.height) or a.has_distortion or b.has_distortion:
        return False
    pa, pb = (a.fx, a.fy, a.cx, a.cy), (b.fx, b.fy, b.cx, b.cy)
    return all(math.isclose(x, y, rel_tol=rtol, abs_tol=rtol) for x, y in zip(pa, pb, strict=True))


def quantise_depth(depth_m: torch.Tensor) -> torch.Tensor:
    """Float depth in metres (...) -> uint16 (...) in 1/DEPTH_UNITS_PER_M m; invalid, non-finite or beyond the
    uint16 range (13.1 m) -> 0 (invalid)."""
    q = torch.round(torch.nan_to_num(depth_m, nan=0.0, posinf=0.0, neginf=0.0) * DEPTH_UNITS_PER_M)
    q = torch.where((q > 0) & (q <= _UINT16_MAX), q, torch.zeros_like(q))
    return q.to(torch.int32).to(torch.uint16)


def depth_metres(depth_u16: torch.Tensor) -> torch.Tensor:
    """uint16 store depth (...) -> float32 metres (...), 0 = invalid."""
    return depth_u16.to(torch.float32) / DEPTH_UNITS_PER_M


def _to_canonical(
    images: torch.Tensor, depth_m: torch.Tensor, src: PinholeCamera, dst: PinholeCamera
) -> tuple[torch.Tensor, torch.Tensor]:
    """(M, 3, h, w) uint8 and (M, h, w) float metres of camera ``src`` -> (M, 3, H, W) uint8 and (M, H, W)
    uint16 of camera ``dst``."""
    out_img, out_depth = [], []
    for i in range(0, images.shape[0], _RESAMPLE_CHUNK):
        img = images[i : i + _RESAMPLE_CHUNK].to(torch.float32) / 255.0
        dep = depth_m[i : i + _RESAMPLE_CHUNK].to(torch.float32)[:, None]
        if not _same_camera(src, dst):
            img = resample_image(img, src, dst)  # (m, 3, H, W)
            dep = resample_depth(dep, src, dst)  # (m, 1, H, W)
        out_img.append(torch.round(img.clamp(0, 1) * 255.0).to(torch.uint8))
        out_depth.append(quantise_depth(dep[:, 0]))
    return torch.cat(out_img), torch.cat(out_depth)


def shard_files(folder: Path) -> list[Path]:
    return sorted(folder.glob("shard_*.safetensors"))


def read_shard_to_canonical(path: Path, camera: PinholeCamera) -> tuple[torch.Tensor, torch.Tensor]:
    """One generator shard (:func:`codeslam.synth.shards.read_shard`, which raises DatasetError for a file that
    is not a readable shard) -> (M, 3, H, W) uint8, (M, H, W) uint16 at ``camera``."""
    from codeslam.synth.shards import read_shard

    images, depth_m, src = read_shard(path)
    if _same_camera(src, camera):
        return images, quantise_depth(depth_m)  # lossless: the shard's depth is 1/5000 m uint16 too
    return _to_canonical(images, depth_m, src, camera)


def read_sequence_to_canonical(
    path: Path, camera: PinholeCamera, workers: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Every frame of a dataset folder -> (N, 3, H, W) uint8, (N, H, W) uint16 at ``camera``."""
    from codeslam.data.registry import open_dataset

    seq = open_dataset(path)
    if not seq.has_depth:
        raise DatasetError(f"{path} has no depth maps; the network can only be trained on RGB-D data")

    def load(i: int) -> tuple[torch.Tensor, torch.Tensor]:
        frame = seq[i]
        if frame.depth is None:
            raise DatasetError(f"{path}: frame {i} has no depth map")
        img = frame.image[None].to(torch.float32)  # (1, 3, h, w)
        dep = frame.depth[None, None].to(torch.float32)  # (1, 1, h, w)
        if not _same_camera(frame.camera, camera):
            img = resample_image(img, frame.camera, camera)
            dep = resample_depth(dep, frame.camera, camera)
        return torch.round(img[0].clamp(0, 1) * 255.0).to(torch.uint8), quantise_depth(dep[0, 0])

    if workers > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            pairs = list(pool.map(load, range(len(seq))))
    else:
        pairs = [load(i) for i in range(len(seq))]
    if not pairs:
        raise DatasetError(f"{path} holds no frames")
    return torch.stack([p[0] for p in pairs]), torch.stack([p[1] for p in pairs])


def parse_source(spec: str | Path) -> tuple[Path, float]:
    """``PATH`` or ``PATH:WEIGHT`` -> (path, weight): the frames of a source appear WEIGHT times per epoch
    (a fraction < 1 takes that share of them; default 1). A path that exists as written is taken whole, so a
    folder whose name ends in ':<number>' still works."""
    text = str(spec)
    head, sep, tail = text.rpartition(":")
    if not sep or Path(text).exists():
        return Path(text), 1.0
    try:
        weight = float(tail)
    except ValueError:
        return Path(text), 1.0
    if not (math.isfinite(weight) and weight > 0):
        raise DatasetError(f"--data {text}: the weight after ':' must be a positive number, got {tail!r}")
    return Path(head), weight


def load_training_data(
    paths: list[str | Path], camera: PinholeCamera, workers: int = 2, log: ProgressFn | None = None
) -> FrameStore:
    """Read every source in ``paths`` (shard folders, single shard files or dataset folders, each optionally
    ``PATH:WEIGHT``, :func:`parse_source`) at ``camera``."""
    images, depths, groups, weights = [], [], [], []
    n = 0
    for p, w in map(parse_source, paths):
        if not p.exists():
            raise DatasetError(f"training data not found: {p}")
        shards = [p] if p.is_file() else shard_files(p)
        if shards:
            blocks = [(str(s), read_shard_to_canonical(s, camera)) for s in shards]
        else:
            blocks = [(str(p), read_sequence_to_canonical(p, camera, workers))]
        for name, (img, dep) in blocks:
            if img.shape[0] and not bool(dep.any()):  # uint16, 0 = invalid: only masked-out pixels to train on
                raise DatasetError(f"{name} holds no valid depth value in any of its {img.shape[0]} frames")
            images.append(img)
            depths.append(dep)
            groups.append((name, n, n + img.shape[0]))
            weights.append(w)
            n += img.shape[0]
            if log is not None:
                log(f"loaded {img.shape[0]} frames from {name}")
    if n == 0:
        raise DatasetError("no training frames found in " + ", ".join(map(str, paths)))
    return FrameStore(torch.cat(images), torch.cat(depths), groups, weights)


def split_train_val(store: FrameStore, val_fraction: float, val_max_frames: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Hold out the last ``val_fraction`` of every group (contiguous, so neighbouring video frames rarely straddle
    the split) -> train indices (N_t,), validation indices (N_v,) (at most ``val_max_frames``, evenly spaced).
    A group of weight w contributes its training frames round(w * n) times (cycled), so a small real set can
    carry a stated share of every epoch."""
    train, val = [], []
    weights = store.group_weights or [1.0] * len(store.groups)
    for (_, start, stop), w in zip(store.groups, weights, strict=True):
        n_val = int(round((stop - start) * val_fraction))
        if val_fraction > 0 and stop - start >= 2:
            n_val = max(1, n_val)
        idx = torch.arange(start, stop - n_val)
        if w != 1.0 and len(idx):  # a weighted source: its frames cycled to round(w * n) entries per epoch
            idx = idx.repeat(math.ceil(w))[: max(1, round(w * len(idx)))]
        train.append(idx)
        val.append(torch.arange(stop - n_val, stop))
    train_idx, val_idx = torch.cat(train), torch.cat(val)
    if len(val_idx) > val_max_frames:
        keep = torch.linspace(0, len(val_idx) - 1, val_max_frames).round().long()
        val_idx = val_idx[keep]
    return train_idx, val_idx


#: independent random streams derived from the run's seed
ORDER_STREAM, STEP_STREAM = 0, 1


def mix_seed(*entropy: int) -> int:
    """A well-mixed 63-bit seed from non-negative integers (e.g. seed, stream, step, rank)."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


class DataOrder:
    """The deterministic order of training frames: a permutation per (seed, epoch), split across processes
    like DistributedSampler (process r takes every world-th entry), ``batch_size`` frames per step."""

    def __init__(self, train_idx: torch.Tensor, batch_size: int, seed: int, rank: int = 0, world: int = 1) -> None:
        self.train_idx, self.batch_size, self.seed, self.rank, self.world = train_idx, batch_size, seed, rank, world
        self.per_rank = len(train_idx) // world
        self.steps_per_epoch = self.per_rank // batch_size
        if self.steps_per_epoch < 1:
            raise DatasetError(
                f"only {len(train_idx)} training frames for a batch of {batch_size} on {world} process(es); "
                "add data or lower --batch-size"
            )
        self._epoch, self._perm = -1, torch.empty(0, dtype=torch.long)

    def epoch_of(self, step: int) -> int:
        return step // self.steps_per_epoch

    def batch(self, step: int) -> torch.Tensor:
        """(batch_size,) frame indices of step ``step`` (0-based) on this process."""
        epoch, j = divmod(step, self.steps_per_epoch)
        if epoch != self._epoch:
            g = torch.Generator().manual_seed(mix_seed(self.seed, ORDER_STREAM, epoch))
            perm = torch.randperm(len(self.train_idx), generator=g)
            self._perm = perm[self.rank :: self.world][: self.per_rank]
            self._epoch = epoch
        return self.train_idx[self._perm[j * self.batch_size : (j + 1) * self.batch_size]]


def camera_effects_of(cfg: TrainConfig) -> CameraEffects | None:
    """The camera effects a training config asks for (None when all are off)."""
    fx = CameraEffects(cfg.exposure, cfg.vignetting, cfg.sensor_noise, cfg.motion_blur, cfg.rolling_shutter,
                       cfg.distortion, cfg.border)
    return fx if fx.any else None


def augment_batch(
    images: torch.Tensor, depth: torch.Tensor, cfg: TrainConfig, in_channels: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Training augmentation of one batch, all random draws from ``generator`` (CPU) so that a step is
    reproducible on any device.

    images (B, 3, H, W) uint8, depth (B, H, W) uint16 -> image (B, in_channels, H, W) float in [0, 1],
    depth (B, 1, H, W) float metres. Horizontal flips (image and depth together) keep the canonical camera
    (its principal point is centred); photometric jitter (gamma, contrast about the image mean, brightness,
    Gaussian noise) teaches robustness to exposure and sensor differences between datasets; with any of the
    config's camera effects on (:mod:`codeslam.network.camera_effects`), they are applied after the gamma, on
    RGB, before the rest (their draws come after the four above, so runs without them are unchanged).
    """
    B = images.shape[0]
    dev = images.device
    u = torch.rand(B, 4, generator=generator).to(dev)  # flip, gamma, contrast, brightness draws
    x = images.to(torch.float32) / 255.0  # (B, 3, H, W)
    d = depth_metres(depth)[:, None]  # (B, 1, H, W)
    flip = (u[:, 0] < cfg.flip_prob).view(B, 1, 1, 1)
    x = torch.where(flip, x.flip(-1), x)
    d = torch.where(flip, d.flip(-1), d)
    gamma = torch.exp((2 * u[:, 1] - 1) * cfg.gamma).view(B, 1, 1, 1)
    x = x.clamp_min(0) ** gamma
    fx = camera_effects_of(cfg)
    if fx is not None and fx.any:  # the image formation of a real camera (data version 2's sensor)
        x, d = apply_camera_effects(x, d, fx, generator)
    if in_channels == 1:
        x = rgb_to_gray(x)  # (B, 1, H, W)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    contrast = (1 + (2 * u[:, 2] - 1) * cfg.contrast).view(B, 1, 1, 1)
    brightness = ((2 * u[:, 3] - 1) * cfg.brightness).view(B, 1, 1, 1)
    x = (x - mean) * contrast + mean + brightness
    if cfg.noise_std > 0:
        x = x + cfg.noise_std * torch.randn(x.shape, generator=generator).to(dev)
    return x.clamp(0, 1), d


def plain_batch(images: torch.Tensor, depth: torch.Tensor, in_channels: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Validation batch without augmentation: uint8 (B, 3, H, W), uint16 (B, H, W) -> (B, Cin, H, W) float,
    (B, 1, H, W) metres."""
    x = images.to(torch.float32) / 255.0
    if in_channels == 1:
        x = rgb_to_gray(x)
    return x, depth_metres(depth)[:, None]
