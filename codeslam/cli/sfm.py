"""``codeslam sfm``: dense N-frame structure from motion (paper Sec. 4.1, Table 1, Fig. 8) on dataset frames.

Every listed frame becomes a keyframe (canonical-camera image and its linear depth decoder from the network);
codes start at zero and poses where ORB matches with the master and PnP on its zero-code depth put them
(``--init features``; ``--init identity`` is the paper's start, which holds rotations of about 10 degrees), and
:func:`codeslam.sfm.sfm` optimises them jointly over the pairs
``master`` (the master frame with every other frame, both directions: the paper's Table 1 setup) or ``all``.
The first listed frame is the gauge (its pose stays the identity).

Outputs under ``--out DIR`` (default: nothing but the printed and ``--json`` metrics):

* ``depth/<index>.png``: optimised depth at the canonical camera, 16-bit, value / 5000 = metres;
* ``poses.txt``: the optimised T_wc in TUM format (first frame at the origin), for ``codeslam eval``;
* ``cloud.ply``: the fused coloured point cloud (bilateral-filtered depth, slanted elements cropped, Fig. 8);
* ``panel.png``: per frame image, ground truth, zero-code and optimised depth, uncertainty;
* ``sfm_config.yaml``: the resolved SfM configuration; ``camera.json``: the canonical camera.

With ground truth, the metrics are the master's proximity RMSE at the zero code and after optimisation (raw, and
after the median depth-ratio scale alignment), and the poses of the other frames relative to the master:
monocular SfM fixes the scale only through the network's depth prior, so translation errors are given as
estimated (``rel_trans_err``, metres) and after the single least-squares scale factor
(``rel_trans_err_scale_aligned``, with ``rel_scale``), next to the error of assuming no motion (``rel_trans_gt``,
``rel_rot_gt_deg``).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import DatasetArg, Device, Format, Frames, JsonOut, OutDir, Threads, Weights
from codeslam.errors import ConfigError
from codeslam.io import check_outputs

PAIR_MODES = ("master", "all")
INIT_MODES = ("features", "identity")


def _load_sfm_config(path: Path | None):
    from codeslam.configfile import read_yaml_mapping
    from codeslam.sfm import SfMConfig

    if path is None:
        return SfMConfig()
    data = read_yaml_mapping(path, "SfMConfig fields, optionally under 'sfm:'")
    if set(data) == {"sfm"}:
        data = data["sfm"]
    return SfMConfig.from_dict(data or {})


@app.command("sfm")
def sfm_command(
    dataset: DatasetArg,
    frames: Frames,
    master: int | None = typer.Option(None, "--master", help="Dataset index of the master frame, one of --frames "
                                      "(default: the first listed)."),
    pairs: str = typer.Option("master", "--pairs", help="master: the master with every other frame; all: every "
                              "pair."),
    fmt: Format = None,
    weights: Weights = None,
    out: OutDir = None,
    json_out: JsonOut = None,
    config: Path | None = typer.Option(None, "--config", help="YAML of SfMConfig fields (optionally under 'sfm:')."),
    init: str = typer.Option("features", "--init", help="Initial poses: features (ORB matches with the master "
                             "and PnP on its zero-code depth) or identity (the paper's start)."),
    max_depth: float = typer.Option(10.0, "--max-depth", help="Point cloud: drop depths beyond this (metres)."),
    device: Device = None,
    threads: Threads = None,
) -> None:
    """Jointly optimise the codes and poses of the listed frames (at least 2); depth, poses, point cloud and
    errors. With --out, writes depth/ PNGs, poses.txt, cloud.ply, panel.png, sfm_config.yaml and camera.json."""
    import torch

    from codeslam.cli.common import check_device, open_frames, set_threads
    from codeslam.clock import StageClock
    from codeslam.depthmodel import DepthModel
    from codeslam.recon.fusion import FusionConfig
    from codeslam.sfm import all_pairs, master_pairs, sfm

    set_threads(threads)
    device = check_device(device)
    check_outputs(out, json_out)  # refuse bad output paths before any work
    if pairs not in PAIR_MODES:
        raise ConfigError(f"--pairs must be one of {', '.join(PAIR_MODES)}, got {pairs!r}")
    if init not in INIT_MODES:
        raise ConfigError(f"--init must be one of {', '.join(INIT_MODES)}, got {init!r}")
    cfg = _load_sfm_config(config)
    fusion_cfg = FusionConfig(max_depth=max_depth)
    seq, indices = open_frames(dataset, fmt, frames, min_frames=2, what="SfM")
    if master is None:
        master = indices[0]
    if master not in indices:
        raise ConfigError(f"--master {master} is not one of --frames {indices}")
    m = indices.index(master)

    model = DepthModel.load(weights, device=device)
    t0 = time.perf_counter()
    cframes = [model.canonical(seq[i]) for i in indices]
    t1 = time.perf_counter()
    keyframes = [model.keyframe(f) for f in cframes]
    t2 = time.perf_counter()
    poses_init, pnp_inliers, left_out = None, None, []
    if init == "features":
        from codeslam.slam.frontend import poses_from_features

        jac = keyframes[m].decoder.levels[0].jac
        zero = keyframes[m].decoder.depth(torch.zeros(model.code_size, dtype=jac.dtype, device=jac.device))
        poses_init, pnp_inliers = poses_from_features([seq[i] for i in indices], m, zero, model.camera)
        # A frame the features cannot place (blur, too little overlap) would start at the identity, far outside
        # the photometric basin, and its diverging pose drags the master's depth with it (TUM fr1/rpy master 18
        # with frames 24 and 27: 38 deg off, depth 71% worse). It is left out, as a tracker drops such a frame.
        keep = [i for i in range(len(indices)) if i == m or pnp_inliers[i] > 0]
        left_out = [indices[i] for i in range(len(indices)) if i not in keep]
        if len(keep) < 2:  # nothing to match (tiny or textureless images): the paper's start for all
            typer.echo(f"codeslam: warning: no frame matched the master {master} (ORB + PnP); starting from the "
                       "identity", err=True)
            poses_init, left_out = None, []
        elif left_out:
            typer.echo(f"codeslam: warning: frames {left_out} left out: ORB + PnP found no pose against the master "
                       f"{master}", err=True)
            indices, cframes, keyframes = ([x[i] for i in keep] for x in (indices, cframes, keyframes))
            poses_init, pnp_inliers = poses_init[keep], [pnp_inliers[i] for i in keep]
            m = indices.index(master)
    pair_list = master_pairs(len(indices), m) if pairs == "master" else all_pairs(len(indices))
    t3 = time.perf_counter()
    clock = StageClock(keyframes[m].decoder.levels[0].jac.device)  # each iteration (CUDA synchronised)
    result = sfm(keyframes, pair_list, cfg, poses_init=poses_init, clock=clock)
    t4 = time.perf_counter()
    depths = [d.cpu() for d in result.depths(keyframes)]
    results = _metrics(model, cframes, keyframes, result, m)
    results.update(
        dataset=str(dataset), weights=str(weights) if weights is not None else "default", frames=indices,
        master=master, pairs=pairs, num_pairs=len(pair_list), code_size=model.code_size,
        camera=model.camera.to_dict(), avg_depth=model.avg_depth, iterations=result.iterations,
        ms_per_iteration=clock.ms.get("iteration", 0.0) / max(clock.count.get("iteration", 0), 1),
        sfm_ms=1e3 * (t4 - t3),
        load_ms=1e3 * (t1 - t0), network_ms=1e3 * (t2 - t1), init=init, init_ms=1e3 * (t3 - t2),
        pnp_inliers=pnp_inliers, left_out=left_out,
        levels=[{"level": lvl, "iterations": r.iterations, "accepted": r.accepted, "reason": r.reason,
                 "cost_initial": r.costs[0], "cost_final": r.costs[-1]} for lvl, r in result.levels],
        readout_rotation_rad=None if result.rs is None else result.rs.detach().cpu().double().tolist(),
    )
    if out is not None:
        _write_outputs(out, model, cframes, keyframes, depths, result, cfg, fusion_cfg, results)
    _print(results)
    if json_out is not None:
        from codeslam.io import write_json

        write_json(json_out, results)


def _metrics(model, cframes, keyframes, result, m: int) -> dict:
    """The master's proximity errors (zero code and optimised) and relative pose errors, None without GT."""
    import torch

    from codeslam.recon.metrics import median_scale, pose_errors_relative_to_frame, prox_rmse

    out: dict = dict.fromkeys(("prox_rmse_master", "prox_rmse_master_zero_code", "prox_rmse_master_scale_aligned",
                               "prox_rmse_master_zero_code_scale_aligned", "depth_scale_master", "rel_trans_err",
                               "rel_trans_err_scale_aligned", "rel_scale", "rel_rot_err_deg", "rel_trans_gt",
                               "rel_rot_gt_deg", "rel_per_frame"))
    f = cframes[m]
    dec = keyframes[m].decoder
    if f.depth is not None:
        gt = f.depth.to(dec.levels[0].prox0.device)
        gt_prox = model.target_prox(gt)
        zero = torch.zeros(model.code_size, dtype=dec.levels[0].jac.dtype, device=gt.device)
        for suffix, code in (("", result.codes[m]), ("_zero_code", zero)):
            depth = dec.depth(code)
            s = median_scale(depth, gt)
            out[f"prox_rmse_master{suffix}"] = prox_rmse(dec.prox(code), gt_prox, gt)
            out[f"prox_rmse_master{suffix}_scale_aligned"] = (
                None if s is None else prox_rmse(model.target_prox(s * depth), gt_prox, gt))
            if not suffix:
                out["depth_scale_master"] = s
    if all(c.pose is not None and bool(torch.isfinite(c.pose).all()) for c in cframes):
        gt_poses = torch.stack([c.pose for c in cframes]).double().numpy()
        err = pose_errors_relative_to_frame(result.poses.detach().cpu().double().numpy(), gt_poses, m)
        out.update(rel_trans_err=err.trans, rel_trans_err_scale_aligned=err.trans_scaled, rel_scale=err.scale,
                   rel_rot_err_deg=err.rot_deg, rel_trans_gt=err.trans_gt, rel_rot_gt_deg=err.rot_gt_deg,
                   rel_per_frame=[{"trans": a, "trans_scale_aligned": b, "rot_deg": c} for a, b, c in err.per_frame])
    return out


