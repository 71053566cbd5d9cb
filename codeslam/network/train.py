"""Training the code network (paper Sec. 2.2): the loop behind ``codeslam train``, as a library call.

* Data: :mod:`codeslam.network.data` (frames in memory at the canonical camera, deterministic order).
* Optimiser: Adam from ``lr`` (1e-4) to ``lr_final`` (1e-6) over the run (cosine or exponential schedule).
* Loss: :func:`codeslam.network.loss.network_loss`, KL weight ramped up over ``kl_warmup_steps``.
* Outputs in the run folder RUN: ``config.yaml`` (resolved config), ``log.csv`` (averaged training losses),
  ``val.csv`` (validation), ``checkpoint.safetensors`` (model + Adam state + progress, atomically, every
  ``checkpoint_every`` steps / ``checkpoint_minutes``) and at the end ``weights.safetensors``.
* Fine-tuning: ``train.init_weights`` starts from a weights file of the same architecture instead of random
  weights (a resumed run takes its weights from the checkpoint).
* Resume: every random draw of step s is a function of (seed, s, rank) and the data order of epoch e a function
  of (seed, e), so continuing from a checkpoint repeats exactly the steps an uninterrupted run would take.
* Multi-process: under ``torchrun`` (WORLD_SIZE > 1) the model is wrapped in DistributedDataParallel (gloo on
  CPU, nccl on CUDA), each process takes every world-th frame of the epoch's permutation, and only rank 0
  writes files.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.distributed as dist

from codeslam.errors import ConfigError, WeightsError
from codeslam.io import atomic_write, check_output_dir, ensure_dir
from codeslam.network.config import NUM_LEVELS, NetworkConfig, RunConfig, TrainConfig, dump_run_config
from codeslam.network.data import (
    STEP_STREAM,
    DataOrder,
    FrameStore,
    augment_batch,
    load_training_data,
    mix_seed,
    plain_batch,
    split_train_val,
)
from codeslam.network.loss import LossParts, network_loss, proximity_pyramid
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import CHECKPOINT_FORMAT, MODEL_PREFIX, read_tensors, save_tensors, save_weights

CHECKPOINT_NAME = "checkpoint.safetensors"
WEIGHTS_NAME = "weights.safetensors"
LOG_FIELDS = ["step", "epoch", "lr", "kl_weight", "loss", "nll", *[f"nll_l{i}" for i in range(NUM_LEVELS)], "kl",
              "nll_zero", "shape", "images_per_s", "elapsed_s"]
VAL_FIELDS = ["step", "val_loss", "val_nll", "val_kl", "val_rmse_zero", "val_rmse_encode", "val_rmse_const"]
_OPTIM_PREFIX = "optim."


@dataclass
class TrainResult:
    """What :func:`train` reports back."""

    run_dir: Path
    step: int  # completed optimiser steps
    finished: bool  # reached config.train.steps (weights written)
    last_loss: float  # mean training loss over the last logging window
    val: dict[str, float] = field(default_factory=dict)  # last validation metrics
    images_per_s: float = 0.0


def learning_rate(step: int, cfg: TrainConfig) -> float:
    """Learning rate of step ``step`` (0-based): ``lr`` at 0, ``lr_final`` at the last step (Sec. 2.2)."""
    t = step / max(cfg.steps - 1, 1)
    if cfg.lr_schedule == "exponential":
        return cfg.lr * (cfg.lr_final / cfg.lr) ** t
    return cfg.lr_final + 0.5 * (cfg.lr - cfg.lr_final) * (1 + math.cos(math.pi * t))


def kl_weight_at(step: int, cfg: TrainConfig) -> float:
    """KL weight of step ``step``: linear warm-up from 0 to ``kl_weight`` over ``kl_warmup_steps``."""
    if cfg.kl_warmup_steps == 0:
        return cfg.kl_weight
    return cfg.kl_weight * min(1.0, step / cfg.kl_warmup_steps)


# ----------------------------------------------------------------------------------------------- distributed
@dataclass
class _Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0
    owns_group: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def _init_distributed(device: str) -> _Dist:
    """Join the process group torchrun describes in the environment (no-op for a single process)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return _Dist()
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    owns = False
    if device.startswith("cuda") and torch.cuda.is_available():
        torch.cuda.set_device(local_rank)  # nccl needs each process on its own GPU before the group forms
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.startswith("cuda") else "gloo")
        owns = True
    return _Dist(rank, world, local_rank, owns)


