"""Self-supervised adaptation of the code network to a video without depth (the paper's future work, Sec. 6).

Given N consecutive frames of one camera (resampled to the network's canonical camera), :func:`adapt` fine-tunes
the network so that its depth explains the video: every target frame i is warped into its neighbours j by its
depth and the relative pose, and the photometric error is minimised (the paper's Eq. 6 residual, Huber-robust,
per pixel the smallest over the neighbours so that occlusions and pixels leaving the view do not count, on
``levels`` pyramid levels). Optimised together, by Adam:

* the network's weights (after ``pose_warmup`` steps in which only the other variables move), held near their
  start by an L2 anchor (``anchor``), so that a short video cannot undo what the network knew, and each frame's
  mean log zero-code depth held at the start network's (``scale_anchor``): the video cannot tell the scale. By
  default only the weights that the zero-code depth D(I, 0) depends on and the code Jacobian J(I) does not
  (``trainable``, :func:`zero_code_parameters`): the prior adapts, and the span SLAM's window optimises codes in
  stays the start network's;
* one code c_i per frame, under the VAE's prior N(0, I) (``code_prior`` * 0.5 |c|² per image, divided by the
  pixel count as in training), the depth being D(I_i, c_i);
* the zero-code depth D(I_i, 0) is put through the same photometric loss (``zero_code_weight``), so the
  prior itself - what SLAM starts every keyframe from - adapts, not only the codes;
* the camera motion: frame i's pose is T_wc_i = T_wc_(i-1) exp(delta_i), with delta_0 = 0 (the gauge), starting
  from given poses (e.g. from ``codeslam slam``) or from no motion;
* an affine brightness (log gain, offset) per frame, for auto-exposure; only differences between frames
  enter the loss (a source is compared as exp(g_s - g_t) I_s + o_s - o_t), so no common gain can shrink it.

Motions and brightness are estimated in the warm-up (all of them in every step, against the start network's
zero-code depth) and then held while network and codes adapt: updated from the few frames of a step, Adam's
momentum kept moving the motions of the other frames and the photometric error grew six-fold within 30 steps
(measured on a generator walk).

Monocular photometric consistency does not fix the scale: depth and translations can grow together. The scale
stays the network's (the scale anchor holds it), so adaptation improves the shape of the depth, not its scale.

Everything random (the frame order of each step) comes from ``seed`` and the step, so a resumed run repeats the
interrupted one. The run folder holds ``checkpoint.safetensors`` (network, codes, motions, brightness, Adam
states, step), ``log.csv`` and, at the end, the adapted ``weights.safetensors``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as F

from codeslam.errors import ConfigError, WeightsError
from codeslam.geometry.camera import PinholeCamera, pixel_grid, project, unproject
from codeslam.geometry.image import bilinear_sample, pyramid_cameras
from codeslam.geometry.lie import se3_exp, se3_inverse, se3_log
from codeslam.geometry.proximity import prox_to_depth
from codeslam.io import atomic_write, ensure_dir
from codeslam.network.data import mix_seed
from codeslam.network.model import CodeNetwork, to_network_image
from codeslam.network.weights import read_tensors, save_tensors, save_weights

ADAPT_CHECKPOINT_FORMAT = "codeslam-adapt-checkpoint-v1"
CHECKPOINT_NAME = "checkpoint.safetensors"
WEIGHTS_NAME = "weights.safetensors"
LOG_FIELDS = ["step", "loss", "photo", "photo_zero", "code_prior", "anchor", "seconds"]
#: In the warm-up (network frozen, its zero-code depth decoded once) a step takes this many times ``batch`` targets,
#: and the motions' learning rate starts this many times ``lr_pose`` (cosine decay to it at the warm-up's end):
#: motions start far from the truth (no motion) and every frame's motion needs gradients in every step.
WARMUP_BATCH_FACTOR = 4
WARMUP_POSE_LR_FACTOR = 5.0
#: Points nearer than this (metres) to the source camera are not compared.
MIN_WARP_DEPTH = 0.05
#: AdaptConfig.trainable's choices.
TRAINABLE = ("zero_code", "all")


@dataclass(frozen=True)
class AdaptConfig:
    """How :func:`adapt` fine-tunes the network on a video."""

    # Adam steps in all (the warm-up included).
    steps: int = 400
    # Steps at the start that move only the motions and brightness, against the start network's zero-code depth
    # (decoded once), so that the network is not fitted to the errors of a wrong initial motion.
    pose_warmup: int = 100
    # Target frames per step; each is compared with its neighbours.
    batch: int = 6
    # Frame offsets of the neighbours a target frame is warped into.
    neighbours: tuple[int, ...] = (-2, -1, 1, 2)
    # Which network weights adapt: "zero_code" (what D(I, 0) depends on and the code Jacobian does not, see
    # zero_code_parameters) or "all". Measured (docs/results/depth_prior_ablation.md, 2026-11-27): 400 steps on
    # the first half of a recording, held-out zero-code RMSE on the second, shipped -> adapted: HoloLens walk
    # 0.1143 -> 0.1130, TUM fr1/rpy 0.1251 -> 0.1237 at lr 1e-3; "all" at lr 1e-5 (the former default)
    # 0.1131 and 0.1249, and longer runs of "all" made SLAM on the held-out halves worse.
    trainable: str = "zero_code"
    # Adam learning rates: network weights (1e-5 suits trainable "all"), codes, motions (per unit of the se(3)
    # vector) and brightness.
    lr: float = 1e-3
    lr_code: float = 1e-2
    lr_pose: float = 2e-3
    lr_brightness: float = 1e-2
    # Pyramid levels of the photometric loss (1 = full resolution only); level l weighs like level 0.
    levels: int = 3
    # Huber threshold of the photometric residual (intensity in [0, 1]).
    huber: float = 0.05
    # Weight of the code prior 0.5 |c|² / (H W) (the VAE's prior as the training loss weighs it).
    code_prior: float = 1.0
    # Weight of the photometric loss of the zero-code depth D(I, 0).
    zero_code_weight: float = 1.0
    # Weight of the anchor 0.5 sum (w - w_start)² / (number of weights), per unit of the photometric loss.
    anchor: float = 10.0
    # Weight of the scale anchor: the squared change of each frame's mean log zero-code depth from the start
    # network's. Video alone cannot tell the scale; without this the depth of a mostly rotating camera drifted
    # away (TUM fr1/rpy: median depth ratio 0.98 -> 1.27 in 400 steps).
    scale_anchor: float = 1.0
    # Leave out pixels that no motion explains better than the warp (see photometric_loss).
    automask: bool = True
    # Seed of the frame order.
    seed: int = 0
    # Append a row to log.csv every this many steps; write the checkpoint every this many.
    log_every: int = 10
    checkpoint_every: int = 50

    def __post_init__(self) -> None:
        object.__setattr__(self, "neighbours", tuple(int(n) for n in self.neighbours))
        for name in ("steps", "batch", "levels", "log_every", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise ConfigError(f"adapt.{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.pose_warmup <= self.steps:
            raise ConfigError(f"adapt.pose_warmup must lie in [0, steps], got {self.pose_warmup}")
        if self.trainable not in TRAINABLE:
            raise ConfigError(f"adapt.trainable must be one of {', '.join(TRAINABLE)}, got {self.trainable!r}")
        if not self.neighbours or 0 in self.neighbours:
            raise ConfigError(f"adapt.neighbours must be non-zero frame offsets, got {list(self.neighbours)}")
        for name in ("lr", "lr_code", "lr_pose", "lr_brightness", "huber"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"adapt.{name} must be positive, got {getattr(self, name)}")
        for name in ("code_prior", "zero_code_weight", "anchor", "scale_anchor"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"adapt.{name} must be >= 0, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["neighbours"] = list(self.neighbours)
        return d


@dataclass
class AdaptResult:
    """What :func:`adapt` reports back."""

    run_dir: Path
    step: int  # completed steps
    finished: bool  # all steps done and weights written
    last: dict[str, float] = field(default_factory=dict)  # the last logged loss terms
    poses: torch.Tensor | None = None  # (N, 4, 4) float64 estimated T_wc of the frames


# ------------------------------------------------------------------------------------------------ the loss
def zero_code_parameters(model: CodeNetwork) -> list[tuple[torch.nn.Parameter, torch.Tensor | None]]:
    """The parameters that the zero-code depth D(I, 0) depends on and the code Jacobian J(I) does not, each with
    the mask of its adaptable entries (None: all of them).

    Every layer of the linear decoder is ``W_y y + W_f f + W_yf (y * f) + b`` on the decoder feature y and the
    image feature f (:func:`~codeslam.network.model.join`), and J is the product of the ``W_y`` and ``W_yf`` (and
    the code's fully connected weight, the heads' weights on y and the transposed convolution's) with the image
    features (:meth:`~codeslam.network.model.DepthDecoder.code_directions`). So the biases and the ``W_f`` slices
    may move; the image U-Net, the encoder and every weight on y may not. Our own choice, not the paper's: SLAM
    optimises each keyframe's code in J's span, and adapting J as well made SLAM on held-out frames worse
    (docs/results/depth_prior_ablation.md)."""
    dec = model.decoder
    if not dec.linear:
        raise ConfigError("adapt.trainable 'zero_code' needs the linear decoder; use 'all'")
    out: list[tuple[torch.nn.Parameter, torch.Tensor | None]] = []
    for conv in (*dec.convs, dec.heads[0]):  # input channels [y, f, y * f]
        K = conv.weight.shape[1] // 3
        mask = torch.zeros_like(conv.weight)
        mask[:, K:2 * K] = 1.0
        out.append((conv.weight, mask))
    out += [(m.bias, None) for m in (*dec.convs, *dec.heads, dec.deconv, dec.fc)]
    return out


def chain_poses(T0: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """Poses T_wc_i = T0_0 prod_(k<=i) exp(delta_k) (N, 4, 4) from the first pose T0 (4, 4) and the motions
    delta (N, 6) (delta_0 is applied to the first frame; :func:`adapt` keeps it 0)."""
    steps = se3_exp(delta)  # (N, 4, 4)
    out, T = [], T0
    for i in range(delta.shape[0]):
        T = T @ steps[i]
        out.append(T)
    return torch.stack(out)


def relative_motions(T_wc: torch.Tensor) -> torch.Tensor:
    """The motions (N, 6) that :func:`chain_poses` turns back into T_wc (N, 4, 4) from T_wc[0] (delta_0 = 0)."""
    rel = se3_inverse(T_wc[:-1]) @ T_wc[1:]  # (N - 1, 4, 4)
    return torch.cat([T_wc.new_zeros(1, 6), se3_log(rel)])


def _huber(r: torch.Tensor, k: float) -> torch.Tensor:
    a = r.abs()
    return torch.where(a <= k, 0.5 * r * r, k * (a - 0.5 * k))


def photometric_loss(
    gray_t: torch.Tensor, depth_t: torch.Tensor, gray_s: torch.Tensor, valid_s: torch.Tensor,
    T_st: torch.Tensor, camera: PinholeCamera, huber: float, automask: bool = False,
) -> torch.Tensor:
    """Mean over target pixels of the smallest Huber photometric error over the source frames.

    gray_t (B, 1, h, w) target intensities, depth_t (B, 1, h, w) its depth, gray_s (B, S, h, w) the S source
    frames' intensities (after their brightness correction), valid_s (B, S, h, w) where the sources hold real
    pixels, T_st (B, S, 4, 4) target-to-source transforms, camera: the pinhole camera of this level.
    A pixel counts where at least one source sees it (inside, valid, in front) and, with ``automask``, where the
    warp explains it better than no motion at all does (Godard et al.'s auto-masking, Monodepth2, ICCV 2019:
    pixels that look the same in both frames - a camera that barely moved, textureless walls - say nothing about
    depth, and left in they pull it towards infinity, where any warp is no motion). Returns a scalar.
    """
    B, S, h, w = gray_s.shape
    uv = pixel_grid(h, w, depth_t.dtype, depth_t.device).reshape(1, -1, 2)  # (1, P, 2)
    params = camera.params().to(depth_t)
    xyz_t = unproject(uv, depth_t.reshape(B, -1), params)  # (B, P, 3) the paper's pi^-1 (Eq. 5)
    R, t = T_st[..., :3, :3], T_st[..., :3, 3]
    xyz_s = torch.einsum("bsij,bpj->bspi", R, xyz_t) + t[:, :, None, :]  # (B, S, P, 3)
    uv_s = project(xyz_s, params)  # (B, S, P, 2)
    warped, inside = bilinear_sample(gray_s.reshape(B * S, 1, h, w), uv_s.reshape(B * S, -1, 2))  # Eq. 6 lookup
    ok_src, _ = bilinear_sample(valid_s.reshape(B * S, 1, h, w).to(gray_s.dtype), uv_s.reshape(B * S, -1, 2))
    warped, ok_src = warped.reshape(B, S, -1), ok_src.reshape(B, S, -1)
    seen = inside.reshape(B, S, -1) & (xyz_s[..., 2] > MIN_WARP_DEPTH) & (ok_src > 0.999)
    err = _huber(gray_t.reshape(B, 1, -1) - warped, huber)  # (B, S, P)
    err = torch.where(seen, err, torch.full_like(err, float("inf")))
    best = err.min(dim=1).values  # (B, P) the best source per pixel
    counted = torch.isfinite(best)
    if automask:
        still = _huber(gray_t.reshape(B, 1, -1) - gray_s.reshape(B, S, -1), huber).min(dim=1).values  # (B, P)
        counted = counted & (best < still)
    return torch.where(counted, best, torch.zeros_like(best)).sum() / counted.sum().clamp_min(1)


def _gray_pyramid(gray: torch.Tensor, levels: int) -> list[torch.Tensor]:
    out = [gray]
    for _ in range(levels - 1):
        out.append(F.avg_pool2d(out[-1], 2))
    return out


def _valid_pyramid(valid: torch.Tensor, levels: int) -> list[torch.Tensor]:
    out = [valid]
    for _ in range(levels - 1):
        out.append(F.avg_pool2d(out[-1].float(), 2) > 0.999)
    return out


# ------------------------------------------------------------------------------------------------ the run
class _Log:
    def __init__(self, path: Path, rows: list[dict]) -> None:
        self.path, self.rows = path, rows

    def append(self, row: dict) -> None:
        self.rows.append({k: row[k] for k in LOG_FIELDS})
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=LOG_FIELDS)
        writer.writeheader()
        writer.writerows(self.rows)
        with atomic_write(self.path, "w", newline="") as f:
            f.write(buf.getvalue())


def _read_log(path: Path, upto: int) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if int(r["step"]) <= upto]


def adapt(
    model: CodeNetwork,
    images: torch.Tensor,
    run_dir: str | Path,
    config: AdaptConfig | None = None,
    valid: torch.Tensor | None = None,
    poses: torch.Tensor | None = None,
    resume: bool = False,
    stop_after: int | None = None,
    progress: Callable[[int, int, dict], None] | None = None,
    source: dict | None = None,
) -> AdaptResult:
    """Adapt ``model`` (changed in place) to the video ``images`` and write the run folder ``run_dir``.

    Args:
        model: the network to adapt (its weights are the start and the anchor).
        images: (N, 3, H, W) consecutive frames at the network's canonical camera, RGB in [0, 1].
        config: see :class:`AdaptConfig`.
        valid: (N, H, W) bool, where the frames hold real pixels (None: everywhere).
        poses: (N, 4, 4) initial camera-to-world poses (e.g. from ``codeslam slam``); None: no motion.
        resume: continue from ``run_dir/checkpoint.safetensors`` if there is one (its weights replace the
            model's; the anchor stays the model's start, which the checkpoint also holds).
        stop_after: stop (with a checkpoint) after this many steps, as if interrupted.
        progress: called as ``progress(done, total, last_logged_terms)`` after every step.
        source: what the frames are (dataset, frame indices), stored with the weights.
    """
    cfg = config or AdaptConfig()
    run_dir = Path(run_dir)
    N, _, H, W = images.shape
    if N < 2:
        raise ConfigError(f"adaptation needs at least 2 frames, got {N}")
    cam = model.camera
    if (W, H) != (cam.width, cam.height):
        raise ConfigError(f"frames are {W}x{H} but the network's canonical camera is {cam.width}x{cam.height}")
    dev = next(model.parameters()).device
    levels = min(cfg.levels, 4)
    gray = to_network_image(images.to(dev, torch.float32), 1)  # (N, 1, H, W) photometric intensities
    net_in = to_network_image(images.to(dev, torch.float32), model.config.in_channels)
    valid = torch.ones(N, H, W, dtype=torch.bool, device=dev) if valid is None else valid.to(dev)
    gray_pyr, valid_pyr = _gray_pyramid(gray, levels), _valid_pyramid(valid[:, None], levels)
    cams = pyramid_cameras(cam, levels)

    start = {k: v.detach().clone() for k, v in model.state_dict().items()}
    T0 = torch.eye(4, dtype=torch.float32, device=dev) if poses is None else poses[0].to(dev, torch.float32)
    delta0 = torch.zeros(N, 6) if poses is None else relative_motions(poses.double()).float()
    codes = torch.zeros(N, model.code_size, device=dev, requires_grad=True)
    delta = delta0.to(dev).clone().requires_grad_(True)
    bright = torch.zeros(N, 2, device=dev, requires_grad=True)  # log gain, offset
    was_trainable = [(p, p.requires_grad) for p in model.parameters()]
    if cfg.trainable == "zero_code":
        chosen = zero_code_parameters(model)
        masks = [(p, m) for p, m in chosen if m is not None]  # applied to the gradients before every step
        for p in model.parameters():
            p.requires_grad_(False)
        net_params = [p for p, _ in chosen]
    else:
        masks = []
        net_params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam([
        {"params": net_params, "lr": cfg.lr},
        {"params": [codes], "lr": cfg.lr_code},
        {"params": [delta], "lr": cfg.lr_pose},
        {"params": [bright], "lr": cfg.lr_brightness},
    ])
    done, elapsed_before = 0, 0.0
    ckpt = run_dir / CHECKPOINT_NAME
    if resume and ckpt.is_file():
        done, elapsed_before, start = _restore(ckpt, model, opt, codes, delta, bright, start, cfg)
    ensure_dir(run_dir)
    with atomic_write(run_dir / "adapt_config.json") as f:
        f.write(json.dumps({"adapt": cfg.to_dict(), "frames": N, "source": source or {}}, indent=1))
    log = _Log(run_dir / "log.csv", _read_log(run_dir / "log.csv", done) if resume else [])
    end = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    offsets = torch.tensor(cfg.neighbours)
    n_weights = sum(v.numel() for v in start.values() if v.is_floating_point())
    t0, acc, acc_n, last = time.perf_counter(), torch.zeros(4, dtype=torch.float64), 0, {}
    model.train()

    def save(step: int) -> None:
        _save(ckpt, model, opt, codes, delta, bright, start, step, elapsed_before + time.perf_counter() - t0, cfg)

    with torch.no_grad():  # the start network's zero-code proximity of every frame: warm-up depth, scale anchor
        parts = [model.decode(f, f[0].new_zeros(f[0].shape[0], model.code_size)) for f in
                 (model.image_features(net_in[a:a + 16]) for a in range(0, N, 16))]
        start_prox = [torch.cat(x) for x in zip(*parts, strict=True)]  # levels x (N, 1, h, w)
    if done > 0:  # resumed: the warm-up depth and the scale anchor are the start weights', not the checkpoint's
        current = {k: v.detach().clone() for k, v in model.state_dict().items()}
        model.load_state_dict(start)
        with torch.no_grad():
            parts = [model.decode(f, f[0].new_zeros(f[0].shape[0], model.code_size)) for f in
                     (model.image_features(net_in[a:a + 16]) for a in range(0, N, 16))]
            start_prox = [torch.cat(x) for x in zip(*parts, strict=True)]
        model.load_state_dict(current)
    start_log_depth = torch.log(prox_to_depth(start_prox[0], model.avg_depth)).mean(dim=(1, 2, 3))  # (N,)
    for step in range(done, end):
        warm = step < cfg.pose_warmup
        for p in net_params:
            p.requires_grad_(not warm)
        delta.requires_grad_(warm)  # motions and brightness are estimated in the warm-up, then held
        bright.requires_grad_(warm)
        # warm-up: a cosine decay of the motion learning rate from WARMUP_POSE_LR_FACTOR x lr_pose to lr_pose
        f = 0.5 * (1 + math.cos(math.pi * step / max(cfg.pose_warmup, 1))) if warm else 0.0
        opt.param_groups[2]["lr"] = cfg.lr_pose * (1 + (WARMUP_POSE_LR_FACTOR - 1) * f)
        g = torch.Generator().manual_seed(mix_seed(cfg.seed, 7, step))
        batch = min(WARMUP_BATCH_FACTOR * cfg.batch if warm else cfg.batch, N)
        tgt = torch.randperm(N, generator=g)[:batch]  # (B,) target frames
        src = (tgt[:, None] + offsets[None, :]).clamp(0, N - 1)  # (B, S); at the ends a neighbour repeats
        src = torch.where(src == tgt[:, None], (tgt[:, None] - offsets[None, :]).clamp(0, N - 1), src)
        tgt_d, src_d = tgt.to(dev), src.to(dev)
        T_wc = chain_poses(T0, delta.clone().index_fill(0, torch.tensor([0], device=dev), 0.0))  # (N, 4, 4)
        T_st = se3_inverse(T_wc[src_d]) @ T_wc[tgt_d][:, None]  # (B, S, 4, 4) target -> source
        B = len(tgt)
        if warm:  # the start network's zero-code depth, decoded once
            prox = [[x[tgt_d]] for x in start_prox]  # per level: [zero code]
        else:
            feats = model.image_features(net_in[tgt_d])
            both = model.decode([torch.cat([f, f]) for f in feats],
                                torch.cat([codes[tgt_d], torch.zeros_like(codes[tgt_d])]))  # 2B decodes
            prox = [[x[:B], x[B:]] for x in both]  # per level: [frames' codes, zero code]
        photo = [torch.zeros((), device=dev), torch.zeros((), device=dev)]
        # the sources' brightness relative to the target's: I_t ~ exp(g_s - g_t) I_s + (o_s - o_t)
        rel_gain = torch.exp(bright[src_d, 0] - bright[tgt_d, 0][:, None])[..., None, None]  # (B, S, 1, 1)
        rel_off = (bright[src_d, 1] - bright[tgt_d, 1][:, None])[..., None, None]
        for lvl in range(levels):
            g_t = gray_pyr[lvl][tgt_d]  # (B, 1, h, w)
            g_s = gray_pyr[lvl][src_d][:, :, 0] * rel_gain + rel_off  # (B, S, h, w)
            v_s = valid_pyr[lvl][src_d][:, :, 0]
            for k, p_lvl in enumerate(prox[lvl]):
                depth = prox_to_depth(p_lvl, model.avg_depth)  # (B, 1, h, w)
                photo[k] = photo[k] + photometric_loss(g_t, depth, g_s, v_s, T_st, cams[lvl], cfg.huber,
                                                       cfg.automask) / levels
        if warm:
            photo[1] = photo[0]  # one depth (the zero code's) in the warm-up, counted once
        prior = cfg.code_prior * 0.5 * codes[tgt_d].square().sum(-1).mean() / (H * W)
        anchor = torch.zeros((), device=dev)
        if not warm and cfg.scale_anchor > 0:
            log_depth = torch.log(prox_to_depth(prox[0][1], model.avg_depth)).mean(dim=(1, 2, 3))  # (B,)
            anchor = anchor + cfg.scale_anchor * (log_depth - start_log_depth[tgt_d]).square().mean()
        if not warm and cfg.anchor > 0:
            moved = sum(((p - start[n].to(p)) ** 2).sum() for n, p in model.named_parameters() if p.requires_grad)
            anchor = anchor + cfg.anchor * 0.5 * moved / n_weights
        loss = (photo[0] if warm else photo[0] + cfg.zero_code_weight * photo[1]) + prior + anchor
        opt.zero_grad(set_to_none=True)
        loss.backward()
        for p, m in masks:
            if p.grad is not None:
                p.grad.mul_(m)
        opt.step()
        acc += torch.tensor([float(loss.detach()), float(photo[0].detach()), float(photo[1].detach()),
                             float(prior.detach())], dtype=torch.float64)
        acc_n += 1
        step_done = step + 1
        if step_done % cfg.log_every == 0 or step_done == end:
            m = (acc / acc_n).tolist()
            last = {"loss": m[0], "photo": m[1], "photo_zero": m[2], "code_prior": m[3],
                    "anchor": float(anchor.detach())}
            log.append({"step": step_done, **{k: f"{v:.6g}" for k, v in last.items()},
                        "seconds": f"{elapsed_before + time.perf_counter() - t0:.1f}"})
            acc.zero_()
            acc_n = 0
        if step_done % cfg.checkpoint_every == 0 or step_done == end:
            save(step_done)
        if progress is not None:
            progress(step_done, cfg.steps, last)
    for p, flag in was_trainable:
        p.requires_grad_(flag)
    delta.requires_grad_(False)
    model.eval()
    finished = end == cfg.steps
    with torch.no_grad():
        poses_out = chain_poses(T0.double(), delta.detach().double().index_fill(0, torch.tensor([0], device=dev), 0))
    if finished:
        save_weights(run_dir / WEIGHTS_NAME, model, extra_metadata={
            "adapted": json.dumps({"adapt": cfg.to_dict(), "frames": N, "source": source or {}}),
            "elapsed_s": f"{elapsed_before + time.perf_counter() - t0:.1f}",
        })
    return AdaptResult(run_dir, end, finished, last, poses_out.cpu())


def _save(path, model, opt, codes, delta, bright, start, step, elapsed, cfg: AdaptConfig) -> None:
    tensors = {f"model.{k}": v for k, v in model.state_dict().items()}
    tensors.update({f"start.{k}": v for k, v in start.items()})
    tensors.update({"codes": codes.detach(), "delta": delta.detach(), "brightness": bright.detach()})
    sd = opt.state_dict()
    for idx, state in sd["state"].items():
        for key, value in state.items():
            tensors[f"optim.{idx}.{key}"] = value if torch.is_tensor(value) else torch.tensor(value)
    groups = [{k: v for k, v in g.items() if k != "params"} | {"params": list(g["params"])}
              for g in sd["param_groups"]]
    save_tensors(path, tensors, {"format": ADAPT_CHECKPOINT_FORMAT, "step": str(step), "elapsed_s": f"{elapsed:.1f}",
                                 "config": model.config.to_json(), "adapt": json.dumps(cfg.to_dict()),
                                 "optim_param_groups": json.dumps(groups)})


def _restore(path, model, opt, codes, delta, bright, start, cfg: AdaptConfig):
    """Load an adaptation checkpoint -> (step, elapsed seconds, start weights)."""
    tensors, meta = read_tensors(path)
    if meta.get("format") != ADAPT_CHECKPOINT_FORMAT:
        raise WeightsError(f"{path} is not a codeslam adaptation checkpoint")
    if meta.get("config") != model.config.to_json():
        raise ConfigError(f"{path} was written for another network")
    saved = json.loads(meta.get("adapt", "{}")).get("trainable", "all")  # checkpoints before the option: all
    if saved != cfg.trainable:
        raise ConfigError(f"{path} adapted trainable={saved!r}; resume it with the same, not {cfg.trainable!r}")
    try:
        model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
        start = {k[6:]: v for k, v in tensors.items() if k.startswith("start.")}
        with torch.no_grad():
            for var, name in ((codes, "codes"), (delta, "delta"), (bright, "brightness")):
                if tensors[name].shape != var.shape:
                    raise ValueError(f"{name} has shape {tuple(tensors[name].shape)}, expected {tuple(var.shape)} "
                                     "(another video or frame range?)")
                var.copy_(tensors[name])
        state: dict[int, dict] = {}
        for name, value in tensors.items():
            if name.startswith("optim."):
                idx, key = name[6:].split(".", 1)
                state.setdefault(int(idx), {})[key] = value
        opt.load_state_dict({"state": state, "param_groups": json.loads(meta["optim_param_groups"])})
        return int(meta["step"]), float(meta.get("elapsed_s", 0.0)), start
    except (KeyError, ValueError, RuntimeError) as e:
        raise WeightsError(f"{path} is not a complete adaptation checkpoint: {' '.join(str(e).split())[:300]}") \
            from None


__all__ = ["AdaptConfig", "AdaptResult", "adapt", "chain_poses", "photometric_loss", "relative_motions",
           "zero_code_parameters"]