def _write_outputs(out, model, cframes, keyframes, depths, result, cfg, fusion_cfg, results) -> None:
    import numpy as np
    import torch
    import yaml

    from codeslam.cli.depth import write_depth16
    from codeslam.data.trajectory import Trajectory, write_tum
    from codeslam.io import atomic_write, write_json
    from codeslam.recon.fusion import FusionView, fuse
    from codeslam.recon.panels import Tile, depth_range, write_panel
    from codeslam.recon.ply import write_ply

    poses = result.poses.detach().cpu().double()
    for f, d in zip(cframes, depths):
        write_depth16(out / "depth" / f"{f.index:06d}.png", d)
    stamps = np.array([f.timestamp for f in cframes])
    order = np.argsort(stamps, kind="stable")  # a trajectory file is in time order, whatever --frames' order
    write_tum(out / "poses.txt", Trajectory(stamps[order], poses[torch.as_tensor(order)]))
    views = [FusionView(f.image.cpu(), d, model.camera, T) for f, d, T in zip(cframes, depths, poses)]
    cloud = fuse(views, fusion_cfg)
    write_ply(out / "cloud.ply", cloud, comments=[f"codeslam sfm: {len(cframes)} keyframes, frames "
                                                  f"{results['frames']}, master {results['master']}"])
    results["cloud_points"] = len(cloud)
    rows = []
    for i, (f, kf, d) in enumerate(zip(cframes, keyframes, depths)):
        dec = kf.decoder
        zero = dec.depth(torch.zeros(model.code_size, dtype=dec.levels[0].jac.dtype, device=dec.levels[0].jac.device))
        tag = " (master)" if i == results["frames"].index(results["master"]) else ""
        rows.append([
            Tile(f"frame {f.index}{tag}", f.image.cpu(), "rgb"),
            Tile("ground truth", f.depth, "depth") if f.depth is not None else None,
            Tile("zero code", zero.cpu(), "depth"),
            Tile("optimised", d, "depth"),
            Tile("uncertainty", dec.levels[0].uncertainty.cpu(), "uncertainty"),
        ])
    gts = [f.depth for f in cframes if f.depth is not None]
    write_panel(out / "panel.png", rows, depth_lim=depth_range(gts) if gts else None,
                title=f"codeslam sfm: {len(cframes)} frames, {results['pairs']} pairs")
    with atomic_write(out / "sfm_config.yaml") as fh:
        fh.write(yaml.safe_dump({"sfm": {k: list(v) if isinstance(v, tuple) else v
                                         for k, v in cfg.to_dict().items()}}, sort_keys=False))
    write_json(out / "camera.json", model.camera.to_dict())