def _resolve_device(device: str, d: _Dist) -> torch.device:
    try:
        kind = torch.device(device).type
    except RuntimeError:
        kind = None
    if kind not in ("cpu", "cuda"):
        raise ConfigError(f"--device must be cpu, cuda or cuda:N, got {device!r}")
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ConfigError("--device cuda was requested but no CUDA device is available")
        if d.world > 1:
            return torch.device("cuda", d.local_rank)
    return torch.device(device)


# ----------------------------------------------------------------------------------------------- checkpoints
def _optimizer_tensors(opt: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], str]:
    """Adam state as flat tensors ``optim.<param index>.<key>`` and the param groups (minus params) as JSON."""
    sd = opt.state_dict()
    tensors = {}
    for idx, state in sd["state"].items():
        for key, value in state.items():
            tensors[f"{_OPTIM_PREFIX}{idx}.{key}"] = value if torch.is_tensor(value) else torch.tensor(value)
    groups = [{k: v for k, v in g.items() if k != "params"} | {"params": list(g["params"])} for g in sd["param_groups"]]
    return tensors, json.dumps(groups)


def _load_optimizer(opt: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], groups_json: str) -> None:
    state: dict[int, dict[str, torch.Tensor]] = {}
    for name, value in tensors.items():
        if name.startswith(_OPTIM_PREFIX):
            idx, key = name[len(_OPTIM_PREFIX) :].split(".", 1)
            state.setdefault(int(idx), {})[key] = value
    opt.load_state_dict({"state": state, "param_groups": json.loads(groups_json)})
    params = [p for g in opt.param_groups for p in g["params"]]
    for p in params:  # keep the moments in the parameter's memory format (channels_last)
        for key, value in opt.state.get(p, {}).items():
            if torch.is_tensor(value) and value.shape == p.shape:
                opt.state[p][key] = torch.empty_like(p).copy_(value)


def save_checkpoint(
    path: Path, model: CodeNetwork, opt: torch.optim.Optimizer, step: int, config: RunConfig, extra: dict
) -> None:
    """Model, Adam state and progress in one safetensors file, written atomically."""
    tensors = {MODEL_PREFIX + k: v for k, v in model.state_dict().items()}
    opt_tensors, groups = _optimizer_tensors(opt)
    tensors.update(opt_tensors)
    tensors["rng.torch_cpu"] = torch.get_rng_state()
    meta = {
        "format": CHECKPOINT_FORMAT,
        "step": str(step),
        "config": config.network.to_json(),
        "train_config": config.train.to_json(),
        "optim_param_groups": groups,
        "extra": json.dumps(extra),
    }
    save_tensors(path, tensors, meta)


def read_run_config(run_dir: str | os.PathLike) -> RunConfig:
    """The configuration of the run whose checkpoint lies in ``run_dir`` (for ``--resume``)."""
    path = Path(run_dir) / CHECKPOINT_NAME
    _, meta = read_tensors(path)
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise WeightsError(f"{path} is not a codeslam training checkpoint")
    try:
        return RunConfig(
            NetworkConfig.from_dict(json.loads(meta["config"])), TrainConfig.from_dict(json.loads(meta["train_config"]))
        )
    except (KeyError, json.JSONDecodeError) as e:
        raise WeightsError(f"{path} has a malformed config ({e})") from None


# ----------------------------------------------------------------------------------------------- logging
class _CsvLog:
    """Rows kept in memory and the whole file rewritten atomically on every flush (a few thousand rows at
    most), so a killed run never leaves a half-written line."""

    def __init__(self, path: Path, fields: list[str], resume_step: int | None) -> None:
        self.path, self.fields, self.rows = path, fields, []
        if resume_step is not None and path.is_file():
            with open(path, newline="") as f:
                self.rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]

    def append(self, row: dict) -> None:
        self.rows.append({k: row[k] for k in self.fields})
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.fields)
        writer.writeheader()
        writer.writerows(self.rows)
        with atomic_write(self.path, "w", newline="") as f:
            f.write(buf.getvalue())


