"""``codeslam slam DATASET``: run the SLAM system over a sequence and write its trajectory, keyframes, summary
and (with ground truth) its evaluation. A thin shell over :func:`codeslam.slam.pipeline.run_slam` and
:func:`codeslam.eval.slam_run.evaluate_run`."""

from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer

from codeslam.cli.app import app
from codeslam.cli.common import DatasetArg, Device, Format, Frames, JsonOut, OutDir, Quiet, Threads, Weights, parse_size
from codeslam.errors import ConfigError

DEPTH_MODELS = ("network", "standin", "true-prior")
#: The depth models built from the dataset's own depth (oracles, for diagnosis).
ORACLE_DEPTH_MODELS = ("standin", "true-prior")

# Options of a SLAM run (`slam` and `evaluate` share them).
SlamConfigFile = Annotated[Path | None, typer.Option("--config", help="YAML overlay of the SLAM configuration.")]
DepthModelName = Annotated[str, typer.Option(
    "--depth-model", help="network (the trained network), standin (a network-free stand-in built from the "
    "dataset's own depth, an oracle for testing the tracking and mapping back-end) or true-prior (the network's "
    "code Jacobian with the zero code at the dataset's depth, an oracle for the network's prior alone).")]
MappingMode = Annotated[bool, typer.Option(
    "--sequential/--parallel", help="Map inline after each keyframe's tracking (deterministic, for tests and "
    "debugging) or on a thread beside the tracking (PTAM-like; tracking waits only when its keyframe leaves the "
    "view).")]
Realtime = Annotated[bool, typer.Option(
    "--realtime", help="Run as a live camera feeds the system: the frames arrive at the recording's own times (its "
    "timestamps) and a frame that arrives while the system is busy with an earlier one is skipped (DSO's realtime "
    "mode); the summary counts the frames skipped. Every frame is processed once (no rolling-shutter restart).")]
Speed = Annotated[float | None, typer.Option(
    "--speed", help="--realtime: play the recording this many times faster (0.5: at half its rate; default 1).")]
StandinSize = Annotated[str, typer.Option(
    "--size", help="--depth-model standin: the camera's WIDTHxHEIGHT (the network uses its own canonical camera).")]

# Options of a video input (a dataset folder carries its own camera and is subsampled with --frames).
VideoCamera = Annotated[Path | None, typer.Option(
    "--camera", help="Video: calibration file (camera.yaml: fx, fy, cx, cy, optional width, height, dist); without "
    "it the intrinsics are guessed from --fov.")]
VideoFov = Annotated[float | None, typer.Option(
    "--fov", help="Video without --camera: horizontal field of view in degrees to guess the intrinsics from "
    "(default 60, stated in the summary and report).")]
VideoFps = Annotated[float | None, typer.Option("--fps", help="Video: keep at most this many frames per second.")]
VideoEvery = Annotated[int | None, typer.Option("--every", help="Video: keep every N-th frame (after --fps).")]


@dataclass(frozen=True)
class RunOptions:
    """The options every SLAM run of ``slam`` and ``evaluate`` takes, defined once (:func:`with_run_options`)."""

    fmt: str | None = None
    frames: str | None = None
    weights: Path | None = None
    config: Path | None = None
    device: str | None = None
    depth_model: str = "network"
    threads: int | None = None
    size: str = "128x96"
    sequential: bool = True
    realtime: bool = False
    speed: float | None = None
    camera: Path | None = None
    fov: float | None = None
    fps: float | None = None
    every: int | None = None
    quiet: bool = False


# (name, type with its typer option, default) of every RunOptions field, in the order --help lists them.
_RUN_OPTION_TYPES = (
    ("fmt", Format), ("frames", Frames), ("weights", Weights), ("config", SlamConfigFile), ("device", Device),
    ("depth_model", DepthModelName), ("threads", Threads), ("size", StandinSize), ("sequential", MappingMode),
    ("realtime", Realtime), ("speed", Speed), ("camera", VideoCamera), ("fov", VideoFov), ("fps", VideoFps),
    ("every", VideoEvery), ("quiet", Quiet),
)


