"""``codeslam synth``: synthetic indoor RGB-D sequences (TUM layout) or training shards."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import JsonOut, parse_size
from codeslam.errors import ConfigError


@app.command("synth")
def synth_command(
    out: Path = typer.Argument(..., help="Output folder."),
    scenes: int = typer.Option(1, "--scenes", help="Number of sequences (scene_000, scene_001, ...)."),
    frames: int = typer.Option(100, "--frames", help="Frames per sequence (30 per second)."),
    seed: int = typer.Option(0, "--seed", help="Base seed: the same seed gives byte-identical output."),
    size: str | None = typer.Option(
        None, "--size", help="Image size WxH (default 256x192 for sequences, 128x96 for --train)."
    ),
    train: bool = typer.Option(False, "--train", help="Write training shards instead of sequences."),
    views: int = typer.Option(1024, "--views", help="--train: total number of views."),
    views_per_scene: int = typer.Option(16, "--views-per-scene", help="--train: views per random room."),
    shard_size: int = typer.Option(256, "--shard-size", help="--train: views per shard file."),
    workers: int = typer.Option(1, "--workers", help="Worker processes (shards or sequences in parallel)."),
    supersample: int | None = typer.Option(
        None, "--supersample", help="Anti-aliasing: s x s colour rays per pixel (default: 2 sequences, 1 --train)."
    ),
    noise: float = typer.Option(0.0, "--noise", help="Std of Gaussian sensor noise on [0, 1] colours."),
    blur: float = typer.Option(0.0, "--blur", help="Std (pixels) of a Gaussian sensor blur."),
    json_out: JsonOut = None,
) -> None:
    """Render procedurally generated rooms: TUM RGB-D sequences, or with --train shards of random views."""
    import torch
    from rich.console import Console

    from codeslam.geometry.camera import canonical_camera
    from codeslam.io import check_output_dir, check_output_file, write_json
    from codeslam.synth.render import RenderConfig

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
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
    config = RenderConfig(supersample=supersample, noise_std=noise, blur_sigma=blur)
    console = Console(stderr=True)
    if train:
        from codeslam.synth.shards import ShardSpec, write_shards

        spec = ShardSpec(views=views, camera=camera, seed=seed, views_per_scene=views_per_scene,
                         shard_size=shard_size, render=config)
        summary = write_shards(spec, out, workers=workers,
                               progress=lambda d, n: console.print(f"shard {d}/{n}", highlight=False))
        console.print(f"{summary['views']} views in {summary['shards']} shards under {out} "
                      f"({summary['written']} written, {summary['skipped']} already there, "
                      f"{summary['views_per_second']:.1f} views/s)", highlight=False)
    else:
        from codeslam.synth.generate import generate_sequences

        summary = generate_sequences(out, scenes, frames, seed=seed, camera=camera, config=config, workers=workers,
                                     progress=lambda d, n: console.print(f"scene {d}/{n}", highlight=False))
        console.print(f"{scenes} sequences of {frames} frames ({w}x{h}) under {out} in "
                      f"{summary['seconds']:.1f} s ({summary['fps']:.1f} frames/s)", highlight=False)
    if json_out is not None:
        write_json(json_out, summary)
