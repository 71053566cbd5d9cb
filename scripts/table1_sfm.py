"""The paper's Table 1: the master keyframe's proximity RMSE as more frames are paired with it in N-frame SfM.

For every dataset and every master frame m, the neighbours are ``m + o`` for the offsets o (default
4,-4,8,-8,12,-12: frames on both sides, further and further away, like the paper's two motions). For n = 1..6
the master and its first n neighbours are optimised jointly (codes from zero, poses from identity, pairs = the
master with every other frame, both directions) and the master's proximity RMSE against its ground-truth depth is
recorded; n = 0 is the zero code (single-view prediction). Results are averaged over the masters (evenly spaced
through each sequence) and written as a markdown table, JSON and a plot.

Usage::

    python scripts/table1_sfm.py DATASET [DATASET ...] [--weights FILE] [--masters 5] \\
        [--offsets 4,-4,8,-8,12,-12] [--config sfm.yaml] [--out table1]

e.g. on generator sequences and the TUM frames::

    codeslam synth synth_seq --scenes 2 --frames 60
    python scripts/table1_sfm.py synth_seq/scene_000 synth_seq/scene_001 ../shared/data/tum_fr1_rpy --out table1
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from codeslam.data.registry import open_dataset
from codeslam.depthmodel import FIT_PROX_SIGMA, DepthModel, fit_code_linear
from codeslam.errors import CodeSLAMError
from codeslam.io import atomic_path, atomic_write, write_json
from codeslam.recon.metrics import median_scale, prox_rmse
from codeslam.sfm import SfMConfig, master_pairs, sfm


def _ints(text: str) -> list[int]:
    return [int(t) for t in text.split(",") if t.strip()]


def _span(text: str) -> tuple[int, int]:
    try:
        start, stop = (int(t) for t in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP, got {text!r}") from None
    if not 0 <= start < stop:
        raise argparse.ArgumentTypeError(f"expected 0 <= START < STOP, got {text!r}")
    return start, stop


def pick_masters(num_frames: int, offsets: list[int], count: int, span: tuple[int, int] | None = None) -> list[int]:
    """``count`` masters evenly spaced over the frames whose neighbours ``m + o`` all exist (and, with ``span`` =
    (start, stop), whose index lies in [start, stop))."""
    lo, hi = max(0, -min(offsets)), num_frames - 1 - max(0, max(offsets))
    if span is not None:
        lo, hi = max(lo, span[0]), min(hi, span[1] - 1)
    if hi < lo:
        raise CodeSLAMError(f"no master frame in a sequence of {num_frames} frames has all neighbours {offsets}"
                            + (f" within frames {span[0]}:{span[1]}" if span else ""))
    return sorted({int(round(x)) for x in np.linspace(lo, hi, count + 2)[1:-1]}) if count < hi - lo + 1 else list(
        range(lo, hi + 1))


def _errors(model: DepthModel, dec, code: torch.Tensor, gt: torch.Tensor) -> tuple[float, float]:
    """The master's proximity RMSE at ``code``: raw, and after scaling its depth by median(d_gt / d)."""
    gt_prox = model.target_prox(gt)
    depth = dec.depth(code)
    s = median_scale(depth, gt)
    return prox_rmse(dec.prox(code), gt_prox, gt), prox_rmse(model.target_prox(s * depth), gt_prox, gt)


def master_rmse_by_count(model: DepthModel, seq, master: int, offsets: list[int], cfg: SfMConfig) -> dict:
    """-> {"rmse": [n = 0..len(offsets)], "rmse_scale_aligned": [...], "ms": [...], "rmse_floor": best code for
    the ground truth} for one master frame."""
    idx = [master] + [master + o for o in offsets]
    frames = [model.canonical(seq[i]) for i in idx]
    gt = frames[0].depth
    if gt is None:
        raise CodeSLAMError(f"frame {master} has no ground-truth depth")
    kfs = [model.keyframe(f) for f in frames]
    dec = kfs[0].decoder
    gt = gt.to(dec.levels[0].prox0.device)
    zero = torch.zeros(model.code_size, dtype=dec.levels[0].jac.dtype, device=gt.device)
    errs, ms = [_errors(model, dec, zero, gt)], [0.0]
    # The decoder's floor: the code that fits the ground truth best (as `codeslam depth --mode optimise`); no
    # SfM result can get below it, so it says how much of the zero code's error the images could remove.
    lv = dec.levels[0]
    target = model.target_prox(gt).to(lv.prox0.dtype)[None, None]
    weight = (target > 0).to(target.dtype) / FIT_PROX_SIGMA**2
    best = fit_code_linear(lv.prox0[None, None], lv.jac[None], target, weight)
    floor = _errors(model, dec, best[0], gt)
    for n in range(1, len(idx)):
        t0 = time.perf_counter()
        res = sfm(kfs[: n + 1], master_pairs(n + 1, 0), cfg)
        ms.append(1e3 * (time.perf_counter() - t0))
        errs.append(_errors(model, dec, res.codes[0], gt))
    return {"master": master, "frames": idx, "rmse": [e[0] for e in errs],
            "rmse_scale_aligned": [e[1] for e in errs], "ms": ms, "rmse_floor": floor[0]}