def with_run_options(command):
    """Give a command the options of :class:`RunOptions` (appended to its signature, so typer lists them) and
    call it with them gathered in one ``opts: RunOptions`` argument: the two commands that run SLAM declare them
    once, here."""
    sig = inspect.signature(command, eval_str=True)
    defaults = RunOptions()
    extra = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=getattr(defaults, name), annotation=t)
             for name, t in _RUN_OPTION_TYPES]
    params = [p for p in sig.parameters.values() if p.name != "opts"] + extra

    @functools.wraps(command)
    def wrapper(**kwargs):
        opts = RunOptions(**{name: kwargs.pop(name) for name, _ in _RUN_OPTION_TYPES})
        return command(opts=opts, **kwargs)

    wrapper.__signature__ = sig.replace(parameters=params)
    wrapper.__annotations__ = {p.name: p.annotation for p in params}
    return wrapper


@dataclass
class SlamSetup:
    """What every run of a ``slam`` or ``evaluate`` invocation shares: the configuration, the depth model (loaded
    once) and the camera the system runs in."""

    cfg: object  # SLAMConfig
    factory: object  # DepthModelFactory
    camera: object  # PinholeCamera
    depth_model: str
    model_info: dict
    parallel: bool = False


def setup_slam(config: Path | None, weights: Path | None, device: str | None, depth_model: str,
               size: str, sequential: bool = True) -> SlamSetup:
    """Check the options and load the configuration and the depth model (ConfigError / WeightsError, one line)."""
    import dataclasses

    from codeslam.cli.common import check_device
    from codeslam.geometry.camera import canonical_camera
    from codeslam.slam.config import load_config

    if depth_model not in DEPTH_MODELS:
        raise ConfigError(f"--depth-model must be one of {', '.join(DEPTH_MODELS)}, got {depth_model!r}")
    if weights is not None and depth_model == "standin":
        raise ConfigError("--weights applies to --depth-model network and true-prior only")
    cfg = load_config(config)
    cfg = dataclasses.replace(cfg, device=check_device(device, cfg.device))
    mode = "sequential" if sequential else "parallel"
    if depth_model in ("network", "true-prior"):
        from codeslam.depthmodel import DepthModel
        from codeslam.network.jacobian import jacobian_dtype
        from codeslam.slam.depth import network_depth_model, true_prior_depth_model

        model = DepthModel.load(weights, device=cfg.device)
        jac_dtype = jacobian_dtype(cfg.jacobian_dtype, cfg.device, cfg.torch_dtype)
        factory, name = network_depth_model(model, jac_dtype), "network"
        if depth_model == "true-prior":
            factory = true_prior_depth_model(factory)
            name = "true-prior (the network's code Jacobian, the zero code at the dataset's depth: an oracle)"
        return SlamSetup(cfg, factory, model.camera, depth_model,
                         {"depth_model": name, "weights": str(weights) if weights else "default",
                          "code_jacobian": str(jac_dtype).removeprefix("torch."), "mapping": mode}, not sequential)
    from codeslam.slam.depth import standin_depth_model

    return SlamSetup(cfg, standin_depth_model(num_levels=cfg.decoder_levels), canonical_camera(*parse_size(size)),
                     depth_model, {"depth_model": "standin (oracle from the dataset's depth)", "mapping": mode},
                     not sequential)


def live_option(realtime: bool, speed: float | None):
    """The live run of ``--realtime`` (:class:`~codeslam.slam.pipeline.Live`, at ``--speed``), or None offline;
    ConfigError for a speed without ``--realtime`` (Live refuses one that is not positive)."""
    if speed is not None and not realtime:
        raise ConfigError("--speed applies to a --realtime run only")
    if not realtime:
        return None
    from codeslam.slam.pipeline import Live

    return Live(1.0 if speed is None else speed)


