"""``codeslam evaluate DATASET... --out DIR``: SLAM on several sequences with the same settings, one table.

Each dataset gets its own run folder under DIR (exactly what ``codeslam slam`` writes, report included), made by
the same function as a single run, so the table's numbers are those the single runs give. The table, as papers
and evo users expect it, goes to DIR/results.md (rounded, for reading) and DIR/results.csv (full precision, for
scripts). (``codeslam eval EST GT`` compares two trajectory files; this command runs the system.)
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Annotated

import typer

from codeslam.cli.app import app
from codeslam.cli.slam import RunOptions, with_run_options
from codeslam.errors import ConfigError

#: The table's columns: (CSV name, Markdown header, summary key, decimals in Markdown). Without ground truth the
#: metric cells are empty (CSV) or "n/a" (Markdown).
COLUMNS = (
    ("sequence", "sequence", None, None),
    ("frames", "frames", "frames", 0),
    ("failed", "failed", "tracking_failures", 0),
    ("ate_se3_m", "ATE SE(3) [m]", "ate_se3_rmse", 4),
    ("ate_sim3_m", "ATE Sim(3) [m]", "ate_sim3_rmse", 4),
    ("never_moving_ate_m", "never-moving ATE [m]", "no_motion_ate_rmse_aligned", 4),
    ("rot_err_deg", "rot. error [deg]", "rot_aligned_rmse_deg", 2),
    ("rpe_trans_m", "RPE [m]", "rpe_trans_rmse", 4),
    ("rpe_trans_sim3_m", "RPE Sim(3) [m]", "rpe_trans_sim3_rmse", 4),
    ("rpe_rot_deg", "RPE [deg]", "rpe_rot_rmse_deg", 3),
    ("sim3_scale", "scale", "sim3_scale", 3),
    ("scale_drift", "scale drift", "scale_drift", 2),
    ("fps", "frames/s", "fps", 2),
)
RESULTS_MD, RESULTS_CSV = "results.md", "results.csv"


def run_names(datasets: list[Path]) -> list[str]:
    """A folder name per dataset: its own name (a video's without the extension); names that clash get their
    parent's name in front, and any clash left a number behind."""
    base = [Path(d).stem if Path(d).is_file() else Path(d).resolve().name for d in datasets]
    names = [f"{Path(d).resolve().parent.name}_{b}" if base.count(b) > 1 else b for d, b in zip(datasets, base)]
    out: list[str] = []
    for n in names:
        k, name = 1, n
        while name in out:
            k += 1
            name = f"{n}_{k}"
        out.append(name)
    return out


def table_rows(names: list[str], summaries: list[dict]) -> list[dict]:
    """One dict per run, keyed by the CSV column names; None where the run has no such value."""
    rows = []
    for name, s in zip(names, summaries):
        row = {"sequence": name}
        for col, _, key, _ in COLUMNS[1:]:
            row[col] = s.get(key)
        rows.append(row)
    return rows


def results_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([c for c, _, _, _ in COLUMNS])
    for r in rows:
        w.writerow(["" if r[c] is None else (repr(float(r[c])) if isinstance(r[c], float) else r[c])
                    for c, _, _, _ in COLUMNS])
    return buf.getvalue()


def results_markdown(rows: list[dict], settings: str) -> str:
    def cell(v, digits):
        if v is None:
            return "n/a"
        return str(v) if digits is None else f"{float(v):.{digits}f}"

    lines = ["# codeslam evaluate", "", settings, "",
             "| " + " | ".join(h for _, h, _, _ in COLUMNS) + " |",
             "|" + "|".join("---" if k == 0 else "---:" for k in range(len(COLUMNS))) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(cell(r[c], d) for c, _, _, d in COLUMNS) + " |")
    lines += ["", "ATE: RMSE of the camera positions after Umeyama alignment (SE(3), and Sim(3) with the scale shown). "
              "never-moving ATE: the best a camera that never moves could do (the positions' RMS distance to their "
              "mean). rot. error: RMSE of the orientation after the best rotation alignment. RPE: per-frame "
              "relative pose error (RMSE). scale drift: the map's scale over the last fifth of the path over its "
              "scale over the first (n/a where the camera turns on the spot). frames/s: the system alone, without "
              "reading. n/a: the sequence has no ground truth. Each sequence's folder holds its report.html.", ""]
    return "\n".join(lines)


@app.command("evaluate")
@with_run_options
def evaluate_command(
    datasets: Annotated[list[Path], typer.Argument(help="Dataset folders or video files, one run each.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder: a run folder per dataset, results.md and "
                                      "results.csv.")] = Path("evaluate_out"),
    opts: RunOptions = RunOptions(),
) -> None:
    """Run SLAM on every DATASET with the same settings and write one table of frames, failed frames, ATE (SE(3),
    Sim(3)) beside the never-moving camera's, rotation error, RPE, scale and frames per second: DIR/results.md and
    DIR/results.csv, with each run's folder (and report.html) under DIR. Video options apply to the video files."""
    from rich.console import Console

    from codeslam.cli.common import open_frames, set_threads
    from codeslam.cli.slam import ORACLE_DEPTH_MODELS, live_option, run_to_folder, setup_slam, video_options
    from codeslam.data.video import is_video_file
    from codeslam.io import atomic_write, check_output_dir, check_output_file

    o = opts
    set_threads(o.threads)
    check_output_dir(out)
    for name in (RESULTS_MD, RESULTS_CSV):
        check_output_file(out / name)
    live = live_option(o.realtime, o.speed)
    is_video = [o.fmt == "video" or (o.fmt is None and Path(d).is_file() and is_video_file(d)) for d in datasets]
    video_given = (("camera", o.camera), ("fov", o.fov), ("fps", o.fps), ("every", o.every))
    given = [f"--{k}" for k, v in video_given if v is not None]
    if given and not any(is_video):
        raise ConfigError(f"{', '.join(given)} apply to video files only, and no DATASET is one")
    names = run_names(datasets)
    setup = setup_slam(o.config, o.weights, o.device, o.depth_model, o.size, o.sequential)
    opened = []  # every dataset opened (and checked) before the first run, so bad input fails at once
    for d, video in zip(datasets, is_video):
        options = video_options(d, o.fmt, o.camera, o.fov, o.fps, o.every) if video else {}
        opened.append(open_frames(d, o.fmt, o.frames, min_frames=2, what="SLAM", increasing=True,
                                  options=options))
        if o.depth_model in ORACLE_DEPTH_MODELS and not opened[-1][0].has_depth:
            raise ConfigError(f"--depth-model {o.depth_model} needs datasets with depth maps; {d} has none")
    console = Console(stderr=True)
    summaries = []
    for k, (d, name, (seq, indices)) in enumerate(zip(datasets, names, opened), start=1):
        if not o.quiet:
            console.print(f"[bold]{k}/{len(datasets)}[/bold] {name}: {len(indices)} frames of {d}")
        summaries.append(run_to_folder(seq, indices, d, out / name, setup, quiet=o.quiet,
                                       label=f"slam {k}/{len(datasets)}", live=live))
    rows = table_rows(names, summaries)
    settings = (f"Settings of every run: depth model {setup.model_info.get('depth_model')}"
                + (f", weights {setup.model_info['weights']}" if "weights" in setup.model_info else "")
                + f", config {o.config or 'default'}, device {setup.cfg.device}, {setup.model_info['mapping']} "
                "mapping" + (f", frames {o.frames}" if o.frames else "")
                + ("" if live is None else f", live at {live.speed:g} times the recordings' rate (--realtime: frames "
                   "that came while the system was busy skipped; 'frames' counts those processed)") + ".")
    with atomic_write(out / RESULTS_CSV) as f:
        f.write(results_csv(rows))
    with atomic_write(out / RESULTS_MD) as f:
        f.write(results_markdown(rows, settings))
    _print_table(rows, out)


def _print_table(rows: list[dict], out: Path) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=escape(f"codeslam evaluate -> {out / RESULTS_MD}"))
    for k, (_, header, _, _) in enumerate(COLUMNS):
        table.add_column(escape(header), justify="left" if k == 0 else "right", no_wrap=k == 0)
    for r in rows:
        table.add_row(*(escape("n/a" if r[c] is None else str(r[c]) if d is None else f"{float(r[c]):.{d}f}")
                        for c, _, _, d in COLUMNS))
    Console().print(table)