# ----------------------------------------------------------------------------------------------- validation
@torch.no_grad()
def validate(
    model: CodeNetwork, store: FrameStore, idx: torch.Tensor, kl_weight: float, batch_size: int
) -> dict[str, float]:
    """Validation metrics over the frames ``idx`` (no augmentation, mean code):

    val_loss / val_nll / val_kl: the paper's loss (NLL + KL) with the encoder's mean code; val_rmse_zero: proximity RMSE
    of the zero code (image-only prediction) at the finest level over valid pixels; val_rmse_encode: that of the
    encoder's mean code; val_rmse_const: that of the best single constant proximity (the set's mean), a baseline.
    """
    was_training = model.training
    model.eval()
    cfg = model.config
    device = next(model.parameters()).device
    sums = dict(loss=0.0, nll=0.0, kl=0.0, se_zero=0.0, se_enc=0.0, p=0.0, p2=0.0, n=0.0)
    for start in range(0, len(idx), batch_size):
        sel = idx[start : start + batch_size].to(store.images.device)
        image, depth = plain_batch(store.images[sel], store.depth[sel], cfg.in_channels)
        image, depth = image.to(device), depth.to(device)
        prox = proximity_pyramid(depth, cfg.avg_depth)
        feats = model.image_features(image)
        mean, logvar = model.encode(feats, prox[0])
        mu = model.decode(feats, mean)
        mu_zero = model.decode(feats, torch.zeros_like(mean))[0]
        parts = network_loss(mu, model.uncertainty(feats), prox, mean, logvar, kl_weight)
        valid = prox[0] > 0
        p = prox[0][valid]
        n = float(valid.sum())
        sums["loss"] += float(parts.total) * len(sel)
        sums["nll"] += float(parts.nll) * len(sel)
        sums["kl"] += float(parts.kl) * len(sel)
        sums["se_zero"] += float((mu_zero[valid] - p).square().sum())
        sums["se_enc"] += float((mu[0][valid] - p).square().sum())
        sums["p"] += float(p.sum())
        sums["p2"] += float(p.square().sum())
        sums["n"] += n
    model.train(was_training)
    n_img, n_px = max(len(idx), 1), max(sums["n"], 1.0)
    mean_p = sums["p"] / n_px
    return {
        "val_loss": sums["loss"] / n_img,
        "val_nll": sums["nll"] / n_img,
        "val_kl": sums["kl"] / n_img,
        "val_rmse_zero": math.sqrt(sums["se_zero"] / n_px),
        "val_rmse_encode": math.sqrt(sums["se_enc"] / n_px),
        "val_rmse_const": math.sqrt(max(sums["p2"] / n_px - mean_p**2, 0.0)),
    }


# ----------------------------------------------------------------------------------------------- the loop
def train_step(
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    store: FrameStore,
    idx: torch.Tensor,
    step: int,
    config: RunConfig,
    lr: float,
    kl_weight: float,
    rank: int,
    device: torch.device,
) -> LossParts:
    """One optimiser step on the frames ``idx`` (B,) of ``store``; every random draw (augmentation and the
    code sample) comes from a generator seeded by (seed, step, rank), so a step can be repeated exactly."""
    tcfg, ncfg = config.train, config.network
    for group in opt.param_groups:
        group["lr"] = lr
    gen = torch.Generator().manual_seed(mix_seed(tcfg.seed, STEP_STREAM, step, rank))
    idx = idx.to(store.images.device)
    image, depth = augment_batch(store.images[idx], store.depth[idx], tcfg, ncfg.in_channels, gen)
    noise = torch.randn(len(idx), ncfg.code_size, generator=gen).to(device)  # eps of the reparameterisation
    image = image.to(device).contiguous(memory_format=torch.channels_last)  # (B, Cin, H, W)
    prox = proximity_pyramid(depth.to(device), ncfg.avg_depth)  # NUM_LEVELS x (B, 1, H / 2^l, W / 2^l)
    prox_zero = None
    if tcfg.code_scale > 0:  # the code path sees each depth at another scale, the zero code the truth
        u = (2 * torch.rand(len(idx), generator=gen) - 1) * tcfg.code_scale
        prox_zero = prox
        scaled = depth * torch.exp(u).to(depth.device).view(-1, 1, 1, 1)  # (B, 1, H, W), holes stay 0
        prox = proximity_pyramid(scaled.to(device), ncfg.avg_depth)
    zero_w, shape_w = tcfg.zero_code_weight, tcfg.shape_weight
    out = net(image, prox[0], sample=True, noise=noise, decode_zero=zero_w > 0 or shape_w > 0)
    parts = network_loss(
        out.mu, out.b, prox, out.code_mean, out.code_logvar, kl_weight, out.mu_zero, zero_w, prox_zero, shape_w
    )
    opt.zero_grad(set_to_none=True)
    parts.total.backward()
    opt.step()
    return parts


