"""``codeslam synth``: synthetic indoor RGB-D sequences (TUM layout) or training shards."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import JsonOut, Quiet, parse_size
from codeslam.errors import ConfigError


@app.command("synth")
def synth_command(
    out: Path = typer.Argument(..., help="Output folder."),
    scenes: int = typer.Option(1, "--scenes", help="Number of sequences (scene_000, scene_001, ...)."),
    frames: int = typer.Option(100, "--frames", help="Frames per sequence (at --fps frames per second)."),
    motion: str | None = typer.Option(
        None, "--motion", help="Camera path preset: handheld (0.3-0.6 m/s, up to 45 deg/s), walk (0.8-1.5 m/s "
        "through a large room, up to 60 deg/s), fast-turn (standing, pans up to 90 deg/s), corridor (0.8-1.4 "
        "m/s along a bare corridor of 10-20 m: forward motion); default: the slow original path."),
    fps: float = typer.Option(30.0, "--fps", help="Frames per second of the sequences (the motion per frame "
                              "follows from the preset's speeds)."),
    seed: int = typer.Option(0, "--seed", help="Base seed: the same seed gives byte-identical output."),
    size: str | None = typer.Option(
        None, "--size", help="Image size WxH (default 256x192 for sequences, 128x96 for --train)."
    ),
    train: bool = typer.Option(False, "--train", help="Write training shards instead of sequences."),
    views: int = typer.Option(1024, "--views", help="--train: total number of views."),
    views_per_scene: int = typer.Option(16, "--views-per-scene", help="--train: views per random room."),
    shard_size: int = typer.Option(256, "--shard-size", help="--train: views per shard file."),
    data_version: int = typer.Option(1, "--data-version", help="--train: 1 = furnished rooms of 3-7 m seen from "
                                     "close by; 2 = also large rooms, open-plan, corridors, ceilings to 4 m and half "
                                     "the views along the room from standing or sitting height (depth to 13 m); "
                                     "3 = version 2's rooms, views along the room and at things from a person's "
                                     "height; 4 = the motion presets' rooms, views along their camera paths."),
    workers: int = typer.Option(1, "--workers", help="Worker processes (shards or sequences in parallel)."),
    supersample: int | None = typer.Option(
        None, "--supersample", help="Anti-aliasing: s x s colour rays per pixel (default: 2 sequences, 1 --train)."
    ),
    noise: float = typer.Option(0.0, "--noise", help="Std of Gaussian sensor noise on [0, 1] colours."),
    blur: float = typer.Option(0.0, "--blur", help="Std (pixels) of a Gaussian sensor blur."),
    video: bool = typer.Option(False, "--video", help="Sequences: also encode each as OUT/scene_NNN.mp4 (at "
                               "--fps), to try the video path: codeslam slam OUT/scene_000.mp4 --fov 60."),
    json_out: JsonOut = None,
    quiet: Quiet = False,
) -> None:
    """Render procedurally generated rooms: TUM RGB-D sequences, or with --train shards of random views."""
    import torch
    from rich.console import Console

    from codeslam.cli.common import progress_bar
    from codeslam.geometry.camera import canonical_camera
    from codeslam.io import check_output_dir, check_output_file, write_json
    from codeslam.synth.motion import PRESETS
    from codeslam.synth.render import RenderConfig

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if motion is not None and motion not in PRESETS:
        raise ConfigError(f"--motion must be one of {', '.join(PRESETS)}, got {motion!r}")
    if train and motion is not None:
        raise ConfigError("--motion sets the camera path of sequences; --train renders random views")
    if not (fps > 0 and fps < float("inf")):
        raise ConfigError(f"--fps must be a positive number, got {fps}")
    check_output_dir(out)  # refuse unwritable outputs before rendering
    if json_out is not None:
        check_output_file(json_out)
    # This command owns its process: render single-threaded, like the workers. The renderer works on
    # cache-sized chunks below torch's parallel grain; intra-op threads only add synchronisation, which
    # was measured to slow rendering down by 10-100x on a loaded machine.
    torch.set_num_threads(1)
    w, h = parse_size(size) if size else ((128, 96) if train else (256, 192))
    camera = canonical_camera(w, h)
    if supersample is None:
        supersample = 1 if train else 2
    if data_version != 1 and not train:
        raise ConfigError("--data-version chooses the rooms and views of --train shards")
    if video and (train or w % 2 or h % 2):
        raise ConfigError("--video encodes sequences (not --train shards) and needs an even width and height, "
                          f"got --size {w}x{h}")
    from codeslam.synth.shards import V2_MAX_DEPTH

    max_depth = V2_MAX_DEPTH if data_version >= 2 else RenderConfig.max_depth
    config = RenderConfig(supersample=supersample, noise_std=noise, blur_sigma=blur, max_depth=max_depth)
    console = Console(stderr=True)
    if train:
        from codeslam.synth.shards import ShardSpec, write_shards

        spec = ShardSpec(views=views, camera=camera, seed=seed, views_per_scene=views_per_scene,
                         shard_size=shard_size, render=config, version=data_version)
        with progress_bar("shards", spec.num_shards, quiet) as update:
            summary = write_shards(spec, out, workers=workers, progress=lambda d, n: update(d))
        console.print(f"{summary['views']} views in {summary['shards']} shards under {out} "
                      f"({summary['written']} written, {summary['skipped']} already there, "
                      f"{summary['views_per_second']:.1f} views/s)", highlight=False)
    else:
        from codeslam.synth.generate import generate_sequences

        with progress_bar("synth", scenes * frames, quiet) as update:
            summary = generate_sequences(out, scenes, frames, seed=seed, camera=camera, config=config, fps=fps,
                                         workers=workers, motion=motion,
                                         progress=lambda d, n: update(d, f"scene {min(d // frames, scenes - 1) + 1}"
                                                                         f"/{scenes}"))
        path = f"'{motion}' paths at {fps:g} frames/s" if motion else f"the default path at {fps:g} frames/s"
        console.print(f"{scenes} sequences of {frames} frames ({w}x{h}, {path}) under {out} in "
                      f"{summary['seconds']:.1f} s ({summary['fps']:.1f} frames/s rendered)", highlight=False)
        if video:
            summary["videos"] = [str(_encode_sequence(Path(p), fps)) for p in summary["paths"]]
            console.print(f"videos: {', '.join(summary['videos'])}", highlight=False)
    if json_out is not None:
        write_json(json_out, summary)


def _encode_sequence(folder: Path, fps: float) -> Path:
    """Encode a rendered sequence's colour frames as ``FOLDER.mp4`` beside it (no depth, no poses: what a phone
    gives)."""
    from codeslam.data.registry import open_dataset
    from codeslam.data.video import write_video

    seq = open_dataset(folder)
    return write_video(folder.with_suffix(".mp4"), (seq[i].image for i in range(len(seq))), fps=fps)
