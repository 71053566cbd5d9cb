"""The paper's Fig. 4: validation error during training for several code sizes (and, optionally, RGB input or a
nonlinear decoder).

Left: the validation metric of every run against the training step (code sizes in increasing shades of grey, other
variants dashed in colour). Right: each run's final value against its code size. The metric defaults to
``val_rmse_encode``, the per-pixel proximity RMSE of the depth decoded from the encoder's code (the paper's
"validation loss ... on the per-pixel proximity errors"); any column of ``val.csv`` works (``val_loss``,
``val_nll``, ``val_rmse_zero``).

Plot existing runs (folders written by ``codeslam train``: ``config.yaml`` and ``val.csv``)::

    python scripts/fig4_code_size.py --runs RUN_A RUN_B ... [--metric val_rmse_encode] [--out fig4.png]

Or train the runs first (one ``codeslam train`` run per code size / variant, same data and schedule), then plot::

    codeslam synth shards --train --views 4096 --workers 2
    python scripts/fig4_code_size.py --train --data shards --code-sizes 8,32,128 --variants rgb,nonlinear \\
        --steps 2000 --runs-dir runs_fig4 [--config base.yaml] --out fig4.png

Training runs that already exist in ``--runs-dir`` are resumed (finished ones are just read).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from codeslam.errors import CodeSLAMError
from codeslam.io import atomic_path

VARIANTS = ("grey", "rgb", "nonlinear")


def _ints(text: str) -> list[int]:
    return [int(t) for t in text.split(",") if t.strip()]


def read_run(run: Path, metric: str) -> dict:
    """-> {label, code_size, variant, steps [..], values [..]} of a ``codeslam train`` run folder."""
    from codeslam.network.config import load_run_config

    cfg = load_run_config(run / "config.yaml").network
    if not (run / "val.csv").is_file():
        raise CodeSLAMError(f"{run} has no val.csv (is it a codeslam train run folder?)")
    with open(run / "val.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or metric not in rows[0]:
        raise CodeSLAMError(f"{run}/val.csv has no column {metric!r}")
    variant = "rgb" if cfg.in_channels == 3 else "nonlinear" if not cfg.linear_decoder else "grey"
    label = f"code {cfg.code_size}" + ("" if variant == "grey" else f", {variant}")
    return {"label": label, "code_size": cfg.code_size, "variant": variant, "run": str(run),
            "steps": [int(r["step"]) for r in rows], "values": [float(r[metric]) for r in rows]}


def train_runs(data: list[Path], runs_dir: Path, code_sizes: list[int], variants: list[str], steps: int,
               config: Path | None) -> list[Path]:
    """One training run per (code size, grey) and per (largest code size, variant); returns the run folders."""
    from codeslam.network.config import RunConfig, load_run_config, overlay
    from codeslam.network.train import train

    base = load_run_config(config)
    jobs = [(c, "grey") for c in code_sizes] + [(max(code_sizes), v) for v in variants if v != "grey"]
    runs = []
    for code_size, variant in jobs:
        net = {"code_size": code_size}
        if variant == "rgb":
            net["in_channels"] = 3
        if variant == "nonlinear":
            net["linear_decoder"] = False
        run_cfg = RunConfig(overlay(base.network, net), overlay(base.train, {"steps": steps}))
        run = runs_dir / f"code{code_size}_{variant}"
        print(f"training {run} ({steps} steps)")
        train(data, run, run_cfg, resume=run.exists(), progress=False)
        runs.append(run)
    return runs


def plot(runs: list[dict], metric: str, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted({r["code_size"] for r in runs if r["variant"] == "grey"})
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {"rgb": "tab:red", "nonlinear": "tab:blue"}
    for r in sorted(runs, key=lambda r: (r["variant"] != "grey", r["code_size"])):
        if r["variant"] == "grey":  # increasing shades of grey with the code size, as the paper
            shade = 0.75 - 0.75 * (sizes.index(r["code_size"]) / max(len(sizes) - 1, 1))
            style = {"color": str(shade), "ls": "-"}
        else:
            style = {"color": colours[r["variant"]], "ls": "--"}
        ax.plot(r["steps"], r["values"], lw=1.4, label=r["label"], **style)
        ax2.plot([r["code_size"]], [r["values"][-1]], "o" if r["variant"] == "grey" else "s", **{
            "color": style["color"]})
    grey = sorted((r for r in runs if r["variant"] == "grey"), key=lambda r: r["code_size"])
    ax2.plot([r["code_size"] for r in grey], [r["values"][-1] for r in grey], "-", color="0.4", lw=1)
    ax.set_xlabel("training step")
    ax.set_ylabel(metric)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax2.set_xscale("log", base=2)
    ax2.set_xlabel("code size")
    ax2.set_ylabel(f"final {metric}")
    ax2.grid(True, alpha=0.3)
    fig.suptitle("Validation error against code size (paper Fig. 4)")
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, nargs="*", default=[], help="codeslam train run folders to plot")
    ap.add_argument("--metric", default="val_rmse_encode", help="column of val.csv to plot")
    ap.add_argument("--out", type=Path, default=Path("fig4_code_size.png"))
    ap.add_argument("--train", action="store_true", help="train the runs first (needs --data and --runs-dir)")
    ap.add_argument("--data", type=Path, nargs="*", default=[], help="training data (shard or dataset folders)")
    ap.add_argument("--runs-dir", type=Path, default=None, help="where --train writes its runs")
    ap.add_argument("--code-sizes", type=_ints, default=[8, 32, 128])
    ap.add_argument("--variants", default="grey", help=f"comma list of {', '.join(VARIANTS)} (at the largest code)")
    ap.add_argument("--steps", type=int, default=2000, help="training steps of every --train run")
    ap.add_argument("--config", type=Path, default=None, help="base YAML config of the --train runs")
    args = ap.parse_args(argv)
    try:
        runs = list(args.runs)
        if args.train:
            variants = [v.strip() for v in args.variants.split(",") if v.strip()]
            if not args.data or args.runs_dir is None or any(v not in VARIANTS for v in variants):
                raise CodeSLAMError(f"--train needs --data, --runs-dir and --variants among {', '.join(VARIANTS)}")
            runs += train_runs(args.data, args.runs_dir, args.code_sizes, variants, args.steps, args.config)
        if not runs:
            raise CodeSLAMError("nothing to plot: give --runs or --train")
        curves = [read_run(r, args.metric) for r in runs]
    except CodeSLAMError as e:
        print(f"fig4: error: {e}")
        return 2
    plot(curves, args.metric, args.out)
    for c in sorted(curves, key=lambda c: (c["variant"], c["code_size"])):
        v = c["values"][-1]
        print(f"{c['label']:>22s}: final {args.metric} {v:.4f}" if math.isfinite(v) else c["label"])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