def _restore_checkpoint(
    path: Path, model: CodeNetwork, opt: torch.optim.Optimizer, ncfg: NetworkConfig
) -> tuple[int, dict]:
    """Load model, Adam state and RNG state of the checkpoint ``path`` into ``model`` / ``opt`` -> (completed
    steps, the checkpoint's extra progress dict). ConfigError when it holds another network; WeightsError when
    it is incomplete or inconsistent (e.g. edited, or written by another version)."""
    tensors, meta = read_tensors(path)
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise WeightsError(f"{path} is not a codeslam training checkpoint")
    try:
        saved_net = NetworkConfig.from_dict(json.loads(meta["config"]))
    except (KeyError, json.JSONDecodeError, ConfigError) as e:
        raise WeightsError(f"{path} has no valid network config in its metadata ({e})") from None
    if saved_net != ncfg:
        raise ConfigError(f"{path} was trained with a different network config")
    try:
        model.load_state_dict({k[len(MODEL_PREFIX) :]: v for k, v in tensors.items() if k.startswith(MODEL_PREFIX)})
        _load_optimizer(opt, tensors, meta["optim_param_groups"])
        for p in model.parameters():  # Adam moments of another shape would only fail deep inside opt.step()
            for key, value in opt.state.get(p, {}).items():
                if key != "step" and torch.is_tensor(value) and value.shape != p.shape:
                    raise ValueError(f"optimiser state {key} of shape {tuple(value.shape)} for a {tuple(p.shape)} "
                                     "parameter")
        torch.set_rng_state(tensors["rng.torch_cpu"])
        start = int(meta["step"])
        extra = json.loads(meta.get("extra", "{}"))
        if start < 0 or not isinstance(extra, dict):
            raise ValueError(f"step {start}, extra {extra!r}")
    except (KeyError, ValueError, TypeError, RuntimeError, IndexError) as e:
        msg = " ".join(str(e).split())[:300]
        raise WeightsError(f"{path} is not a complete training checkpoint: {type(e).__name__}: {msg}") from None
    return start, extra


def _check_run_dir(run_dir: Path, resume: bool) -> bool:
    """-> whether a checkpoint exists to resume from; ConfigError when a finished or started run would be
    overwritten, OutputError when ``run_dir`` cannot be a folder (a file is in the way)."""
    check_output_dir(run_dir)
    has_ckpt = (run_dir / CHECKPOINT_NAME).is_file()
    if not resume and (has_ckpt or (run_dir / WEIGHTS_NAME).is_file()):
        raise ConfigError(
            f"{run_dir} already holds a training run; pass --resume to continue it or choose another --out"
        )
    return resume and has_ckpt


def train(
    data: list[str | os.PathLike],
    run_dir: str | os.PathLike,
    config: RunConfig | None = None,
    resume: bool = False,
    stop_after: int | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = print,
    store: FrameStore | None = None,
) -> TrainResult:
    """Train (or continue training) the network on ``data`` and write the run folder ``run_dir``.

    Args:
        data: shard folders / shard files / dataset folders (see :mod:`codeslam.network.data`).
        run_dir: output folder (created).
        config: network and training configuration; with ``resume`` and a checkpoint in ``run_dir`` the network
            config must equal the checkpoint's (the training config given here is used, so ``steps`` may grow).
        resume: continue from ``run_dir/checkpoint.safetensors`` if there is one.
        stop_after: stop (with a checkpoint) once this many steps are done, as if interrupted; the schedule
            still spans ``config.train.steps``.
        progress: show a rich progress bar (rank 0 only).
        log: where one-line messages go (rank 0 only); None for silence.
        store: frames already in memory (skips reading ``data``; for tests and notebooks).
    """
    config = config or RunConfig()
    run_dir = Path(run_dir)
    d = _init_distributed(config.train.device)
    try:
        return _train(data, run_dir, config, resume, stop_after, progress, log, store, d)
    finally:
        if d.owns_group:
            dist.destroy_process_group()


