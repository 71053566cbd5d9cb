"""The run report as one self-contained HTML file: tables written here, figures by plotly, plotly.js embedded
once in the page's head, so the file opens offline in any browser, with no server."""

from __future__ import annotations

import html
from collections import Counter
from pathlib import Path

import numpy as np

from codeslam.io import atomic_write
from codeslam.report import figures as F
from codeslam.report.run import (
    REPORT_FILE,
    RunFiles,
    frame_statuses,
    live_text,
    load_run,
    map_scale_text,
    mapping_text,
    trajectory_text,
)

#: Statuses of frames whose tracking failed (the pose is the motion model's prediction).
FAILED_STATUSES = ("predicted", "failed")

_CSS = """
body { font-family: Helvetica, Arial, sans-serif; margin: 0 auto; max-width: 1280px; padding: 0 24px 48px;
       color: #222; }
h1 { font-size: 26px; margin: 24px 0 4px; } h2 { font-size: 20px; margin: 32px 0 8px; border-bottom: 1px solid #ddd; }
.sub { color: #666; margin: 0 0 16px; } .note { color: #666; font-size: 13px; margin: 4px 0 0; }
table { border-collapse: collapse; margin: 8px 0; font-size: 14px; }
th, td { padding: 4px 12px; border-bottom: 1px solid #eee; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; } th { background: #f5f5f5; }
.cols { display: flex; flex-wrap: wrap; gap: 32px; } .figure { margin: 12px 0 28px; }
nav a { margin-right: 14px; color: #1f77b4; text-decoration: none; font-size: 14px; }
.warn { color: #b26a00; }
"""


def _e(v) -> str:
    return html.escape(str(v))


def _num(v, digits: int = 4, unit: str = "") -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "n/a"
    if not np.isfinite(v):
        return "n/a"
    return f"{v:.{digits}f}{unit}"