def plot(results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for ax, key, what in ((axes[0], "mean_rmse", "raw"), (axes[1], "mean_rmse_scale_aligned", "scale-aligned")):
        for name, r in results.items():
            mean = np.array(r[key])
            ax.plot(range(len(mean)), 100 * mean, "o-", label=f"{name} ({len(r['masters'])} masters)")
        ax.set_xlabel("# frames paired with the master (0 = zero code)")
        ax.set_ylabel(r"master proximity RMSE [$10^{-2}$]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"{what}")
    fig.suptitle("N-frame SfM: error against frames paired (paper Table 1)")
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def markdown(results: dict, n_max: int) -> str:
    head = "| dataset | masters | " + " | ".join(str(n) for n in range(n_max + 1)) + " | decoder floor |"
    sep = "|---|---|" + "---|" * (n_max + 2)
    lines = []
    for key, what in (("mean_rmse", "as estimated"), ("mean_rmse_scale_aligned", "after median depth-scale "
                                                                                "alignment")):
        lines += [f"RMSE of the master's proximity [1e-2], {what}; column n = frames paired with it "
                  "(0 = zero code; decoder floor = the code that fits the ground truth best).", "", head, sep]
        for name, r in results.items():
            floor = f" {100 * r['mean_rmse_floor']:.2f} |" if key == "mean_rmse" else " |"
            lines.append(f"| {name} | {len(r['masters'])} | " + " | ".join(f"{100 * v:.2f}" for v in r[key]) + " |"
                         + floor)
        lines.append("")
    return "\n".join(lines)


def dataset_labels(paths: list[Path]) -> list[str]:
    """A row label per dataset: its folder name, with the parent folder where two share a name (two generator
    runs' scene_000 would otherwise fill one row with both)."""
    names = [p.name for p in paths]
    return [f"{p.parent.name}/{p.name}" if names.count(p.name) > 1 else p.name for p in paths]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", type=Path, nargs="+")
    ap.add_argument("--weights", type=Path, default=None, help="network weights (default: the shipped weights)")
    ap.add_argument("--masters", type=int, default=5, help="master frames per dataset, evenly spaced")
    ap.add_argument("--span", type=_span, default=None,
                    help="START:STOP: draw the masters from frames START..STOP-1 only (e.g. one part of a sequence)")
    ap.add_argument("--offsets", type=_ints, default=[4, -4, 8, -8, 12, -12], help="neighbour offsets, in order")
    ap.add_argument("--config", type=Path, default=None, help="YAML of SfMConfig fields")
    ap.add_argument("--out", type=Path, default=Path("table1"), help="output folder")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = ap.parse_args(argv)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    try:
        import yaml

        cfg = SfMConfig.from_dict(yaml.safe_load(args.config.read_text()) or {}) if args.config else SfMConfig()
        model = DepthModel.load(args.weights, device=args.device)
        results = {}
        for path, label in zip(args.datasets, dataset_labels(args.datasets)):
            seq = open_dataset(path)
            masters = pick_masters(len(seq), args.offsets, args.masters, args.span)
            name = label if args.span is None else f"{label} [{args.span[0]}:{args.span[1]}]"
            per_master = []
            for m in masters:
                r = master_rmse_by_count(model, seq, m, args.offsets, cfg)
                print(f"{name} master {m}: " + " ".join(f"{v:.4f}" for v in r["rmse"]) + "  (scale-aligned "
                      + " ".join(f"{v:.4f}" for v in r["rmse_scale_aligned"]) + ")", flush=True)
                per_master.append(r)
            rmse = np.array([r["rmse"] for r in per_master], dtype=np.float64)  # (masters, n + 1)
            aligned = np.array([r["rmse_scale_aligned"] for r in per_master], dtype=np.float64)
            results[name] = {"path": str(path), "masters": masters, "mean_rmse": rmse.mean(0).tolist(),
                             "mean_rmse_scale_aligned": aligned.mean(0).tolist(),
                             "mean_rmse_floor": float(np.mean([r["rmse_floor"] for r in per_master])),
                             "per_master": per_master}
    except CodeSLAMError as e:
        print(f"table1: error: {e}")
        return 2
    table = markdown(results, len(args.offsets))
    results_meta = {"weights": str(args.weights) if args.weights else "default", "offsets": args.offsets,
                    "code_size": model.code_size, "sfm_config": cfg.to_dict(), "datasets": results}
    write_json(args.out / "table1.json", results_meta)
    with atomic_write(args.out / "table1.md") as f:
        f.write(table)
    plot(results, args.out / "table1.png")
    print(table)
    print(f"wrote {args.out}/table1.md, table1.json, table1.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
