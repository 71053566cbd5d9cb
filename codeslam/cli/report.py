"""``codeslam report RUN_DIR``: (re)build a run's HTML report from the files in its folder. A thin shell over
:func:`codeslam.report.write_report`; ``--screenshot`` photographs the page in a headless Chromium."""

from __future__ import annotations

from pathlib import Path

import typer

from codeslam.cli.app import app


@app.command("report")
def report_command(
    run_dir: Path = typer.Argument(..., help="A run folder written by `codeslam slam` (or `demo`, `evaluate`)."),
    out: Path | None = typer.Option(None, "--out", help="Where to write the report (default RUN_DIR/report.html)."),
    screenshot: Path | None = typer.Option(None, "--screenshot", help="Also save a PNG of the whole page as headless "
                                           "Chromium renders it (needs chromium on PATH or $CODESLAM_CHROMIUM)."),
) -> None:
    """Write RUN_DIR/report.html: one self-contained page (opens offline in any browser) with the metrics, the
    trajectory against ground truth, drift against distance, tracking status per frame, keyframe depths and a 3D
    view of the map. A run without ground truth gets no metrics section."""
    from codeslam.io import check_output_file
    from codeslam.report import write_report

    for path in (out, screenshot):
        if path is not None:
            check_output_file(path)
    if screenshot is not None:
        from codeslam.report.browser import find_chromium

        if find_chromium() is None:  # before the work
            from codeslam.errors import ConfigError

            raise ConfigError("--screenshot needs Chromium (e.g. 'apt-get install chromium'), or name it with "
                              "$CODESLAM_CHROMIUM")
    path = write_report(run_dir, out)
    print(f"report: {path}")
    if screenshot is not None:
        from codeslam.report.browser import screenshot as take_screenshot

        check = take_screenshot(path, screenshot)
        drawn = sum(1 for f in check["figures"].values() if f["svg"] > 0)
        print(f"screenshot: {screenshot} ({drawn} of {len(check['figures'])} figures drawn)")