def _table(rows: list[tuple], header: tuple | None = None, numeric: bool = True) -> str:
    """Rows of cells; with ``numeric``, a cell after the first that starts with a number is right-aligned."""
    out = ["<table>"]
    if header:
        out.append("<tr>" + "".join(f"<th>{_e(h)}</th>" for h in header) + "</tr>")
    for row in rows:
        cells = []
        for k, c in enumerate(row):
            cls = ' class="num"' if numeric and k > 0 and _looks_numeric(str(c)) else ""
            cells.append(f"<td{cls}>{_e(c)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _looks_numeric(s: str) -> bool:
    head = s.split(" ")[0]
    try:
        float(head)
    except ValueError:
        return False
    return True


# ---- sections -------------------------------------------------------------------------------------------------
def run_info_rows(run: RunFiles) -> list[tuple[str, str]]:
    """What ran on what: dataset, frames, camera (with the field-of-view guess when there was no calibration),
    depth model, device."""
    s = run.summary
    rows = [("dataset", f"{s.get('dataset', '?')} ({s.get('format', '?')})")]
    if "frames" in s:
        rows.append(("frames", f"{s['frames']} (frames {s.get('first_frame', '?')}..{s.get('last_frame', '?')})"))
    if "keyframes" in s:
        rows.append(("keyframes", f"{s['keyframes']} ({s.get('marginalised', 0)} marginalised)"))
    if "width" in s:
        rows.append(("image size in the system", f"{s['width']}x{s['height']}"))
    if "camera" in s:  # e.g. the video reader's "60 deg horizontal field of view (a guess; no calibration)"
        rows.append(("camera", str(s["camera"])))
    if "depth_model" in s:
        rows.append(("depth model", f"{s['depth_model']}" + (f", weights {s['weights']}" if "weights" in s else "")
                     + (f", code Jacobian in {s['code_jacobian']}" if "code_jacobian" in s else "")))
    if "device" in s:
        rows.append(("device", str(s["device"])))
    if "settings" in s:
        rows.append(("settings", str(s["settings"])))
    if (live := live_text(s)) is not None:
        rows.append(("live", live))
    if (mapping := mapping_text(s)) is not None:
        rows.append(("mapping", mapping))
    if (scale := map_scale_text(s)) is not None:
        rows.append(("map scale", scale))
    if s.get("trajectory_smoothing_s"):
        rows.append(("trajectory", trajectory_text(s["trajectory_smoothing_s"])))
    return rows


def metric_rows(s: dict) -> list[tuple[str, str, str]]:
    """(metric, CodeSLAM, never-moving camera) rows of a run evaluated against ground truth."""
    never = s.get("no_motion_ate_rmse_aligned")
    rows = [
        ("ATE RMSE, SE(3) alignment [m]", _num(s.get("ate_se3_rmse")), _num(never)),
        ("ATE RMSE, Sim(3) alignment [m]", _num(s.get("ate_sim3_rmse")) + f" (scale {_num(s.get('sim3_scale'), 3)})",
         _num(never)),
        ("ATE RMSE, unaligned, at the first pose [m]", "", _num(s.get("no_motion_ate_rmse"))),
        ("orientation error after the best rotation alignment [deg]",
         f"{_num(s.get('rot_aligned_rmse_deg'), 3)} RMSE, {_num(s.get('rot_aligned_max_deg'), 3)} max", ""),
        ("rotation error relative to the first frame [deg]",
         f"{_num(s.get('rot_err_rmse_deg'), 3)} RMSE, {_num(s.get('rot_err_max_deg'), 3)} max", ""),
        ("scale drift: the map's scale at the end over its scale at the start", _num(s.get("scale_drift"), 3), ""),
        ("RPE per frame, translation [m]", _num(s.get("rpe_trans_rmse")), ""),
        ("RPE per frame, translation after the Sim(3) scale [m]", _num(s.get("rpe_trans_sim3_rmse")), ""),
        ("RPE per frame, rotation [deg]", _num(s.get("rpe_rot_rmse_deg"), 3), ""),
        ("error at the last frame, first pose anchored [m]", _num(s.get("drift_end_error")), ""),
        ("ground-truth path length [m]", _num(s.get("path_length_gt"), 3), ""),
    ]
    return rows


def failure_counts(run: RunFiles) -> tuple[dict[str, int], str]:
    """(failed frames by reason, where the reasons came from): the summary's ``failures_by_reason``, else counted in
    frames.csv, else the summary's ``tracking_failures`` under 'reason not recorded'."""
    s = run.summary
    if isinstance(s.get("failures_by_reason"), dict):
        return {str(k): int(v) for k, v in s["failures_by_reason"].items()}, "result.json"
    if run.frames is not None and "reason" in run.frames:
        counts = Counter(r or "no reason given" for st, r in zip(run.frames["status"], run.frames["reason"])
                         if st in FAILED_STATUSES)
        return dict(counts), "frames.csv"
    n = int(s.get("tracking_failures", 0))
    return ({"reason not recorded": n} if n else {}), "result.json"


#: The order a frame goes through the stages (result.json stores them sorted by name); unknown ones follow.
STAGE_ORDER = ("read", "resample", "features", "track", "relocalise", "merge", "wait", "decode", "marginalise",
               "window")


def _in_stage_order(times: dict) -> dict:
    rank = {k: i for i, k in enumerate(STAGE_ORDER)}
    return dict(sorted(times.items(), key=lambda kv: (rank.get(kv[0], len(rank)), kv[0])))


def statistics_html(run: RunFiles) -> str:
    """Tracking outcome per status, failures by reason, speed and time per stage."""
    s = run.summary
    _, status, _ = frame_statuses(run)
    counts = s.get("status_counts") if isinstance(s.get("status_counts"), dict) else Counter(status)
    status_rows = [(k, str(v)) for k, v in counts.items()]
    failures, source = failure_counts(run)
    fail_rows = [(k, str(v)) for k, v in sorted(failures.items(), key=lambda kv: -kv[1])] or [("none", "0")]
    speed_rows = []
    if "fps" in s:
        speed_rows.append(("frames per second (system)", _num(s["fps"], 2)))
    if "fps_with_io" in s:
        speed_rows.append(("frames per second (with reading)", _num(s["fps_with_io"], 2)))
    if "wall_s" in s:
        speed_rows.append(("wall time [s]", _num(s["wall_s"], 1)))
    per_frame = _in_stage_order(s.get("ms_per_frame") or {})
    total = sum(float(v) for v in per_frame.values()) or 1.0
    stage_rows = [(k, _num(v, 1), _num(100 * float(v) / total, 1)) for k, v in per_frame.items()]
    per_kf = _in_stage_order(s.get("ms_per_keyframe") or {})
    kf_rows = [(k, _num(v, 1)) for k, v in per_kf.items()]
    parts = ['<div class="cols">',
             "<div><h3>Frames by tracking status</h3>" + _table(status_rows, ("status", "frames")) + "</div>",
             "<div><h3>Failed frames by reason</h3>" + _table(fail_rows, ("reason", "frames"))
             + f'<p class="note">from {_e(source)}</p></div>',
             "<div><h3>Speed</h3>" + _table(speed_rows) + "</div>",
             "<div><h3>Time per stage</h3>" + _table(stage_rows, ("stage", "ms per frame", "%")) + "</div>"]
    if kf_rows:
        parts.append("<div><h3>Per keyframe</h3>" + _table(kf_rows, ("stage", "ms per keyframe")) + "</div>")
    parts.append("</div>")
    return "\n".join(parts)


# ---- figures --------------------------------------------------------------------------------------------------
def report_figures(run: RunFiles) -> list[tuple[str, object, str]]:
    """The report's figures as (element id, plotly figure or figure dict, caption), in page order. The drift figure
    needs ground truth, the keyframe panels ``keyframes.npz``; the others are always there."""
    s = run.summary
    kf = run.keyframes
    kf_times = kf["timestamp"] if kf is not None and "timestamp" in kf else None
    gt = run.groundtruth if run.has_metrics else None
    out = [("fig-trajectory", F.trajectory_figure(run.trajectory, gt, kf_times),
            "Estimated camera path " + ("against ground truth after SE(3) alignment (click the Sim(3) entry in the "
                                        "legend to show the scale-corrected estimate)." if gt is not None else
                                        "in the map frame; the run has no ground truth."))]
    if gt is not None:
        out.append(("fig-drift", F.drift_figure(run.trajectory, gt),
                    "Distance between estimated and true camera positions as the camera travels, the estimate "
                    "anchored at its first pose: accumulated drift, as in the paper's Fig. 9."))
    idx, status, reason = frame_statuses(run)
    kf_frames = [int(v) for v in (kf["frame_index"] if kf is not None else s.get("keyframe_frames", []))]
    note = "" if run.frames is not None else " (derived from result.json: this run has no per-frame log frames.csv)"
    out.append(("fig-status", F.status_figure(idx, status, reason, kf_frames, run.frames),
                "Status of every processed frame; hover for the reason" + note + "."))
    if kf is not None and "depth" in kf and len(kf["depth"]):
        out.append(("fig-keyframes", F.keyframe_figure(kf),
                    "Depth of a few keyframes as decoded from the zero code (the network's single-view prediction) "
                    "and after the window optimisation, the network's uncertainty (the Laplace scale b of its "
                    "proximity prediction) and the ground truth, where the run has them; depths share one colour "
                    "scale."))
    out.append(("fig-map", F.map_figure(run.cloud, run.trajectory, kf, gt),
                "The keyframes' depths fused into one point cloud (map.ply, a random subset when large), the camera "
                "path and the keyframe cameras."))
    return out


def build_html(run: RunFiles) -> str:
    """The whole report page for ``run``."""
    import plotly.io as pio
    from plotly.offline import get_plotlyjs

    s = run.summary
    figs = report_figures(run)
    titles = {"fig-trajectory": "Trajectory", "fig-drift": "Drift", "fig-status": "Tracking status",
              "fig-keyframes": "Keyframes", "fig-map": "3D map"}
    nav = ['<a href="#run">Run</a>'] + (['<a href="#metrics">Metrics</a>'] if run.has_metrics else [])
    nav += ['<a href="#statistics">Statistics</a>'] + [f'<a href="#{i}">{titles.get(i, i)}</a>' for i, _, _ in figs]
    body = [f"<h1>CodeSLAM run report</h1><p class=\"sub\">{_e(run.root)}</p>", "<nav>" + "".join(nav) + "</nav>",
            '<h2 id="run">Run</h2>', _table(run_info_rows(run), numeric=False)]
    if run.has_metrics:
        body += ['<h2 id="metrics">Accuracy against ground truth</h2>',
                 _table(metric_rows(s), ("metric", "CodeSLAM", "never-moving camera")),
                 '<p class="note">The never-moving camera stays at one pose for the whole sequence: aligned, it is '
                 "the best constant pose (the positions' RMS distance to their mean); unaligned, it stays at the "
                 "first ground-truth pose. A SLAM result must be well below it to have tracked anything.</p>"]
    elif "evaluation_error" in s:
        body.append(f'<p class="warn">Ground truth present but not evaluated: {_e(s["evaluation_error"])}</p>')
    body += ['<h2 id="statistics">Statistics</h2>', statistics_html(run)]
    config = {"displaylogo": False, "responsive": True}
    for fig_id, fig, caption in figs:
        div = pio.to_html(fig, full_html=False, include_plotlyjs=False, div_id=fig_id, config=config,
                          validate=not isinstance(fig, dict))  # a dict was built from a validated figure
        body.append(f'<div class="figure"><h2>{_e(titles.get(fig_id, fig_id))}</h2>{div}'
                    f'<p class="note">{_e(caption)}</p></div>')
    head = (f"<meta charset=\"utf-8\"><title>CodeSLAM report: {_e(Path(str(s.get('dataset', run.root))).name)}"
            f"</title><style>{_CSS}</style><script type=\"text/javascript\">{get_plotlyjs()}</script>")
    return f"<!DOCTYPE html>\n<html lang=\"en\"><head>{head}</head><body>\n" + "\n".join(body) + "\n</body></html>\n"


def write_report(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Build the report of the run in ``run_dir`` from its files and write it (atomically) to ``out``, by default
    ``run_dir/report.html``. Returns the path written."""
    run = load_run(run_dir)
    path = Path(out) if out is not None else Path(run_dir) / REPORT_FILE
    page = build_html(run)
    with atomic_write(path, "w", encoding="utf-8") as f:
        f.write(page)
    return path