def _train(data, run_dir, config, resume, stop_after, progress, log, store, d: _Dist) -> TrainResult:
    tcfg, ncfg = config.train, config.network
    say = log if (log is not None and d.is_main) else (lambda msg: None)
    device = _resolve_device(tcfg.device, d)
    can_resume = _check_run_dir(run_dir, resume)

    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the caller's RNG
        torch.manual_seed(tcfg.seed)
        model = CodeNetwork(ncfg).to(device)
    model = model.to(memory_format=torch.channels_last)  # measured ~25% faster convolutions on a 2-core CPU
    opt = torch.optim.Adam(model.parameters(), lr=tcfg.lr)
    start, elapsed_before, saved_extra = 0, 0.0, {}
    if can_resume:
        start, saved_extra = _restore_checkpoint(run_dir / CHECKPOINT_NAME, model, opt, ncfg)
        elapsed_before = float(saved_extra.get("elapsed_s", 0.0))
        say(f"resuming {run_dir} at step {start}")
    elif resume:
        say(f"warning: --resume: {run_dir} holds no {CHECKPOINT_NAME}; starting a new run")
    if not can_resume and tcfg.init_weights:  # fine-tuning: start from a trained network of the same architecture
        from codeslam.network.weights import load_model

        init = None if tcfg.init_weights == "default" else tcfg.init_weights  # "default": the shipped weights
        model.load_state_dict(load_model(init, device=device, config=ncfg).state_dict())
        say(f"starting from the weights {tcfg.init_weights}")

    if store is None:
        store = load_training_data(list(data), model.camera, tcfg.workers, log=say)
    store = store.to(device)
    train_idx, val_idx = split_train_val(store, tcfg.val_fraction, tcfg.val_max_frames)
    if can_resume and saved_extra.get("frames") not in (None, len(store)):
        say(f"warning: the checkpoint was trained on {saved_extra['frames']} frames, now {len(store)}: the data order "
            "differs from the interrupted run's")
    order = DataOrder(train_idx, tcfg.batch_size, tcfg.seed, d.rank, d.world)
    say(
        f"{len(train_idx)} training / {len(val_idx)} validation frames, {order.steps_per_epoch} steps per epoch, "
        f"{d.world} process(es), device {device}"
    )
    if d.is_main:  # only once the data has loaded: a run that cannot start leaves no run folder behind
        ensure_dir(run_dir)
        with atomic_write(run_dir / "config.yaml") as f:
            f.write(dump_run_config(config))

    net: torch.nn.Module = model
    if d.world > 1:
        ids = [device.index] if device.type == "cuda" else None
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=ids)
    model.train()

    train_log = _CsvLog(run_dir / "log.csv", LOG_FIELDS, start if can_resume else None) if d.is_main else None
    val_log = _CsvLog(run_dir / "val.csv", VAL_FIELDS, start if can_resume else None) if d.is_main else None
    end = tcfg.steps if stop_after is None else min(tcfg.steps, stop_after)
    if start >= end:
        say(f"{run_dir} is already at step {start} of {tcfg.steps}: nothing to do (raise --steps to train on)")
        return TrainResult(run_dir, start, start >= tcfg.steps, float("nan"), saved_extra.get("val", {}))
    acc = torch.zeros(5 + NUM_LEVELS, dtype=torch.float64, device=device)  # loss, nll, kl, nll_zero, shape, levels
    acc_n, t_window, images_window = 0, time.perf_counter(), 0
    t_start, t_ckpt = time.perf_counter(), time.perf_counter()
    last_loss, last_val, rate = float("nan"), {}, 0.0

    def checkpoint(step: int) -> None:
        nonlocal t_ckpt
        if d.is_main:
            extra = {"val": last_val, "elapsed_s": elapsed_before + time.perf_counter() - t_start,
                     "frames": len(store)}
            save_checkpoint(run_dir / CHECKPOINT_NAME, model, opt, step, config, extra)
        t_ckpt = time.perf_counter()

    bar = _progress_bar(progress and d.is_main, start, end, tcfg.steps)
    with bar, _StopOnSignal() as stop:
        for step in range(start, end):
            lr, klw = learning_rate(step, tcfg), kl_weight_at(step, tcfg)
            parts = train_step(net, opt, store, order.batch(step), step, config, lr, klw, d.rank, device)
            with torch.no_grad():  # accumulated on the device: no host sync per step
                acc += torch.stack([parts.total, parts.nll, parts.kl, parts.nll_zero, parts.shape,
                                    *parts.nll_levels]).double()
            acc_n += 1
            images_window += tcfg.batch_size * d.world
            done = step + 1
            stopping = stop.requested
            if d.world > 1:  # agree on stopping, so that every rank takes part in the same collectives
                flag = torch.tensor([float(stopping)], device=device)
                dist.all_reduce(flag, op=dist.ReduceOp.MAX)
                stopping = bool(flag.item())
            last = done == end or stopping  # the loop ends after this step: log and checkpoint it
            if done % tcfg.log_every == 0 or last:
                if d.world > 1:  # every rank logs at the same steps, so this collective always matches
                    dist.all_reduce(acc)
                    acc /= d.world
                mean = (acc / max(acc_n, 1)).tolist()
                now = time.perf_counter()
                rate = images_window / max(now - t_window, 1e-9)
                last_loss = mean[0]
                if train_log is not None:
                    train_log.append({
                        "step": done, "epoch": order.epoch_of(step), "lr": f"{lr:.4g}", "kl_weight": f"{klw:.4g}",
                        "loss": f"{mean[0]:.6f}", "nll": f"{mean[1]:.6f}",
                        **{f"nll_l{i}": f"{mean[5 + i]:.6f}" for i in range(NUM_LEVELS)},
                        "kl": f"{mean[2]:.4f}", "nll_zero": f"{mean[3]:.6f}",
                        "shape": f"{mean[4]:.6f}", "images_per_s": f"{rate:.2f}",
                        "elapsed_s": f"{elapsed_before + now - t_start:.1f}",
                    })
                acc.zero_()
                acc_n, t_window, images_window = 0, now, 0
            if d.is_main and len(val_idx) > 0 and (done % tcfg.val_every == 0 or done == tcfg.steps):
                last_val = validate(model, store, val_idx, tcfg.kl_weight, tcfg.batch_size)
                val_log.append({"step": done, **{k: f"{v:.6f}" for k, v in last_val.items()}})
            minutes = (time.perf_counter() - t_ckpt) / 60.0
            if done % tcfg.checkpoint_every == 0 or last or (d.is_main and minutes >= tcfg.checkpoint_minutes):
                checkpoint(done)
            bar.advance(loss=last_loss, rate=rate, val=last_val.get("val_rmse_zero"))
            if last and done < end:
                say(f"stopped by signal after step {done}; continue with --resume")
                end = done
                break

    finished = end == tcfg.steps
    if finished and d.is_main:
        save_weights(
            run_dir / WEIGHTS_NAME,
            model,
            extra_metadata={
                "steps": str(tcfg.steps),
                "train_config": tcfg.to_json(),
                "train_frames": str(len(train_idx)),
                "world_size": str(d.world),
                "val": json.dumps(last_val),
                "data": json.dumps([str(p) for p in data]),
                "torch": torch.__version__,
                "elapsed_s": f"{elapsed_before + time.perf_counter() - t_start:.1f}",
            },
        )
        say(f"wrote {run_dir / WEIGHTS_NAME}")
    if d.world > 1:
        dist.barrier()
    return TrainResult(run_dir, end, finished, last_loss, last_val, rate)


