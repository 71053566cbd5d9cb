"""``codeslam adapt``: fine-tune the depth network on a video or dataset without depth (self-supervised)."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import Device, Format, Frames, Quiet, Threads, Weights
from codeslam.errors import ConfigError, DatasetError


def run_dir_for(out: Path) -> Path:
    """The run folder (checkpoint, log, estimated poses) of the weights file ``out``: ``<out stem>_adapt/``."""
    return out.parent / f"{out.stem}_adapt"


@app.command("adapt")
def adapt_command(
    dataset: Path = typer.Argument(..., help="Video file or dataset folder; only its images are used (any depth "
                                   "it holds is ignored)."),
    out: Path = typer.Option(..., "--out", help="Adapted weights (safetensors). Checkpoint, log.csv and the "
                             "estimated poses go to <out stem>_adapt/ beside it."),
    frames: Frames = None,
    fmt: Format = None,
    weights: Weights = None,
    poses: Path | None = typer.Option(None, "--poses", help="Initial camera poses (TUM trajectory file, e.g. "
                                      "from `codeslam slam --out`), matched to the frames by timestamp; "
                                      "default: no motion, estimated in the warm-up."),
    steps: int | None = typer.Option(None, "--steps", help="Adam steps in all (default 400)."),
    warmup: int | None = typer.Option(None, "--warmup", help="Steps that estimate motion only (default 100)."),
    lr: float | None = typer.Option(None, "--lr", help="Learning rate of the network weights (default 1e-3; "
                                    "1e-5 suits --trainable all)."),
    trainable: str | None = typer.Option(None, "--trainable", help="Which weights adapt: zero_code (default: what "
                                         "the zero-code depth depends on and the code Jacobian does not) or all."),
    seed: int | None = typer.Option(None, "--seed", help="Seed of the frame order."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the run folder's checkpoint."),
    stop_after: int | None = typer.Option(None, "--stop-after", help="Stop (with a checkpoint) after this many "
                                          "steps as if interrupted; --resume continues it."),
    device: Device = None,
    threads: Threads = None,
    quiet: Quiet = False,
) -> None:
    """Self-supervised adaptation (the paper's future work): photometric consistency between nearby frames, with
    the camera motion estimated (or given by --poses), one code per frame under the VAE's prior, and the
    network's weights held near the start; writes the adapted weights to --out."""
    import dataclasses
    import shutil

    import numpy as np
    import torch

    from codeslam.cli.common import check_device, open_frames, progress_bar, set_threads
    from codeslam.depthmodel import DepthModel
    from codeslam.io import atomic_path, check_output_file
    from codeslam.network.adapt import WEIGHTS_NAME, AdaptConfig, adapt

    set_threads(threads)
    device = check_device(device)
    check_output_file(out)
    cfg = AdaptConfig()
    overrides = {k: v for k, v in dict(steps=steps, pose_warmup=warmup, lr=lr, seed=seed,
                                       trainable=trainable).items() if v is not None}
    if "steps" in overrides and "pose_warmup" not in overrides:
        overrides["pose_warmup"] = min(cfg.pose_warmup, overrides["steps"] // 4)
    cfg = dataclasses.replace(cfg, **overrides)  # validated by AdaptConfig
    seq, indices = open_frames(dataset, fmt, frames, min_frames=3, what="adapt", increasing=True)
    model = DepthModel.load(weights, device=device)
    images, valid, stamps = [], [], []
    with progress_bar("reading", len(indices), quiet) as update:
        for k, i in enumerate(indices):
            f = model.canonical(seq[i])
            images.append(f.image)
            valid.append(torch.ones_like(f.image[0], dtype=torch.bool) if f.valid is None else f.valid)
            stamps.append(f.timestamp)
            update(k + 1)
    init = None
    if poses is not None:
        from codeslam.data.association import interpolate_poses
        from codeslam.data.trajectory_file import load_trajectory

        traj = load_trajectory(poses)
        init, ok = interpolate_poses(traj, np.array(stamps), max_gap=1.0)
        if not bool(ok.all()):
            raise DatasetError(f"--poses {poses} does not cover frame {indices[int((~ok).nonzero()[0, 0])]} "
                               "(timestamps outside the trajectory)")
    run_dir = run_dir_for(out)
    if resume and not (run_dir / "checkpoint.safetensors").is_file():
        print(f"codeslam: warning: --resume: {run_dir} holds no checkpoint; starting a new run")
    if not resume and (run_dir / "checkpoint.safetensors").is_file():
        raise ConfigError(f"{run_dir} already holds an adaptation run; pass --resume to continue it or choose "
                          "another --out")
    source = {"dataset": str(dataset), "frames": indices, "start_weights": str(weights or "default")}
    with progress_bar("adapting", cfg.steps, quiet) as update:
        result = adapt(model.network, torch.stack(images), run_dir, cfg, valid=torch.stack(valid), poses=init,
                       resume=resume, stop_after=stop_after, source=source,
                       progress=lambda d, n, last: update(d, f"photometric {last.get('photo', float('nan')):.5f}"))
    from codeslam.data.trajectory import Trajectory, write_tum

    write_tum(run_dir / "poses.txt", Trajectory(np.array(stamps), result.poses))
    if not result.finished:
        print(f"stopped at step {result.step} of {cfg.steps}; continue with --resume")
        return
    with atomic_path(out) as tmp:
        shutil.copyfile(run_dir / WEIGHTS_NAME, tmp)
    last = "  ".join(f"{k} {v:.5g}" for k, v in result.last.items())
    print(f"adapted on {len(indices)} frames of {dataset} in {cfg.steps} steps: {last}; wrote {out}")
