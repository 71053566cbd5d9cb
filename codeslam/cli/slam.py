"""``codeslam slam DATASET``: run the SLAM system over a sequence and write its trajectory, keyframes, summary
and (with ground truth) its evaluation. A thin shell over :func:`codeslam.slam.pipeline.run_slam` and
:func:`codeslam.eval.slam_run.evaluate_run`."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import DatasetArg, Device, Format, Frames, JsonOut, OutDir, Quiet, Threads, Weights, parse_size
from codeslam.errors import ConfigError

DEPTH_MODELS = ("network", "standin")


@app.command("slam")
def slam_command(
    dataset: DatasetArg,
    out: OutDir = Path("slam_out"),
    fmt: Format = None,
    frames: Frames = None,
    weights: Weights = None,
    config: Path | None = typer.Option(None, "--config", help="YAML overlay of the SLAM configuration."),
    json_out: JsonOut = None,
    viewer: str = typer.Option("none", "--viewer", help="Live viewer: none or rerun (needs rerun-sdk)."),
    device: Device = None,
    depth_model: str = typer.Option("network", "--depth-model", help="network (the trained network) or standin "
                                    "(a network-free stand-in built from the dataset's own depth, an oracle for "
                                    "testing the tracking and mapping back-end)."),
    threads: Threads = None,
    size: str = typer.Option("128x96", "--size", help="--depth-model standin: the camera's WIDTHxHEIGHT (the "
                             "network uses its own canonical camera)."),
    quiet: Quiet = False,
) -> None:
    """Dense monocular SLAM (paper Sec. 4): track, select keyframes, optimise a sliding window of depth codes and
    poses, marginalise old keyframes. Runs on every frame unless --frames selects some (at least 2, increasing).
    Writes trajectory.txt, keyframes.txt/.npz, map.ply, config.yaml and result.json under --out (default
    slam_out), and with ground truth prints the metrics and plots trajectory.png."""
    import dataclasses

    from codeslam.cli.common import check_device, open_frames, progress_bar, set_threads
    from codeslam.eval.slam_run import evaluate_run_if_possible, plot_run
    from codeslam.geometry.camera import canonical_camera
    from codeslam.io import check_outputs, write_json
    from codeslam.slam.config import load_config
    from codeslam.slam.pipeline import ground_truth, run_slam, summarise, write_outputs
    from codeslam.slam.system import CodeSLAM
    from codeslam.viz import VIEWERS, make_visualizer

    if depth_model not in DEPTH_MODELS:
        raise ConfigError(f"--depth-model must be one of {', '.join(DEPTH_MODELS)}, got {depth_model!r}")
    if viewer not in VIEWERS:
        raise ConfigError(f"--viewer must be one of {', '.join(VIEWERS)}, got {viewer!r}")
    if weights is not None and depth_model != "network":
        raise ConfigError("--weights applies to --depth-model network only")
    set_threads(threads)
    check_outputs(out, json_out)  # refuse bad output paths before any work
    cfg = load_config(config)
    cfg = dataclasses.replace(cfg, device=check_device(device, cfg.device))
    seq, indices = open_frames(dataset, fmt, frames, min_frames=2, what="SLAM", increasing=True)

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
        camera = canonical_camera(*parse_size(size))
        factory = standin_depth_model(num_levels=cfg.decoder_levels)
        model_info = {"depth_model": "standin (oracle from the dataset's depth)"}
    visualizer = make_visualizer(viewer)

    keyframes = 0
    with progress_bar("slam", len(indices), quiet) as update:
        def progress(done: int, total: int, result) -> None:
            nonlocal keyframes
            keyframes += int(result.is_keyframe)
            update(done, f"{result.status}, {keyframes} keyframes")

        run = run_slam(seq, CodeSLAM(cfg, factory), camera, indices, visualizer, progress)
    gt = ground_truth(seq, indices)
    evaluation = evaluate_run_if_possible(run.trajectory, gt)
    summary = summarise(run, evaluation, dataset=str(dataset), format=seq.format_name, device=cfg.device,
                        **model_info)
    written = {}
    if "ate_se3_rmse" in evaluation:
        written["trajectory.png"] = str(out / "trajectory.png")
        plot_run(written["trajectory.png"], run.trajectory, gt, len(run.keyframes))
    summary["outputs"] = write_outputs(out, run, cfg, summary, written)
    _print_summary(summary, out)
    if json_out is not None:
        write_json(json_out, summary)




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
