"""The report's figures, one plotly figure per function, built from a run's files (:class:`RunFiles`).

Positions are shown in the ground truth's world frame when the run has one (the estimate aligned to it), in
the map frame (the first camera's) otherwise. "From above" looks down the world's up direction, which is
estimated from the cameras themselves: a hand-held or mounted camera is mostly upright, so the mean of the
cameras' image-down axes (OpenCV y) is close to gravity.
"""

from __future__ import annotations

import numpy as np

from codeslam.data.trajectory import Trajectory
from codeslam.recon.fusion import PointCloud

#: Colours of the tracking statuses in the timeline (frames.csv's statuses and the summary-derived ones).
STATUS_COLOURS = {
    "initialising": "#9e9e9e",
    "tracked": "#2e7d32",
    "relocalised": "#ef6c00",
    "predicted": "#c62828",
    "failed": "#c62828",
}
ESTIMATE_COLOUR, GT_COLOUR, SIM3_COLOUR, KEYFRAME_COLOUR = "#1f77b4", "#444444", "#9467bd", "#d62728"
#: Largest number of map points sent to the 3D view (a random subset; WebGL stays responsive).
MAX_MAP_POINTS = 60_000
#: Keyframes shown in the depth panels (evenly spread over the run, first and last included).
PANEL_KEYFRAMES = 4
_PLOT_FONT = dict(family="Helvetica, Arial, sans-serif", size=12)


def _go():
    import plotly.graph_objects as go

    return go


def _layout(fig, title: str, height: int) -> None:
    fig.update_layout(title=dict(text=title, x=0.01), height=height, font=_PLOT_FONT, template="plotly_white",
                      margin=dict(l=60, r=20, t=60, b=50), legend=dict(orientation="h", y=-0.12))


# ---- frames of reference --------------------------------------------------------------------------------------
def view_axes(poses: np.ndarray) -> np.ndarray:
    """(3, 3) rows ``(e1, e2, up)``, a right-handed orthonormal basis for looking at camera poses ``(N, 4, 4)``
    ``T_wc``: ``up`` against the mean image-down axis of the cameras (OpenCV y), ``e1`` the main horizontal
    direction of travel, ``e2 = up x e1``. When the cameras' down axes cancel out (a camera rolling through
    every angle), ``up`` is the direction in which the positions spread least."""
    xyz = poses[:, :3, 3]
    down = poses[:, :3, 1].mean(axis=0)  # mean image-down (y) axis in the world
    centred = xyz - xyz.mean(axis=0)
    if np.linalg.norm(down) > 0.3:
        up = -down / np.linalg.norm(down)
    else:
        up = np.linalg.svd(centred, full_matrices=True)[2][2]
    horiz = centred - np.outer(centred @ up, up)  # positions projected on the horizontal plane
    e1 = np.linalg.svd(horiz, full_matrices=True)[2][0] if len(xyz) > 1 else np.zeros(3)
    e1 = e1 - (e1 @ up) * up
    if np.linalg.norm(e1) < 1e-9:  # no horizontal motion: any horizontal direction
        e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up])


def aligned_estimate(est: Trajectory, gt: Trajectory, align: str):
    """(every estimated position (N, 3) in the ground truth's frame, the alignment :class:`Sim3`), fitted by
    Umeyama over the time-matched poses as the ATE is (``align`` 'se3' or 'sim3')."""
    from codeslam.eval import metrics

    S = metrics.ate(est, gt, align=align).alignment
    return S.apply_points(est.positions_xyz.numpy()), S


