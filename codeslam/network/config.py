"""Typed configuration of the code network and of its training, overlaid from YAML.

A YAML file holds up to two sections, ``network:`` and ``train:``, each a subset of the fields below::

    network:
      code_size: 32
      width: 256
      height: 192
    train:
      steps: 20000

Unknown keys and values of the wrong type are refused with a :class:`~codeslam.errors.ConfigError`.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from codeslam.configfile import from_mapping, read_yaml_mapping
from codeslam.errors import ConfigError

#: number of down-sampling stages of every branch; image sizes must be multiples of 2 ** this
NUM_SCALES = 4
#: largest magnitude of an integer option (a YAML integer can be arbitrarily large; torch needs int64 and
#: no option of a network that fits in memory comes near this)
NUM_LEVELS = 4


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of the intensity-conditioned depth VAE (paper Sec. 2.1, Fig. 3)."""

    # Entries of the depth code c; 128 is the paper's reference, 32 trades accuracy for speed in SLAM.
    code_size: int = 128
    # Identity activations in the depth decoder and [L1, L2, L1*L2] concatenations, so D(I, c) is affine
    # in c and its Jacobian can be pre-computed once per keyframe (the paper's reference network).
    linear_decoder: bool = True
    # 1 = greyscale input (the paper's reference network), 3 = RGB.
    in_channels: int = 1
    # Canonical image width in pixels (multiple of 16); 128x96 keeps training and SLAM on a CPU.
    width: int = 128
    # Canonical image height in pixels (multiple of 16); the paper's 256x192 is a config away.
    height: int = 96
    # Horizontal field of view of the canonical camera every image is resampled to (SceneNet RGB-D: 60).
    hfov_deg: float = 60.0
    # Average depth a (metres) of the proximity p = a / (d + a) (Eq. 4), so that typical depths map to p ~ 0.5:
    # the generator's rooms have median depth 1.2 m (mean 1.44 m, 5-95% 0.4-3.2 m; measured on 512 views) and
    # TUM fr1 Kinect depths span ~0.7-2.6 m.
    avg_depth: float = 1.5
    # U-Net widths at 1/2, 1/4, 1/8, 1/16 resolution; the depth decoder uses the same widths so that its
    # features can be multiplied element-wise with the image features.
    image_channels: tuple[int, ...] = (16, 32, 64, 128)
    # Width of the full-resolution U-Net features (and of the decoder's last, deconvolved layer).
    full_res_channels: int = 8
    # Depth encoder widths at 1/2, 1/4, 1/8, 1/16 resolution.
    depth_channels: tuple[int, ...] = (16, 32, 64, 128)
    # Channels of the 1/16 map flattened into the fully connected bottleneck (keeps the FC layer small).
    bottleneck_channels: int = 32
    # Units of each of the two fully connected layers before the code mean / log-variance (paper: 512).
    fc_units: int = 512

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_channels", tuple(int(c) for c in self.image_channels))
        object.__setattr__(self, "depth_channels", tuple(int(c) for c in self.depth_channels))
        step = 2**NUM_SCALES
        if self.code_size < 1:
            raise ConfigError(f"network.code_size must be >= 1, got {self.code_size}")
        if self.in_channels not in (1, 3):
            raise ConfigError(f"network.in_channels must be 1 (grey) or 3 (RGB), got {self.in_channels}")
        if self.width < step or self.height < step or self.width % step or self.height % step:
            raise ConfigError(
                f"network image size must be a positive multiple of {step} in both axes, "
                f"got {self.width}x{self.height}"
            )
        if not 0 < self.hfov_deg < 180:
            raise ConfigError(f"network.hfov_deg must lie in (0, 180), got {self.hfov_deg}")
        if not self.avg_depth > 0:
            raise ConfigError(f"network.avg_depth must be positive, got {self.avg_depth}")
        for name in ("image_channels", "depth_channels"):
            chans = getattr(self, name)
            if len(chans) != NUM_SCALES or min(chans) < 1:
                raise ConfigError(f"network.{name} needs {NUM_SCALES} positive widths, got {list(chans)}")
        for name in ("full_res_channels", "bottleneck_channels", "fc_units"):
            if getattr(self, name) < 1:
                raise ConfigError(f"network.{name} must be >= 1, got {getattr(self, name)}")

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["image_channels"] = list(self.image_channels)
        d["depth_channels"] = list(self.depth_channels)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetworkConfig:
        return from_mapping(cls, d, "network")


