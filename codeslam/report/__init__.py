"""The HTML report of a SLAM run (tools layer: reads a run's files, never imported by the core).

``write_report(run_dir)`` writes ``run_dir/report.html``: one self-contained file (plotly.js embedded) with the
metrics, the trajectory against ground truth, drift against travelled distance, tracking status per frame,
keyframe depth panels and an interactive 3D view of the map. ``codeslam report RUN_DIR`` runs it.
"""

from codeslam.report.html import build_html, report_figures, write_report
from codeslam.report.run import RunFiles, load_run, write_groundtruth

__all__ = ["RunFiles", "build_html", "load_run", "report_figures", "write_groundtruth", "write_report"]