# ---- trajectory -----------------------------------------------------------------------------------------------
def trajectory_figure(est: Trajectory, gt: Trajectory | None, keyframe_times: np.ndarray | None = None):
    """The trajectory from above and from the side: with ground truth the estimate aligned to it by SE(3) (and,
    hidden until clicked in the legend, by Sim(3)); without, the estimate in the map frame."""
    from plotly.subplots import make_subplots

    go = _go()
    if gt is not None:
        est_xyz, _ = aligned_estimate(est, gt, "se3")
        sim3_xyz, sim3 = aligned_estimate(est, gt, "sim3")
        axes = view_axes(gt.poses.numpy())
        frame_name = "ground-truth world frame"
    else:
        est_xyz, sim3_xyz = est.positions_xyz.numpy(), None
        axes = view_axes(est.poses.numpy())
        frame_name = "map frame (first camera), no ground truth"
    fig = make_subplots(rows=1, cols=2, subplot_titles=("from above", "from the side"), horizontal_spacing=0.08)
    views = ((0, 1, "horizontal 1 [m]", "horizontal 2 [m]"), (0, 2, "horizontal 1 [m]", "up [m]"))
    for col, (a, b, xlabel, ylabel) in enumerate(views, start=1):
        def add(xyz, name, colour, dash=None, visible=True, width=2.0, col=col, a=a, b=b):
            uv = xyz @ axes.T  # (N, 3) coordinates along (e1, e2, up)
            fig.add_trace(go.Scatter(x=uv[:, a], y=uv[:, b], mode="lines", name=name, legendgroup=name,
                                     showlegend=col == 1, visible=visible,
                                     line=dict(color=colour, width=width, dash=dash)), row=1, col=col)

        if gt is not None:
            add(gt.positions_xyz.numpy(), "ground truth", GT_COLOUR, dash="dash")
        add(est_xyz, "CodeSLAM" + (" (SE(3)-aligned)" if gt is not None else ""), ESTIMATE_COLOUR)
        if sim3_xyz is not None:
            add(sim3_xyz, f"CodeSLAM (Sim(3)-aligned, scale {sim3.s:.3f})", SIM3_COLOUR, visible="legendonly")
        start = est_xyz[:1] @ axes.T
        fig.add_trace(go.Scatter(x=start[:, a], y=start[:, b], mode="markers", name="start", legendgroup="start",
                                 showlegend=col == 1, marker=dict(color="black", size=9, symbol="circle-open")),
                      row=1, col=col)
        if keyframe_times is not None and len(keyframe_times):
            k = np.searchsorted(est.timestamps, keyframe_times).clip(0, len(est_xyz) - 1)
            kf = est_xyz[k] @ axes.T
            fig.add_trace(go.Scatter(x=kf[:, a], y=kf[:, b], mode="markers", name="keyframes",
                                     legendgroup="keyframes", showlegend=col == 1,
                                     marker=dict(color=KEYFRAME_COLOUR, size=7, symbol="diamond")), row=1, col=col)
        fig.update_xaxes(title_text=xlabel, row=1, col=col)
        fig.update_yaxes(title_text=ylabel, scaleanchor=f"x{col if col > 1 else ''}", scaleratio=1, row=1, col=col)
    _layout(fig, f"Trajectory ({frame_name})", 480)
    return fig


def drift_figure(est: Trajectory, gt: Trajectory):
    """Translation error against travelled ground-truth distance (the paper's Fig. 9), the estimate anchored at
    its first pose (odometry drift), and the same after the Sim(3) scale correction."""
    from codeslam.eval.metrics import drift_vs_distance

    go = _go()
    fig = go.Figure()
    for with_scale, name, colour in ((False, "first pose anchored", ESTIMATE_COLOUR),
                                     (True, "first pose anchored, Sim(3) scale", SIM3_COLOUR)):
        d = drift_vs_distance(est, gt, anchor="first", with_scale=with_scale)
        fig.add_trace(go.Scatter(x=d.distances, y=d.errors, mode="lines", name=name, line=dict(color=colour),
                                 customdata=d.timestamps, hovertemplate="%{x:.3f} m travelled<br>error %{y:.4f} m"
                                 "<br>t = %{customdata:.3f} s<extra></extra>"))
    fig.update_xaxes(title_text="travelled distance (ground truth) [m]", rangemode="tozero")
    fig.update_yaxes(title_text="translation error [m]", rangemode="tozero")
    _layout(fig, "Translation error against travelled distance (paper Fig. 9)", 380)
    return fig