class _StopOnSignal:
    """While active (in the main thread), SIGINT / SIGTERM only set ``requested``: the loop finishes the current
    step, writes a checkpoint and returns, so Ctrl-C or a scheduler's SIGTERM never loses more than one step (and
    never saves a half-applied optimiser update). SIGKILL is covered by the periodic checkpoints."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, object] = {}

    def _handle(self, signum, frame) -> None:
        self.requested = True

    def __enter__(self) -> _StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def advance(self, **fields) -> None:
        return None


class _RichBar(_NoBar):
    """A rich progress bar with the running loss, throughput and validation RMSE."""

    def __init__(self, start: int, end: int, total: int) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.progress = Progress(
            TextColumn("training"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
            TextColumn("{task.fields[info]}"),
        )
        self.task = self.progress.add_task("train", total=total, completed=start, info="")

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.progress.__exit__(*exc)

    def advance(self, loss: float, rate: float, val: float | None) -> None:
        info = f"loss {loss:.4f}  {rate:.1f} img/s" + ("" if val is None else f"  val rmse(zero) {val:.4f}")
        self.progress.update(self.task, advance=1, info=info)


def _progress_bar(enabled: bool, start: int, end: int, total: int) -> _NoBar:
    return _RichBar(start, end, total) if enabled else _NoBar()
