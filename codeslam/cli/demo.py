"""``codeslam demo``: the main job on the embedded default data, with nothing to download.

It renders one furnished room with the synthetic generator (``codeslam synth``), runs the SLAM system on it
with the shipped network weights (``codeslam slam``), and evaluates the trajectory against the generator's
exact ground truth. It is exactly those two commands in sequence, so what it prints can be reproduced with
them.
"""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import Device, OutDir, Quiet, Threads, Weights


@app.command("demo")
def demo_command(
    out: OutDir = Path("codeslam_demo"),
    frames: int = typer.Option(60, "--frames", help="How many frames to render (30 per second); SLAM runs on all "
                               "of them."),
    seed: int = typer.Option(3, "--seed", help="Seed of the synthetic room and camera path."),
    weights: Weights = None,
    threads: Threads = None,
    device: Device = None,
    quiet: Quiet = False,
) -> None:
    """Render a synthetic room, run CodeSLAM on it with the shipped weights, evaluate against ground truth.
    Writes the sequence to data/ and the SLAM outputs to slam/ under --out (default codeslam_demo)."""
    from rich.console import Console

    from codeslam.cli.slam import slam_command
    from codeslam.cli.synth import synth_command
    from codeslam.io import check_output_dir

    console = Console(stderr=True)
    check_output_dir(out)
    data = out / "data"
    console.print(f"[bold]1/2[/bold] rendering a synthetic room ({frames} frames, seed {seed}) into {data}")
    synth_command(out=data, scenes=1, frames=frames, seed=seed, size="128x96", train=False, views=0,
                  views_per_scene=1, shard_size=1, workers=1, supersample=2, noise=0.0, blur=0.0, json_out=None)
    console.print(f"[bold]2/2[/bold] running CodeSLAM on {data / 'scene_000'} (results in {out / 'slam'})")
    slam_command(dataset=data / "scene_000", out=out / "slam", fmt=None, frames=None, weights=weights,
                 config=None, json_out=None, viewer="none", device=device, depth_model="network", threads=threads,
                 size="128x96", quiet=quiet)