# ---- tracking status ------------------------------------------------------------------------------------------
def status_figure(frame_idx: np.ndarray, status: list[str], reason: list[str], keyframe_frames: list[int],
                  frames: dict | None = None):
    """Tracking status per frame (one coloured mark per frame and status), the keyframes, and with a per-frame
    log (frames.csv) the tracking statistics below it."""
    from plotly.subplots import make_subplots

    go = _go()
    stats = [c for c in ("inlier_ratio", "overlap", "texture") if frames is not None and c in frames
             and np.isfinite(np.asarray(frames[c], dtype=float)).any()]
    rows = 2 if stats else 1
    fig = make_subplots(rows=rows, cols=1, shared_xaxes=True, vertical_spacing=0.08,
                        row_heights=[0.55, 0.45] if rows == 2 else None)
    order = [s for s in STATUS_COLOURS if s in status] + sorted({s for s in status} - set(STATUS_COLOURS))
    for s in order:
        sel = [k for k, v in enumerate(status) if v == s]
        fig.add_trace(go.Scatter(
            x=frame_idx[sel], y=[s] * len(sel), mode="markers", name=f"{s} ({len(sel)})",
            marker=dict(symbol="line-ns-open", size=18, color=STATUS_COLOURS.get(s, "#795548"), line=dict(width=3)),
            customdata=[reason[k] or "-" for k in sel],
            hovertemplate="frame %{x}<br>" + s + "<br>%{customdata}<extra></extra>"), row=1, col=1)
    kf_reasons = None
    if frames is not None and "keyframe_reason" in frames:
        by_frame = dict(zip(np.asarray(frames["frame"]).astype(int).tolist(), frames["keyframe_reason"]))
        kf_reasons = [by_frame.get(int(f), "") or "-" for f in keyframe_frames]
    fig.add_trace(go.Scatter(
        x=list(keyframe_frames), y=["keyframe"] * len(keyframe_frames), mode="markers",
        name=f"keyframe ({len(keyframe_frames)})", marker=dict(symbol="diamond", size=10, color=KEYFRAME_COLOUR),
        customdata=kf_reasons, hovertemplate="keyframe at frame %{x}"
        + ("<br>%{customdata}" if kf_reasons else "") + "<extra></extra>"), row=1, col=1)
    fig.update_yaxes(type="category", categoryorder="array", categoryarray=["keyframe", *order[::-1]], row=1, col=1)
    for c, colour in zip(stats, ("#00838f", "#6a1b9a", "#ef6c00")):
        fig.add_trace(go.Scatter(x=np.asarray(frames["frame"]), y=np.asarray(frames[c], dtype=float), mode="lines",
                                 name=c.replace("_", " "), line=dict(color=colour)), row=2, col=1)
    if stats:
        fig.update_yaxes(title_text="fraction; texture: intensity std", range=[0, 1.05], row=2, col=1)
    fig.update_xaxes(title_text="frame", row=rows, col=1)
    _layout(fig, "Tracking status per frame", 300 if rows == 1 else 460)
    return fig


# ---- keyframe depth panels ------------------------------------------------------------------------------------
#: Panel columns: (title, keyframes.npz array, colour axis). The image is drawn as an image.
PANEL_COLUMNS = (
    ("image", "image", None),
    ("zero-code depth", "depth_zero", "coloraxis"),
    ("optimised depth", "depth", "coloraxis"),
    ("uncertainty", "uncertainty", "coloraxis2"),
    ("ground-truth depth", "depth_gt", "coloraxis"),
)


def panel_keyframes(n_keyframes: int, count: int = PANEL_KEYFRAMES) -> list[int]:
    """Indices of up to ``count`` keyframes spread evenly over ``n_keyframes`` (first and last included)."""
    if n_keyframes <= count:
        return list(range(n_keyframes))
    return sorted({int(round(v)) for v in np.linspace(0, n_keyframes - 1, count)})


