"""``codeslam eval``: ATE and RPE of an estimated trajectory against ground truth (evo's definitions)."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import JsonOut
from codeslam.errors import ConfigError


@app.command("eval")
def eval_command(
    estimate: Path = typer.Argument(..., help="Estimated trajectory (TUM text or EuRoC CSV, detected)."),
    groundtruth: Path = typer.Argument(..., help="Reference trajectory (TUM text or EuRoC CSV, detected)."),
    align: str = typer.Option("se3", "--align", help="Umeyama alignment of the estimate: se3, sim3 or none."),
    delta: float = typer.Option(1.0, "--delta", help="RPE pair spacing (frames, or metres with --delta-unit m)."),
    delta_unit: str = typer.Option("frames", "--delta-unit", help="Unit of --delta: frames or m."),
    max_diff: float = typer.Option(0.01, "--max-diff", help="Largest timestamp difference to match poses (s)."),
    json_out: JsonOut = None,
    plot: Path | None = typer.Option(None, "--plot", help="Write a PNG of the aligned trajectories (xy, xz)."),
    drift_plot: Path | None = typer.Option(
        None, "--drift-plot", help="Write a PNG of translation error against travelled distance."
    ),
) -> None:
    """Absolute trajectory error (after alignment) and relative pose error of ESTIMATE against GROUNDTRUTH."""
    from codeslam.data.trajectory_file import load_trajectory
    from codeslam.eval import metrics
    from codeslam.io import check_output_file

    if align not in metrics.ALIGN_MODES:
        raise ConfigError(f"--align must be one of {', '.join(metrics.ALIGN_MODES)}, got {align!r}")
    if delta_unit not in ("frames", "m"):
        raise ConfigError(f"--delta-unit must be 'frames' or 'm', got {delta_unit!r}")
    for out_path in (json_out, plot, drift_plot):  # refuse unwritable outputs before the work
        if out_path is not None:
            check_output_file(out_path)
    est = load_trajectory(estimate)
    ref = load_trajectory(groundtruth)
    ev = metrics.evaluate(est, ref, align=align, delta=delta, delta_unit=delta_unit, max_diff=max_diff)
    results = ev.summary()
    results.update(estimate=str(estimate), groundtruth=str(groundtruth), n_estimate=len(est),
                   n_groundtruth=len(ref), scale_drift=metrics.scale_drift_or_none(est, ref, max_diff))

    if plot is not None:
        from codeslam.eval.plots import plot_trajectories

        plot_trajectories(plot, ev.ate.est_xyz, ref.positions_xyz.numpy(),
                          title=f"ATE RMSE {ev.ate.rmse:.4f} m ({align} alignment)", est_label=estimate.name,
                          ref_label=groundtruth.name)
    if drift_plot is not None:
        from codeslam.eval.plots import plot_error_vs_distance

        plot_error_vs_distance(drift_plot, ev.drift.distances, ev.drift.errors, label=estimate.name)
    _print_table(results)
    if json_out is not None:  # last, so that a failure above leaves no JSON behind
        from codeslam.io import write_json

        write_json(json_out, results)


def _print_table(res: dict) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    unit = "frames" if res["rpe_delta_unit"] == "frames" else "m"
    table = Table(
        title=escape(f"{res['estimate']} vs {res['groundtruth']}"),
        caption=escape(f"{res['n_matched']} matched poses, {res['align']} alignment, scale {res['scale']:.4f}; "
                       f"RPE over {res['rpe_n_pairs']} pairs {res['rpe_delta']:g} {unit} apart"
                       + ("" if res.get("scale_drift") is None else
                          f"; scale drift {res['scale_drift']:.3f} (the estimate's scale over the last fifth of "
                          f"the path over the first)")),
    )
    table.add_column("metric")
    stats = ("rmse", "mean", "median", "std", "min", "max")
    for col in stats:
        table.add_column(col, justify="right")
    for name, key in (("ATE [m]", "ate_{}"), ("RPE trans [m]", "rpe_trans_{}"), ("RPE rot [deg]", "rpe_rot_{}_deg")):
        table.add_row(escape(name), *(f"{res[key.format(c)]:.4f}" for c in stats))
    console = Console()
    console.print(table)
    console.print(escape(f"ground-truth path length {res['path_length_gt']:.3f} m; error at the last pose with the "
                         f"first pose anchored {res['drift_end_error']:.4f} m"))