def video_options(dataset: Path, fmt: str | None, camera: Path | None, fov: float | None, fps: float | None,
                  every: int | None) -> dict:
    """The video reader's options for ``dataset`` ({} for a dataset folder); ConfigError when one is given for a
    dataset that is not a video."""
    from codeslam.data.video import is_video_file

    given = {k: v for k, v in (("camera", camera), ("fov", fov), ("fps", fps), ("every", every)) if v is not None}
    is_video = fmt == "video" or (fmt is None and Path(dataset).is_file() and is_video_file(dataset))
    if given and not is_video:
        flags = ", ".join(f"--{k}" for k in given)
        raise ConfigError(f"{flags} apply to a video file only; {dataset} is not one (a dataset folder carries its "
                          "own camera; --frames START:END:STEP subsamples it)")
    return given


def run_to_folder(seq, indices: list[int], dataset: Path, out: Path, setup: SlamSetup, viewer: str = "none",
                  quiet: bool = False, label: str = "slam", live=None) -> dict:
    """Run SLAM on ``indices`` of ``seq`` and write the run folder ``out``: the runner's files, with ground truth
    the evaluation, its plot and the ground truth of the processed frames, then ``report.html``. Returns the
    summary (as in result.json). ``live``: a live run (:func:`live_option`), None offline."""
    from codeslam.cli.common import progress_bar
    from codeslam.clock import StageClock
    from codeslam.eval.slam_run import evaluate_run_if_possible, plot_run
    from codeslam.report import write_groundtruth, write_report
    from codeslam.report.run import REPORT_FILE
    from codeslam.slam.pipeline import ground_truth, run_slam, summarise, write_outputs
    from codeslam.slam.system import CodeSLAM
    from codeslam.viz import make_visualizer

    if setup.depth_model in ORACLE_DEPTH_MODELS and not seq.has_depth:
        raise ConfigError(f"--depth-model {setup.depth_model} needs a dataset with depth maps; {dataset} has none")
    keyframes = 0
    with progress_bar(label, len(indices), quiet) as update:
        def progress(done: int, total: int, result) -> None:
            nonlocal keyframes
            keyframes = (0 if done == 1 else keyframes) + int(result.is_keyframe)  # (a second pass starts at 1)
            update(done, f"{result.status}, {keyframes} keyframes")

        system = CodeSLAM(setup.cfg, setup.factory, parallel=setup.parallel, clock=StageClock(setup.cfg.device))
        run = run_slam(seq, system, setup.camera, indices, make_visualizer(viewer), progress, live=live)
    gt = ground_truth(seq, [r.index for r in run.results] if live is not None else indices)
    evaluation = evaluate_run_if_possible(run.trajectory, gt)
    source = seq.describe() if hasattr(seq, "describe") else {}  # a video: its rate and how the camera was found
    summary = summarise(run, evaluation, dataset=str(dataset), format=seq.format_name, device=setup.cfg.device,
                        **setup.model_info, **source)
    written = {}
    if "ate_se3_rmse" in evaluation:
        written["trajectory.png"] = str(out / "trajectory.png")
        plot_run(written["trajectory.png"], run.trajectory, gt, len(run.keyframes))
    if write_groundtruth(out, gt) is not None:  # for the report, rebuilt from the folder alone
        written["groundtruth.txt"] = str(out / "groundtruth.txt")
    written[REPORT_FILE] = str(out / REPORT_FILE)
    summary["outputs"] = write_outputs(out, run, setup.cfg, summary, written)
    write_report(out)  # reads result.json, so after it
    return summary


