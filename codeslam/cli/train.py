"""``codeslam train``: train the code network on generator shards and/or RGB-D dataset folders.

Single process: ``codeslam train --data DIR --out RUN``; several processes / GPUs / nodes:
``torchrun --nproc_per_node N -m codeslam train --data DIR --out RUN`` (DDP; --batch-size is per process).
"""

from __future__ import annotations

import os
from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import Device, Threads, parse_size
from codeslam.errors import ConfigError

#: training options a resumed run may change
_RESUME_MUTABLE = ("steps", "workers", "device")


def _check_resumable(saved, requested) -> None:
    """ConfigError naming the first option that would change a resumed run's network or training."""
    a = {**{f"network.{k}": v for k, v in saved.network.to_dict().items()},
         **{f"train.{k}": v for k, v in saved.train.to_dict().items() if k not in _RESUME_MUTABLE}}
    b = {**{f"network.{k}": v for k, v in requested.network.to_dict().items()},
         **{f"train.{k}": v for k, v in requested.train.to_dict().items() if k not in _RESUME_MUTABLE}}
    changed = [k for k in a if a[k] != b[k]]
    if changed:
        k = changed[0]
        raise ConfigError(f"--resume cannot change {k} ({a[k]} in the checkpoint, {b[k]} requested); only "
                          f"{', '.join('--' + m for m in _RESUME_MUTABLE)} may change")


@app.command("train")
def train_command(
    data: list[Path] = typer.Option(..., "--data", help="Shard folder(s) (shard_*.safetensors) or RGB-D dataset "
                                    "folder(s): --data DIR [DIR ...] (or repeat --data); DIR:W repeats a source's "
                                    "frames W times per epoch (e.g. a small real set among many rendered views)."),
    more_data: list[Path] | None = typer.Argument(None, hidden=True, help="Further --data folders."),
    out: Path = typer.Option(..., "--out", help="Run folder: config.yaml, log.csv, val.csv, checkpoint, weights."),
    config: Path | None = typer.Option(None, "--config", help="YAML with 'network:' and/or 'train:' sections."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its checkpoint "
                                "(without one: a new run, with a warning)."),
    steps: int | None = typer.Option(None, "--steps", help="Total optimiser steps (the schedule's length)."),
    batch_size: int | None = typer.Option(None, "--batch-size", help="Images per step per process."),
    code_size: int | None = typer.Option(None, "--code-size", help="Code entries (128 default, 32 for speed)."),
    size: str | None = typer.Option(None, "--size", help="Canonical image size WIDTHxHEIGHT, multiples of 16."),
    workers: int | None = typer.Option(None, "--workers", help="Threads that load and resample dataset frames."),
    seed: int | None = typer.Option(None, "--seed", help="Seed of weights, data order and augmentation."),
    init: str | None = typer.Option(None, "--init", help="Fine-tune: start from this weights file ('default': the "
                                    "shipped weights) instead of random weights."),
    device: Device = None,
    stop_after: int | None = typer.Option(None, "--stop-after", help="Stop (with a checkpoint) after this many "
                                          "steps as if interrupted; --resume continues it."),
    threads: Threads = None,
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar (log lines only)."),
) -> None:
    """Train the intensity-conditioned depth auto-encoder (paper Sec. 2) and write RUN/weights.safetensors.
    Under torchrun on CPU, --threads defaults to the cores divided by the processes."""
    from codeslam.cli.common import check_device, set_threads
    from codeslam.network.config import RunConfig, load_run_config, overlay
    from codeslam.network.train import read_run_config, train

    if device is not None:
        check_device(device)
    if threads is None and int(os.environ.get("LOCAL_WORLD_SIZE", "1")) > 1 and not (device or "").startswith("cuda"):
        threads = max(1, (os.cpu_count() or 1) // int(os.environ["LOCAL_WORLD_SIZE"]))  # under torchrun on CPU
    set_threads(threads)

    net_opts: dict = {}
    if code_size is not None:
        net_opts["code_size"] = code_size
    if size is not None:
        net_opts["width"], net_opts["height"] = parse_size(size, limits=None)  # NetworkConfig checks them
    train_opts = {k: v for k, v in dict(steps=steps, batch_size=batch_size, workers=workers, seed=seed,
                                         device=device, init_weights=init).items() if v is not None}

    if resume and (out / "checkpoint.safetensors").is_file():
        # the checkpoint's configuration, with the given file / options applied on top: they may repeat the
        # original command, but only --steps, --workers and --device may change a resumed run
        saved = read_run_config(out)
        base = load_run_config(config, base=saved)
        run_config = RunConfig(overlay(base.network, net_opts), overlay(base.train, train_opts))
        _check_resumable(saved, run_config)
    else:
        base = load_run_config(config)
        run_config = RunConfig(overlay(base.network, net_opts), overlay(base.train, train_opts))
    sources = [*data, *(more_data or [])]
    result = train(sources, out, run_config, resume=resume, stop_after=stop_after, progress=not no_progress)
    if int(os.environ.get("RANK", "0")) == 0:
        status = "finished" if result.finished else "stopped"
        val = "  ".join(f"{k} {v:.4f}" for k, v in result.val.items())
        print(f"{status} at step {result.step}: loss {result.last_loss:.4f}  {val}".rstrip())
