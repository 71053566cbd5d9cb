"""``codeslam depth``: depth of dataset frames from the code network, in three modes (paper Sec. 5.1, Fig. 5):
``zero`` (the zero code: single-view prediction), ``encode`` (the encoder's code of the ground-truth depth) and
``optimise`` (the code fitted to the ground-truth depth by Gauss-Newton with the decoder Jacobian).

``--mode`` may be repeated (or take a comma list) to compare modes in one run: the metrics are reported for every
requested mode, together with the RMSE of the best single constant proximity on the same pixels (the baseline any
prediction must beat). Metrics are pooled over all valid ground-truth pixels of all frames at the canonical camera.

Outputs under ``--out DIR`` (nothing is written without it), all at the network's canonical camera:

* ``depth/<mode>/<index>.png``: 16-bit depth, value / 5000 = metres (the TUM convention), 0 = beyond 13.1 m;
* ``uncertainty/<index>.png``: 16-bit Laplace scale b of the proximity, value / 10000 = b;
* ``panel/<index>.png``: image, ground truth, one column per mode, uncertainty;
* ``camera.json``: the canonical camera (to back-project the depth PNGs).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import typer

from codeslam.cli.app import app
from codeslam.cli.common import DatasetArg, Device, Format, Frames, JsonOut, OutDir, Quiet, Threads, Weights
from codeslam.errors import ConfigError, DatasetError
from codeslam.io import check_outputs

#: depth PNG scale (TUM: value / 5000 = metres)
DEPTH_PNG_FACTOR = 5000.0
#: uncertainty PNG scale: value / 10000 = b (proximity units), so b up to 6.5 fits 16 bits
UNCERTAINTY_PNG_FACTOR = 10000.0
_UINT16_MAX = 65535


def parse_modes(modes: list[str]) -> list[str]:
    from codeslam.depthmodel import MODES

    out: list[str] = []
    for m in (p.strip() for spec in modes for p in spec.split(",")):
        if m not in MODES:
            raise ConfigError(f"--mode must be one of {', '.join(MODES)}, got {m!r}")
        if m not in out:
            out.append(m)
    return out


def write_depth16(path: Path, depth, factor: float = DEPTH_PNG_FACTOR) -> None:
    """(H, W) non-negative values -> 16-bit PNG of ``round(value * factor)``, atomically; values beyond the 16-bit
    range (or invalid) become 0, which readers take as "no value"."""
    import torch

    from codeslam.data.imageio import write_depth_png

    d = torch.as_tensor(depth).detach().cpu().double()
    d = torch.where(torch.isfinite(d) & (d > 0) & (d * factor <= _UINT16_MAX), d, torch.zeros_like(d))
    write_depth_png(path, d, factor)


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.4f}"


@app.command("depth")
def depth_command(
    dataset: DatasetArg,
    frames: Frames,
    mode: list[str] = typer.Option(["zero"], "--mode", help="zero | encode | optimise; repeat (or comma-separate) "
                                   "to compare modes. encode and optimise need ground-truth depth."),
    fmt: Format = None,
    weights: Weights = None,
    out: OutDir = None,
    json_out: JsonOut = None,
    fit_sigma: float | None = typer.Option(None, "--fit-sigma", help="optimise: ground-truth noise in proximity "
                                           "units, weighting the data against the code prior N(0, I) (default "
                                           "0.01)."),
    device: Device = None,
    threads: Threads = None,
    quiet: Quiet = False,
) -> None:
    """Depth from the code network (zero code, encoded, or optimised code) with proximity RMSE and abs-rel.
    With --out, writes depth/<mode>/, uncertainty/ and panel/ PNGs and camera.json there."""
    from rich.console import Console

    from codeslam.cli.common import check_device, open_frames, progress_bar, set_threads
    from codeslam.depthmodel import FIT_PROX_SIGMA, DepthModel, evaluate_predictions, predict_depth

    set_threads(threads)
    device = check_device(device)
    check_outputs(out, json_out)  # refuse bad output paths before any work
    modes = parse_modes(mode)
    sigma = FIT_PROX_SIGMA if fit_sigma is None else fit_sigma
    if not (math.isfinite(sigma) and sigma > 0):
        raise ConfigError(f"--fit-sigma must be a positive number, got {fit_sigma}")
    t0 = time.perf_counter()
    seq, indices = open_frames(dataset, fmt, frames)
    if any(m != "zero" for m in modes) and not seq.has_depth:
        raise DatasetError(f"--mode {'/'.join(m for m in modes if m != 'zero')} needs ground-truth depth, and "
                           f"{dataset} has none")
    model = DepthModel.load(weights, device=device)
    preds = []
    with progress_bar("depth", len(indices), quiet) as update:
        for k, i in enumerate(indices):  # one frame at a time, as predict_depth works anyway
            preds += predict_depth(model, [model.canonical(seq[i])], modes, sigma)
            update(k + 1, f"frame {i}")

    a = model.avg_depth
    errors = evaluate_predictions(preds, a)
    const = next(iter(errors.values())).constant_rmse
    results = {
        "dataset": str(dataset),
        "weights": str(weights) if weights is not None else "default",
        "frames": indices,
        "timestamps": [p.frame.timestamp for p in preds],
        "modes": modes,
        "camera": model.camera.to_dict(),
        "avg_depth": a,
        "code_size": model.code_size,
        "fit_sigma": sigma,
        "valid_pixels": next(iter(errors.values())).n,
        "prox_rmse": {m: e.prox_rmse for m, e in errors.items()},
        "depth_abs_rel": {m: e.depth_abs_rel for m, e in errors.items()},
        "prox_rmse_per_frame": {m: e.per_frame for m, e in errors.items()},
        "prox_rmse_constant": const,
        "seconds": time.perf_counter() - t0,
    }

    if out is not None:
        from codeslam.io import write_json
        from codeslam.recon.panels import Tile, depth_range, write_panel

        for k, p in enumerate(preds):
            name = f"{p.frame.index:06d}.png"
            for m in modes:
                write_depth16(out / "depth" / m / name, p.depth(m, a))
            write_depth16(out / "uncertainty" / name, p.uncertainty, UNCERTAINTY_PNG_FACTOR)
            tiles = [Tile("image", p.frame.image, "rgb")]
            if p.frame.depth is not None:
                tiles.append(Tile("ground truth", p.frame.depth, "depth"))
            for m in modes:
                r = errors[m].per_frame[k]
                tiles.append(Tile(m if r is None else f"{m} (RMSE {r:.3f})", p.depth(m, a), "depth"))
            tiles.append(Tile("uncertainty", p.uncertainty, "uncertainty"))
            lim = None if p.frame.depth is None else depth_range([p.frame.depth])  # colours of the ground truth
            write_panel(out / "panel" / name, [tiles], depth_lim=lim, title=f"{dataset.name} frame {p.frame.index}")
        write_json(out / "camera.json", model.camera.to_dict())

    console = Console()
    console.print(f"{len(indices)} frames of {dataset} at {model.camera.width}x{model.camera.height}, "
                  f"{results['valid_pixels']} valid ground-truth pixels", highlight=False)
    for m in modes:
        console.print(f"  {m:9s} proximity RMSE {_fmt(errors[m].prox_rmse)}  depth abs-rel "
                      f"{_fmt(errors[m].depth_abs_rel)}", highlight=False)
    console.print(f"  best constant proximity RMSE {_fmt(const)}", highlight=False)
    if json_out is not None:
        from codeslam.io import write_json

        write_json(json_out, results)