@app.command("slam")
@with_run_options
def slam_command(
    dataset: DatasetArg,
    out: OutDir = Path("slam_out"),
    json_out: JsonOut = None,
    viewer: Annotated[str, typer.Option("--viewer", help="Live viewer: none or rerun (needs rerun-sdk).")] = "none",
    opts: RunOptions = RunOptions(),
) -> None:
    """Dense monocular SLAM (paper Sec. 4): track, select keyframes, optimise a sliding window of depth codes and
    poses, marginalise old keyframes. DATASET is a dataset folder or a video file (a phone's MP4: --camera
    camera.yaml, or a --fov guess). Runs on every frame unless --frames selects some (at least 2, increasing).
    Writes trajectory.txt, keyframes.txt/.npz, map.ply, config.yaml, result.json and report.html (open it in a
    browser) under --out (default slam_out); with ground truth prints the metrics and plots trajectory.png."""
    from codeslam.cli.common import open_frames, set_threads
    from codeslam.io import check_outputs, write_json
    from codeslam.viz import VIEWERS

    if viewer not in VIEWERS:
        raise ConfigError(f"--viewer must be one of {', '.join(VIEWERS)}, got {viewer!r}")
    o = opts
    set_threads(o.threads)
    check_outputs(out, json_out)  # refuse bad output paths before any work
    live = live_option(o.realtime, o.speed)
    options = video_options(dataset, o.fmt, o.camera, o.fov, o.fps, o.every)
    setup = setup_slam(o.config, o.weights, o.device, o.depth_model, o.size, o.sequential)
    seq, indices = open_frames(dataset, o.fmt, o.frames, min_frames=2, what="SLAM", increasing=True,
                               options=options)
    summary = run_to_folder(seq, indices, dataset, out, setup, viewer, o.quiet, live=live)
    _print_summary(summary, out)
    if json_out is not None:
        write_json(json_out, summary)


def _readout_text(rs: dict) -> str:
    """The summary's line on the readout chosen online (``result.json``'s ``rolling_shutter``)."""
    if rs["readout"] is None:
        return f"readout not decided ({rs['frames']} turning frames, too few)"
    r = rs["readout"]
    what = f"readout {abs(r):.2f} of the frame interval" + (", rows read bottom up" if r < 0 else "") if r \
        else "global shutter"
    if rs["decided_at_frame"] is None:
        return f"{what} (provisional, from {rs['frames']} turning frames)"
    again = (f"; the first {rs['restarted_after_frames']} frames processed again with it"
             if rs.get("restarted_after_frames") else "")
    return f"{what} (chosen at frame {rs['decided_at_frame']} from {rs['frames']} turning frames{again})"


def _print_summary(s: dict, out: Path) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from codeslam.report.run import live_text, map_scale_text, mapping_text, trajectory_text

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
    if s.get("segments", 1) > 1:  # tracking was lost long enough to start again
        merged = len(s.get("segment_merges", []))
        rows.append(("map segments", f"{s['segments']} ({merged} merged into an older map)"))
    if (live := live_text(s)) is not None:  # --realtime
        rows.append(("live", live))
    if "camera" in s:  # a video: the calibration file, or the field-of-view guess
        rows.append(("camera", str(s["camera"])))
    rs = s.get("rolling_shutter")
    if isinstance(rs, dict):  # tracker.rolling_shutter_estimate
        rows.append(("rolling shutter", _readout_text(rs)))
    if (mapping := mapping_text(s)) is not None:
        rows.append(("mapping", mapping))
    if (scale := map_scale_text(s)) is not None:
        rows.append(("map scale", scale))
    if s.get("trajectory_smoothing_s"):
        rows.append(("trajectory", trajectory_text(s["trajectory_smoothing_s"])))
    if "ate_se3_rmse" in s:
        rows += [
            ("ATE SE(3)", f"{s['ate_se3_rmse']:.4f} m"),
            ("ATE Sim(3)", f"{s['ate_sim3_rmse']:.4f} m (scale {s['sim3_scale']:.3f}"
                           + ("" if s.get("scale_drift") is None else
                              f"; the map's scale at the end {s['scale_drift']:.2f}x its scale at the start")
                           + ")"),
            ("no-motion ATE", f"{s['no_motion_ate_rmse']:.4f} m (aligned {s['no_motion_ate_rmse_aligned']:.4f} m)"),
            ("rotation error", f"{s['rot_aligned_rmse_deg']:.3f} deg RMSE after the best rotation alignment "
                               f"({s['rot_err_rmse_deg']:.3f} deg relative to the first frame)"),
            ("RPE", f"{s['rpe_trans_rmse']:.4f} m ({s['rpe_trans_sim3_rmse']:.4f} m after the Sim(3) scale), "
                    f"{s['rpe_rot_rmse_deg']:.3f} deg per frame"),
        ]
    elif "evaluation_error" in s:
        rows.append(("evaluation", s["evaluation_error"]))
    if "report.html" in s.get("outputs", {}):
        rows.append(("report", s["outputs"]["report.html"]))
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    Console().print(table)