@dataclass(frozen=True)
class TrainConfig:
    """How ``codeslam train`` optimises the network (paper Sec. 2.2 "Training Setup")."""

    # Total optimiser steps; the learning-rate schedule spans exactly these. 10000 x 16 = 160k images take
    # ~47 min at the ~57 images/s measured on an idle 2-core CPU (the 2-hour CPU budget of the default weights).
    steps: int = 10000
    # Images per step per process (under torchrun the global batch is this times the world size).
    batch_size: int = 16
    # Initial Adam learning rate (paper: 1e-4).
    lr: float = 1e-4
    # Learning rate reached at the last step (paper: 1e-6).
    lr_final: float = 1e-6
    # "cosine" (stays near lr for longer, better for short CPU runs) or "exponential" (geometric decay);
    # the paper only says it decays from 1e-4 to 1e-6.
    lr_schedule: str = "cosine"
    # Weight of the per-image KL divergence divided by the pixel count: 1 makes the loss the negative ELBO per
    # finest-level pixel (Kingma & Welling), which keeps the code close to N(0, I) for the SLAM prior.
    kl_weight: float = 1.0
    # Steps over which the KL weight ramps linearly from 0 to kl_weight (lets the code carry depth early on).
    kl_warmup_steps: int = 1000
    # Weight of the NLL of the zero-code prediction D(I, 0) (not in the paper; see codeslam.network.loss: without
    # it the image-only prediction trains far slower than the reconstruction); 0 disables it.
    zero_code_weight: float = 1.0
    # Weight of the zero-code prediction's scale-free shape error (not in the paper; codeslam.network.loss.shape_error:
    # log-depth gradient matching and the scale-invariant log error); 0 disables it. Measured as 1,000-step fine-tunes
    # of the shipped default (docs/results/depth_prior_ablation.md, sixtieth session): at 100 the zero code's error
    # after its per-frame scale falls on all 10 sets (TUM fr1/rpy 0.0836 -> 0.0762, the HoloLens walk 0.0766 ->
    # 0.0752, the generator's 3-8%) while its scale moves (TUM's median depth ratio 1.26 -> 1.36), and SLAM is no
    # better (one run a sequence, mixed; a fine-tune alone moves it as much); 300 adds little. Off by default.
    shape_weight: float = 0.0
    # Scale-equivariant code span (not in the paper): the code path's targets (the encoder's input and the
    # reconstruction) at each image's depth times exp(u), u uniform in [-x, x], the zero code's at the true depth.
    # The window fits keyframe codes to images, which fix the shape and not the scale, so where the decoder's
    # span holds a room's shape only at the training rooms' depth, a monocular map drifts there
    # (docs/results/depth_prior_ablation.md, "Where the code's span holds the truth"). Measured on a lent GPU
    # (x = 0.7, ~2,800 steps of 128 images from random weights): the span's best scale on the walks 0.4-0.5 -> 0.5-0.6,
    # the SLAM maps' scale unchanged, so 0 = off stays the default ("Scale-augmented code targets", same file).
    code_scale: float = 0.0
    # Seed of the initial weights, the data order (per epoch) and the augmentation/sampling noise (per step).
    seed: int = 0
    # Fraction of every data source (the last frames of each shard / sequence) held out for validation.
    val_fraction: float = 0.05
    # At most this many held-out frames are evaluated (evenly spaced), to keep validation cheap.
    val_max_frames: int = 256
    # Validate every this many steps (and at the end).
    val_every: int = 500
    # Append a row of averaged training losses to RUN/log.csv every this many steps.
    log_every: int = 50
    # Write RUN/checkpoint.safetensors every this many steps ...
    checkpoint_every: int = 500
    # ... or when this many minutes have passed since the last one, whichever comes first.
    checkpoint_minutes: float = 10.0
    # Probability of a horizontal flip of image and depth together.
    flip_prob: float = 0.5
    # Brightness jitter: an offset drawn uniformly from [-x, x] (intensity in [0, 1]).
    brightness: float = 0.1
    # Contrast jitter: a gain drawn uniformly from [1 - x, 1 + x] about the image mean.
    contrast: float = 0.2
    # Gamma jitter: exponent exp(u), u uniform in [-x, x].
    gamma: float = 0.2
    # Standard deviation of additive Gaussian pixel noise (intensity units).
    noise_std: float = 0.01
    # Image formation of real cameras applied to every training image (codeslam.network.camera_effects; all 0 =
    # off, as for the first default weights). exposure: log-gain range; vignetting: largest corner darkening;
    # sensor_noise: shot/read noise level; motion_blur: longest blur (pixels); rolling_shutter: largest row shear
    # (pixels, top to bottom); distortion: largest |k1| of a lens that is undistorted again.
    exposure: float = 0.0
    vignetting: float = 0.0
    sensor_noise: float = 0.0
    motion_blur: float = 0.0
    rolling_shutter: float = 0.0
    distortion: float = 0.0
    # Black bands of a source camera with a narrower field of view than the canonical one, in half the images:
    # up to this fraction of the height at the top and at the bottom (2/3 of it of the width at each side).
    border: float = 0.0
    # Weights file to start from (fine-tuning) instead of random weights; "" = random, "default" = the shipped
    # weights. Its architecture must be the network config's.
    init_weights: str = ""
    # Threads that load and resample dataset frames in parallel (training itself runs in the main thread).
    workers: int = 2
    # Device of the model and the in-memory data: "cpu", "cuda" or "cuda:N" (under torchrun: the local rank).
    device: str = "cpu"

    def __post_init__(self) -> None:
        positive_ints = ("steps", "batch_size", "val_max_frames", "val_every", "log_every", "checkpoint_every")
        for name in positive_ints:
            if getattr(self, name) < 1:
                raise ConfigError(f"train.{name} must be >= 1, got {getattr(self, name)}")
        if not (self.lr > 0 and self.lr_final > 0):
            raise ConfigError(f"train.lr and train.lr_final must be positive, got {self.lr}, {self.lr_final}")
        if self.lr_schedule not in ("cosine", "exponential"):
            raise ConfigError(f"train.lr_schedule must be 'cosine' or 'exponential', got {self.lr_schedule!r}")
        if self.kl_weight < 0 or self.kl_warmup_steps < 0 or self.zero_code_weight < 0:
            raise ConfigError("train.kl_weight, train.kl_warmup_steps and train.zero_code_weight must be >= 0")
        if not 0 <= self.val_fraction < 1:
            raise ConfigError(f"train.val_fraction must lie in [0, 1), got {self.val_fraction}")
        if not 0 <= self.flip_prob <= 1:
            raise ConfigError(f"train.flip_prob must lie in [0, 1], got {self.flip_prob}")
        for name in ("brightness", "contrast", "gamma", "noise_std", "checkpoint_minutes", "exposure", "vignetting",
                     "sensor_noise", "rolling_shutter", "distortion", "border", "code_scale", "shape_weight"):
            if getattr(self, name) < 0:
                raise ConfigError(f"train.{name} must be >= 0, got {getattr(self, name)}")
        from codeslam.network.camera_effects import BLUR_TAPS

        if not 0 <= self.motion_blur <= BLUR_TAPS:
            raise ConfigError(f"train.motion_blur must lie in [0, {BLUR_TAPS}] pixels, got {self.motion_blur}")
        if self.vignetting > 1 or self.distortion > 0.5 or self.border > 0.3:
            raise ConfigError("train.vignetting must be at most 1, train.distortion at most 0.5 and train.border at "
                              "most 0.3")
        if self.workers < 0:
            raise ConfigError(f"train.workers must be >= 0, got {self.workers}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        return from_mapping(cls, d, "train")


@dataclass(frozen=True)
class RunConfig:
    """Both configs of a training run, as written to RUN/config.yaml."""

    network: NetworkConfig = field(default_factory=NetworkConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def to_dict(self) -> dict[str, Any]:
        return {"network": self.network.to_dict(), "train": self.train.to_dict()}


def overlay(base, updates: dict[str, Any]):
    """``base`` (a NetworkConfig or TrainConfig) with the fields in ``updates`` replaced (validated)."""
    section = "network" if isinstance(base, NetworkConfig) else "train"
    merged = {**base.to_dict(), **updates}
    return from_mapping(type(base), merged, section)


def load_run_config(path: str | os.PathLike | None, base: RunConfig | None = None) -> RunConfig:
    """Read a YAML file with optional ``network:`` / ``train:`` sections and overlay it on ``base``
    (defaults when None). ``path=None`` returns ``base`` unchanged."""
    base = base or RunConfig()
    if path is None:
        return base
    path = Path(path)
    data = read_yaml_mapping(path, "sections 'network' and/or 'train'")
    unknown = sorted(set(data) - {"network", "train"})
    if unknown:
        raise ConfigError(f"config file {path}: unknown section(s) {', '.join(map(str, unknown))}")
    for section in ("network", "train"):
        if not isinstance(data.get(section) or {}, dict):
            raise ConfigError(f"config file {path}: section '{section}' must be a mapping of options, "
                              f"got {data[section]!r}")
    net = overlay(base.network, data.get("network") or {})
    tr = overlay(base.train, data.get("train") or {})
    return RunConfig(network=net, train=tr)


def dump_run_config(config: RunConfig) -> str:
    """The YAML text of a resolved run configuration."""
    return yaml.safe_dump(config.to_dict(), sort_keys=False)
