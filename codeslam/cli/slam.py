"""``codeslam slam DATASET``: run the SLAM system over a sequence and write its trajectory, keyframes, summary
and (with ground truth) its evaluation. A thin shell over :func:`codeslam.slam.pipeline.run_and_write`."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.errors import ConfigError

DEPTH_MODELS = ("network", "standin")


def _device(name: str | None, default: str) -> str:
    """The torch device to run on; ConfigError for an unknown or unavailable one."""
    import torch

    name = default if name is None else name
    try:
        dev = torch.device(name)
    except (RuntimeError, ValueError):
        raise ConfigError(f"unknown device {name!r}; use cpu, cuda or cuda:N") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {name!r} requested but CUDA is not available on this machine")
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"device {name!r} is not supported; use cpu, cuda or cuda:N")
    return name


@app.command("slam")
def slam_command(
    dataset: Path = typer.Argument(..., help="Dataset folder (TUM, EuRoC, SceneNet, TartanAir or image folder)."),
    out: Path = typer.Option(Path("slam_out"), "--out", help="Output folder (trajectory, keyframes, summary)."),
    fmt: str | None = typer.Option(None, "--format", "-f", help="Dataset format; detected when omitted."),
    frames: str | None = typer.Option(None, "--frames", help="START:END[:STEP] of the frames to run on (END "
                                      "exclusive); all frames when omitted."),
    weights: Path | None = typer.Option(None, "--weights", help="Network weights (safetensors); the installed "
                                        "default weights when omitted."),
    config: Path | None = typer.Option(None, "--config", help="YAML overlay of the SLAM configuration."),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the summary to this JSON file."),
    viewer: str = typer.Option("none", "--viewer", help="Live viewer: none or rerun (needs rerun-sdk)."),
    device: str | None = typer.Option(None, "--device", help="cpu, cuda or cuda:N (default: the config's, cpu)."),
    depth_model: str = typer.Option("network", "--depth-model", help="network (the trained network) or standin "
                                    "(a network-free stand-in built from the dataset's own depth, an oracle for "
                                    "testing the tracking and mapping back-end)."),
    threads: int | None = typer.Option(None, "--threads", help="torch CPU threads (default: torch's choice)."),
    size: str = typer.Option("128x96", "--size", help="--depth-model standin: the camera's WIDTHxHEIGHT (the "
                             "network uses its own canonical camera)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Dense monocular SLAM (paper Sec. 4): track, select keyframes, optimise a sliding window of depth codes and
    poses, marginalise old keyframes. Prints the metrics when the dataset has ground truth."""
    import dataclasses

    from codeslam.data.registry import open_dataset
    from codeslam.geometry.camera import canonical_camera
    from codeslam.io import check_outputs, write_json
    from codeslam.slam.config import load_config
    from codeslam.slam.pipeline import parse_frame_range, run_and_write
    from codeslam.viz import VIEWERS, make_visualizer

    if depth_model not in DEPTH_MODELS:
        raise ConfigError(f"--depth-model must be one of {', '.join(DEPTH_MODELS)}, got {depth_model!r}")
    if viewer not in VIEWERS:
        raise ConfigError(f"--viewer must be one of {', '.join(VIEWERS)}, got {viewer!r}")
    if weights is not None and depth_model != "network":
        raise ConfigError("--weights applies to --depth-model network only")
    if threads is not None:
        if threads < 1:
            raise ConfigError(f"--threads must be >= 1, got {threads}")
        import torch

        torch.set_num_threads(threads)
    check_outputs(out, json_out)  # refuse bad output paths before any work
    cfg = load_config(config)
    cfg = dataclasses.replace(cfg, device=_device(device, cfg.device))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        seq = open_dataset(dataset, format=fmt)
    for w in caught:
        print(f"codeslam: warning: {' '.join(str(w.message).split())}", file=sys.stderr)
    frame_range = parse_frame_range(frames, len(seq))

    if depth_model == "network":
        from codeslam.depthmodel import DepthModel
        from codeslam.slam.depth import network_depth_model

        model = DepthModel.load(weights, device=cfg.device)
        factory, camera = network_depth_model(model), model.camera
        model_info = {"depth_model": "network", "weights": str(weights) if weights else "default"}
    else:
        from codeslam.slam.depth import standin_depth_model

        if not seq.has_depth:
            raise ConfigError("--depth-model standin needs a dataset with depth maps; this one has none")
        camera = canonical_camera(*_parse_size(size))
        factory = standin_depth_model(num_levels=cfg.decoder_levels)
        model_info = {"depth_model": "standin (oracle from the dataset's depth)"}
    visualizer = make_visualizer(viewer)

    progress, bar = _progress(len(frame_range), quiet)
    with bar:
        _, summary = run_and_write(seq, cfg, factory, camera, frame_range, out_dir=out, visualizer=visualizer,
                                   progress=progress, dataset=str(dataset), format=seq.format_name,
                                   device=cfg.device, **model_info)
    _print_summary(summary, out)
    if json_out is not None:
        write_json(json_out, summary)


def _parse_size(size: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size must look like WIDTHxHEIGHT (e.g. 128x96), got {size!r}") from None
    if w < 8 or h < 8:
        raise ConfigError(f"--size must be at least 8x8, got {size!r}")
    return w, h


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None


def _progress(total: int, quiet: bool):
    """(progress callback, context manager) for a rich progress bar on stderr (or nothing when quiet)."""
    if quiet:
        return None, _NoBar()
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    bar = Progress(TextColumn("slam"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                   TextColumn("{task.fields[status]}"), console=Console(stderr=True), transient=True)
    task = bar.add_task("slam", total=total, status="")
    keyframes = [0]

    def update(done: int, n: int, result) -> None:
        keyframes[0] += int(result.is_keyframe)
        bar.update(task, completed=done, status=f"{result.status}, {keyframes[0]} keyframes")

    return update, bar


def _print_summary(s: dict, out: Path) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=escape(f"codeslam slam -> {out}"), show_header=False)
    table.add_column("key", style="bold")
    table.add_column("value")
    rows = [
        ("frames", f"{s['frames']} ({s['first_frame']}..{s['last_frame']}), {s['width']}x{s['height']}"),
        ("keyframes", f"{s['keyframes']} ({s['marginalised']} marginalised)"),
        ("tracking failures", str(s["tracking_failures"])),
        ("speed", f"{s['fps']:.2f} frames/s ({s['fps_with_io']:.2f} with reading)"),
        ("depth model", str(s.get("depth_model", ""))),
    ]
    if "ate_se3_rmse" in s:
        rows += [
            ("ATE SE(3)", f"{s['ate_se3_rmse']:.4f} m"),
            ("ATE Sim(3)", f"{s['ate_sim3_rmse']:.4f} m (scale {s['sim3_scale']:.3f})"),
            ("no-motion ATE", f"{s['no_motion_ate_rmse']:.4f} m (aligned {s['no_motion_ate_rmse_aligned']:.4f} m)"),
            ("rotation error", f"{s['rot_err_rmse_deg']:.3f} deg RMSE, {s['rot_err_max_deg']:.3f} deg max "
                               "(relative to the first frame)"),
            ("RPE", f"{s['rpe_trans_rmse']:.4f} m, {s['rpe_rot_rmse_deg']:.3f} deg per frame"),
        ]
    elif "evaluation_error" in s:
        rows.append(("evaluation", s["evaluation_error"]))
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    Console().print(table)