def _fmt(v, spec=".4f") -> str:
    return "-" if v is None else format(v, spec)


def _print(res: dict) -> None:
    from rich.console import Console

    c = Console()
    c.print(f"SfM of {len(res['frames'])} frames (master {res['master']}, {res['num_pairs']} {res['pairs']} pairs): "
            f"{res['iterations']} iterations, {res['ms_per_iteration']:.1f} ms each, {res['sfm_ms'] / 1e3:.2f} s "
            f"(network {res['network_ms'] / 1e3:.2f} s)", highlight=False)
    c.print(f"  master proximity RMSE: zero code {_fmt(res['prox_rmse_master_zero_code'])} -> optimised "
            f"{_fmt(res['prox_rmse_master'])}   (scale-aligned {_fmt(res['prox_rmse_master_zero_code_scale_aligned'])}"
            f" -> {_fmt(res['prox_rmse_master_scale_aligned'])})", highlight=False)
    if res["rel_rot_err_deg"] is not None:
        c.print(f"  poses relative to the master: translation error {_fmt(res['rel_trans_err'])} m (scale-aligned "
                f"{_fmt(res['rel_trans_err_scale_aligned'])} m, scale {_fmt(res['rel_scale'], '.3f')}; no motion: "
                f"{_fmt(res['rel_trans_gt'])} m), rotation error {_fmt(res['rel_rot_err_deg'], '.3f')} deg (no motion: "
                f"{_fmt(res['rel_rot_gt_deg'], '.3f')} deg)", highlight=False)
    if "cloud_points" in res:
        c.print(f"  point cloud: {res['cloud_points']} points", highlight=False)
