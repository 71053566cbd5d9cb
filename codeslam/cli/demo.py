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

    from codeslam.io import check_output_dir

    console = Console(stderr=True)
    check_output_dir(out)
    data = out / "data"
    console.print(f"[bold]1/2[/bold] rendering a synthetic room ({frames} frames, seed {seed}) into {data}")
    _run_command(["synth", str(data), "--scenes", "1", "--frames", str(frames), "--seed", str(seed), "--size",
                  "128x96", "--supersample", "2", *(["--quiet"] if quiet else [])])
    console.print(f"[bold]2/2[/bold] running CodeSLAM on {data / 'scene_000'} (results in {out / 'slam'})")
    _run_command(["slam", str(data / "scene_000"), "--out", str(out / "slam"),
                  *(["--weights", str(weights)] if weights is not None else []),
                  *(["--device", device] if device is not None else []),
                  *(["--threads", str(threads)] if threads is not None else []), *(["--quiet"] if quiet else [])])


def _run_command(args: list[str]) -> None:
    """Run one ``codeslam`` command as its command line would, every option not given at its default (calling the
    command functions directly would pass typer's option objects for any option added later). Errors propagate
    to the entry point, which prints them as one line."""
    from typer.main import get_command

    get_command(app).main(args=args, prog_name="codeslam", standalone_mode=False)