def _finite(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


def panel_columns(kf: dict[str, np.ndarray]) -> tuple[list[tuple[str, str, str | None]], list[str]]:
    """(the panel columns this run stored, the titles of those it did not)."""
    have = [c for c in PANEL_COLUMNS if c[1] in kf]
    return have, [title for title, key, _ in PANEL_COLUMNS if key not in kf]


def keyframe_figure(kf: dict[str, np.ndarray]):
    """For a few keyframes: the image, the zero-code depth, the optimised depth, the uncertainty and the ground-
    truth depth, those the run stored (a keyframe without a value, e.g. no ground truth, says "not available").
    Depths share one colour scale."""
    from plotly.subplots import make_subplots

    go = _go()
    sel = panel_keyframes(len(kf["depth"]))
    columns, missing = panel_columns(kf)
    ncol = len(columns)
    titles = []
    for k in sel:
        for title, key, _ in columns:
            available = np.isfinite(np.asarray(kf[key][k], dtype=float)).any()
            label = f"keyframe {int(kf['id'][k])} (frame {int(kf['frame_index'][k])})" if key == "image" else title
            titles.append(label if available else f"{title}: not available")
    fig = make_subplots(rows=len(sel), cols=ncol, subplot_titles=titles, horizontal_spacing=0.02,
                        vertical_spacing=0.06 if len(sel) > 1 else 0.0)
    depth_keys = [key for _, key, axis in columns if axis == "coloraxis"]
    depth_vals = np.concatenate([_finite(kf[key][sel]).ravel() for key in depth_keys])
    depth_vals = depth_vals[np.isfinite(depth_vals)]
    zmin, zmax = (np.percentile(depth_vals, [1, 99]) if depth_vals.size else (0.0, 1.0))
    for r, k in enumerate(sel, start=1):
        for c, (_, key, axis) in enumerate(columns, start=1):
            if key == "image":
                img = np.clip(np.moveaxis(np.asarray(kf["image"][k], dtype=np.float32), 0, -1), 0, 1)  # (H, W, 3)
                fig.add_trace(go.Image(z=(255 * img).astype(np.uint8), hoverinfo="skip"), row=r, col=c)
            else:
                z = _finite(kf[key][k])
                if not np.isfinite(z).any():
                    continue
                unit = "" if key == "uncertainty" else " m"
                fig.add_trace(go.Heatmap(z=z, coloraxis=axis, hovertemplate="x %{x}, y %{y}<br>%{z:.3f}" + unit
                                         + "<extra></extra>"), row=r, col=c)
    fig.update_xaxes(visible=False, constrain="domain")
    fig.update_yaxes(visible=False, autorange="reversed", scaleanchor="x", constrain="domain")
    for r in range(1, len(sel) + 1):  # keep each panel's pixels square
        for c in range(1, ncol + 1):
            n = (r - 1) * ncol + c
            fig.update_yaxes(scaleanchor=f"x{n if n > 1 else ''}", row=r, col=c)
    unc = np.concatenate([_finite(kf["uncertainty"][sel]).ravel()]) if "uncertainty" in kf else np.array([])
    unc = unc[np.isfinite(unc)]
    fig.update_layout(
        coloraxis=dict(colorscale="Viridis", cmin=float(zmin), cmax=float(zmax),
                       colorbar=dict(title="depth [m]", x=1.0, len=0.45, y=0.75) if unc.size else
                       dict(title="depth [m]", x=1.0)),
        coloraxis2=dict(colorscale="Inferno", cmin=0.0, cmax=float(np.percentile(unc, 99)) if unc.size else 1.0,
                        colorbar=dict(title="uncertainty<br>b [proximity]", x=1.0, len=0.45, y=0.22)),
    )
    h, w = kf["depth"].shape[1:]
    title = "Keyframes: " + ", ".join(t for t, _, _ in columns)
    if missing:
        title += f"<br><sup>not available in this run: {', '.join(missing)}</sup>"
    _layout(fig, title, int(140 + len(sel) * (1100 / max(ncol, 4)) * h / w * 1.2))
    fig.update_layout(margin=dict(t=110 if missing else 80))  # room for the subtitle above the panel titles
    fig.update_annotations(font_size=11)
    return fig


# ---- 3D map ---------------------------------------------------------------------------------------------------
def subsample(cloud: PointCloud, max_points: int = MAX_MAP_POINTS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (M, 3), rgb (M, 3) uint8): at most ``max_points`` points of ``cloud``, a fixed random subset."""
    xyz = np.asarray(cloud.xyz, dtype=np.float32)
    rgb = np.asarray(cloud.rgb, dtype=np.uint8)
    if len(xyz) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(xyz), max_points, replace=False))
        xyz, rgb = xyz[keep], rgb[keep]
    return xyz, rgb


def _frusta(T_wc: np.ndarray, camera: np.ndarray, size: float) -> np.ndarray:
    """Line vertices (with NaN breaks) of a small pyramid per camera pose: apex at the centre, base the image
    corners at depth ``size``."""
    fx, fy, cx, cy, w, h = (float(v) for v in camera)
    corners = np.array([[(u - cx) / fx, (v - cy) / fy, 1.0] for u, v in ((0, 0), (w, 0), (w, h), (0, h))]) * size
    segs = []
    for T in T_wc:
        c = T[:3, 3]
        p = corners @ T[:3, :3].T + c  # (4, 3) base corners in the world
        segs += [c, p[0], p[1], c, p[2], p[3], c, p[0], p[3], [np.nan] * 3, p[1], p[2], [np.nan] * 3]
    return np.array(segs, dtype=np.float64)


def map_figure(cloud: PointCloud | None, est: Trajectory, keyframes: dict[str, np.ndarray] | None,
               gt: Trajectory | None) -> dict:
    """Interactive 3D view (WebGL) of the fused point cloud, the camera path and the keyframes' cameras; with ground
    truth also the ground-truth path brought into the map frame (inverse SE(3) alignment). Shown in the map frame
    turned upright (:func:`view_axes` of the estimated cameras: z is up), so that plotly's turntable rotation turns
    about the vertical. Returned as plotly's figure dict (write it with ``plotly.io.to_html(..., validate=False)``:
    its traces were validated, the points' colours are added after)."""
    go = _go()
    fig = go.Figure()
    poses = est.poses.numpy()
    axes = view_axes(poses)  # rows e1, e2, up: map frame -> display frame

    def show(xyz: np.ndarray) -> np.ndarray:
        return np.asarray(xyz, dtype=np.float64) @ axes.T  # (N, 3) display coordinates

    est_xyz = show(poses[:, :3, 3])
    if cloud is not None and len(cloud):
        xyz, rgb = subsample(cloud)
        xyz = show(xyz)
        fig.add_trace(go.Scatter3d(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], mode="markers", name=f"map ({len(xyz)} "
                                   f"of {len(cloud)} points)", marker=dict(size=1.5), hoverinfo="skip"))
    fig.add_trace(go.Scatter3d(x=est_xyz[:, 0], y=est_xyz[:, 1], z=est_xyz[:, 2], mode="lines", name="CodeSLAM path",
                               line=dict(color=ESTIMATE_COLOUR, width=5)))
    if gt is not None:
        _, S = aligned_estimate(est, gt, "se3")  # maps map-frame points into the ground-truth frame
        gt_map = show((gt.positions_xyz.numpy() - S.t) @ S.R / S.s)  # (N, 3), its inverse
        fig.add_trace(go.Scatter3d(x=gt_map[:, 0], y=gt_map[:, 1], z=gt_map[:, 2], mode="lines",
                                   name="ground truth (SE(3)-aligned)", line=dict(color=GT_COLOUR, width=4,
                                                                                   dash="dash")))
    if keyframes is not None and "T_wc" in keyframes and "camera" in keyframes:
        extent = float(np.ptp(est_xyz, axis=0).max()) if len(est_xyz) > 1 else 0.0
        depths = _finite(keyframes["depth"]) if "depth" in keyframes else np.array([np.nan])
        median_depth = float(np.median(depths[np.isfinite(depths)])) if np.isfinite(depths).any() else 1.0
        size = 0.15 * (extent if extent > 1e-3 else median_depth)
        f = show(_frusta(keyframes["T_wc"], keyframes["camera"], size))
        fig.add_trace(go.Scatter3d(x=f[:, 0], y=f[:, 1], z=f[:, 2], mode="lines", name="keyframe cameras",
                                   line=dict(color=KEYFRAME_COLOUR, width=3), hoverinfo="skip"))
    forward = axes @ poses[0, :3, 2]  # the first camera's viewing direction in the display frame
    horiz = forward[:2] / max(np.linalg.norm(forward[:2]), 1e-9)
    eye = dict(x=-1.6 * horiz[0], y=-1.6 * horiz[1], z=1.0)  # behind and above the first camera
    fig.update_layout(scene=dict(aspectmode="data", xaxis_title="horizontal 1 [m]", yaxis_title="horizontal 2 [m]",
                                 zaxis_title="up [m]", camera=dict(eye=eye)), uirevision="map")
    _layout(fig, "Map and camera path (drag to rotate, scroll to zoom)", 640)
    # The points' colours go into the figure's dict unvalidated: plotly checks a list of colour strings one by one
    # (60,000 points: 5.7 s of an 80-frame TUM run's 62 s, most of its report), the dict takes them as they are.
    fig_dict = fig.to_dict()
    if cloud is not None and len(cloud):
        value = (rgb[:, 0].astype(np.int64) << 16) | (rgb[:, 1].astype(np.int64) << 8) | rgb[:, 2]
        fig_dict["data"][0]["marker"]["color"] = [f"#{v:06x}" for v in value.tolist()]
    return fig_dict
