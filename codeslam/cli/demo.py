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


@app.command("demo")
def demo_command(
    out: Path = typer.Option(Path("codeslam_demo"), "--out", help="Output folder (data/ and slam/ inside)."),
    frames: int = typer.Option(60, "--frames", help="Frames of the synthetic sequence (30 per second)."),
    seed: int = typer.Option(3, "--seed", help="Seed of the synthetic room and camera path."),
    weights: Path | None = typer.Option(None, "--weights", help="Network weights (default: the shipped weights)."),
    threads: int | None = typer.Option(None, "--threads", help="torch CPU threads (default: torch's choice)."),
    device: str | None = typer.Option(None, "--device", help="cpu, cuda or cuda:N."),
) -> None:
    """Render a synthetic room, run CodeSLAM on it with the shipped weights, evaluate against ground truth."""
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
                 size="128x96", quiet=False)
