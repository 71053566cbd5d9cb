"""How good is the network's zero-code depth as a prior? The table of issue 13 for one or more weight files.

For every evaluation set, the zero-code depth ``D(I, 0)`` (``codeslam depth --mode zero``) is compared with the
ground truth at the canonical camera: proximity RMSE (a = the network's average depth, 1.5 m), the RMSE of the
best single constant proximity on the same pixels, their ratio (below 1: the prior carries information), and
the median over all valid pixels of predicted / true depth (1: right scale).

Sets (name=PATH[@FRAMES], FRAMES in the ``--frames`` grammar; shard folders take their first ``--shard-views``):

* ``tum`` and ``hololens``: ``../shared/data`` frames 0:180:4 (issue 13's measurement), never trained on;
* ``cabinet``, ``realsense``, ``redwood``, ``office``: the validation halves of ``../shared/train_data``
  (``scripts/split_real_rgbd.py``), written under ``--data-dir`` on first use;
* ``gen_v1`` ... ``gen_v4``: 256 held-out generator views of data versions 1-4 (seeds 4001, 4000, 4002, 4003),
  rendered under ``--data-dir`` on first use (``codeslam synth --train``, about a minute each on one core).

Also reported: ``si_rmse``, the proximity RMSE after scaling every frame's predicted depth by its median ratio to
the ground truth (the error of the depth's shape alone; what self-supervised adaptation can improve), and how much
that per-frame scale moves: ``scale_spread``, the standard deviation over frames of its logarithm, and
``scale_jump``, the mean absolute change of the logarithm from one evaluated frame to the next (for a sequence's
frames in order; for generator shards, random views, only the spread means something). A monocular map's scale
follows its keyframes' priors, so a prior whose scale jumps from view to view makes the map's scale jump with it
(the HoloLens walk, issue 13: the border fill raised the spread from 0.28 to 0.30 and SLAM's ATE from 0.14 to
0.17 m while the ratio and median improved).

With ``--span``, also where the code's span holds the truth (slower: each frame's code Jacobian): for every frame
the code ``c`` of the linear decoder ``prox0 + J c`` is fitted by least squares (a weak ridge) to the true depth
scaled to ``s`` times the zero code's median scale, for ``s`` on a grid from 0.3 to 3, and the fit's log-depth
error after its own median scale is read. ``span_scale`` is the median over frames of the ``s`` with the smallest
error, ``span_error`` that error and ``span_error_1`` the error at ``s = 1``. SLAM's window fits the codes to the
images, which fix the shape and not the scale, so a span that holds the truth's shape best at half the zero
code's scale lets the map shrink to half (docs/results/slam_table.md, twentieth session: the generator's five
walks, span scale 0.5, end their SLAM runs at 0.44-0.60 of their zero code's scale; TUM and the HoloLens walk,
span scale 1, within 10% of it). It is a fit to the truth, not a prediction of SLAM: networks trained with
scaled code targets raised it on the walks (0.5 -> 0.6) and their maps' scale did not move (twenty-first session).

    python scripts/depth_prior_eval.py --weights W [--weights W2 ...] [--set name=PATH[@FRAMES] ...]
        [--span] [--json OUT.json] [--markdown OUT.md] [--threads 1] [--data-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
#: real validation halves: set name -> folder of ../shared/train_data (split by scripts/split_real_rgbd.py)
REAL_SETS = {
    "cabinet": "tum_fr3_cabinet_kf",
    "realsense": "realsense_room_floorlevel_felixchenfy",
    "redwood": "redwood_livingroom_synthetic_open3d",
    "office": "tum_fr3_office_single_open3d",
}
#: held-out generator views: set name -> (data version, seed)
GEN_SETS = {"gen_v1": (1, 4001), "gen_v2": (2, 4000), "gen_v3": (3, 4002), "gen_v4": (4, 4003)}
GEN_VIEWS = 256


def default_sets(data_dir: Path) -> dict[str, str]:
    """The default sets (name -> PATH[@FRAMES]); the real and generator ones live under ``data_dir``."""
    sets = {"tum": f"{SHARED}/data/tum_fr1_rpy@0:180:4", "hololens": f"{SHARED}/data/hololens_dvmvs@0:180:4"}
    sets |= {name: str(data_dir / "real_split" / "val" / folder) for name, folder in REAL_SETS.items()}
    sets |= {name: str(data_dir / f"val128_v{version}") for name, (version, _) in GEN_SETS.items()}
    return sets


def prepare_set(name: str, path: Path, data_dir: Path, views: int = GEN_VIEWS) -> bool:
    """Write a missing default set at ``path``: a generator set rendered with its seed, the real validation
    halves split from ``../shared/train_data``. False when it cannot be made here (no source, or the command that
    makes it failed: its last line of error output is printed)."""
    if name in GEN_SETS:
        version, seed = GEN_SETS[name]
        print(f"rendering {name}: {views} views of data version {version}, seed {seed} -> {path}", flush=True)
        cmd = [sys.executable, "-m", "codeslam", "synth", str(path), "--train", "--views", str(views),
               "--views-per-scene", "16", "--shard-size", str(views), "--size", "128x96", "--seed", str(seed),
               "--data-version", str(version), "--workers", "1"]
    elif name in REAL_SETS and (SHARED / "train_data").is_dir():
        print(f"splitting {SHARED / 'train_data'} -> {data_dir / 'real_split'}", flush=True)
        cmd = [sys.executable, str(REPO / "scripts" / "split_real_rgbd.py"), "--out", str(data_dir / "real_split")]
    else:
        return False
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()
        print(f"could not make {name}: {lines[-1] if lines else f'exit status {done.returncode}'}", flush=True)
    return done.returncode == 0 and path.exists()


def depth_of(prox: torch.Tensor, a: float) -> torch.Tensor:
    """Eq. 4 inverted, ``a (1 - p) / p``, with p clamped to (1e-6, 1 - 1e-6) so that every prediction or fit,
    even one that leaves (0, 1), has a finite positive depth to compare (``prox_to_depth`` maps 0 to the invalid
    depth 0 instead)."""
    p = prox.clamp(1e-6, 1 - 1e-6)
    return a * (1.0 - p) / p


class PriorStats:
    """Pooled sums over valid pixels: zero-code proximity errors, ground-truth proximity moments and the
    predicted / true depth ratios (kept for the median)."""

    def __init__(self) -> None:
        self.n, self.se, self.s1, self.s2, self.se_si = 0, 0.0, 0.0, 0.0, 0.0
        self.ratios: list[torch.Tensor] = []
        self.log_scales: list[float] = []  # per frame, in the order added: log of its median predicted / true

    def add(self, prox_pred: torch.Tensor, depth_gt: torch.Tensor, a: float) -> None:
        """prox_pred, depth_gt: (..., H, W); depth 0 = invalid."""
        valid = torch.isfinite(depth_gt) & (depth_gt > 0)
        g = (a / (depth_gt[valid] + a)).double()
        p = prox_pred[valid].double()
        self.n += int(valid.sum())
        self.se += float((p - g).square().sum())
        self.s1 += float(g.sum())
        self.s2 += float(g.square().sum())
        d_pred = depth_of(p, a)
        ratio = d_pred / depth_gt[valid].double()
        self.ratios.append(ratio.float())
        # per frame: the predicted depth scaled by its median ratio to the ground truth
        frame = torch.arange(valid.shape[0])[:, None, None].expand_as(valid)[valid]
        for f in frame.unique():
            sel = frame == f
            scale = ratio[sel].median()
            self.log_scales.append(math.log(float(scale)))
            d_si = d_pred[sel] / scale
            self.se_si += float((a / (d_si + a) - g[sel]).square().sum())

    def result(self) -> dict:
        if self.n == 0:
            return {"pixels": 0}
        rmse = math.sqrt(self.se / self.n)
        const = math.sqrt(max(self.s2 / self.n - (self.s1 / self.n) ** 2, 0.0))
        r = torch.cat(self.ratios)
        if r.numel() > 4_000_000:
            r = r[torch.randperm(r.numel(), generator=torch.Generator().manual_seed(0))[:4_000_000]]
        ls = torch.tensor(self.log_scales, dtype=torch.float64)
        spread = float(ls.std()) if ls.numel() > 1 else float("nan")
        jump = float((ls[1:] - ls[:-1]).abs().mean()) if ls.numel() > 1 else float("nan")
        return {"pixels": self.n, "zero_rmse": rmse, "const_rmse": const, "ratio": rmse / const,
                "median_depth_ratio": float(r.median()), "si_rmse": math.sqrt(self.se_si / self.n),
                "scale_spread": spread, "scale_jump": jump}


#: The scales of the truth, relative to the zero code's median, at which --span fits the code. Up to 3, as
#: keyframe_span.py's grid: a corridor's first views are held at 1.6-2.3 (twenty-third session), which a grid
#: ending at 1.5 read as 1.5; the points up to 1.5 are the earlier tables' own.
SPAN_SCALES = (0.3, 0.4, 0.5, 0.6, 0.7, 0.85, 1.0, 1.2, 1.5, 1.75, 2.0, 2.5, 3.0)
#: The ridge of that fit per pixel (weak: what the span can hold, not what the code prior would allow).
SPAN_RIDGE = 1e-6


def span_fit(prox0: torch.Tensor, jac: torch.Tensor, depth_gt: torch.Tensor, a: float,
             scales: tuple[float, ...] = SPAN_SCALES, ridge: float = SPAN_RIDGE) -> dict[float, float]:
    """One frame: its zero-code proximity (H, W), code Jacobian (C, H, W) and true depth (H, W; 0 = invalid) ->
    for each s in ``scales`` the log-depth RMSE, after its median, of ``prox0 + J c`` fitted by ridge least squares
    (on the valid pixels) to the true depth scaled to s times the zero code's median ratio to it."""
    valid = torch.isfinite(depth_gt) & (depth_gt > 0)
    p0 = prox0.double()[valid]
    J = jac.double()[:, valid]  # (C, N)
    d = depth_gt.double()[valid]
    d0 = depth_of(p0, a)
    m = torch.exp(torch.median(torch.log(d0 / d)))
    A = J @ J.T + ridge * J.shape[1] * torch.eye(J.shape[0], dtype=torch.float64)
    out = {}
    for s in scales:
        target = d * m * s
        c = torch.linalg.solve(A, J @ (a / (target + a) - p0))
        err = torch.log(depth_of(p0 + J.T @ c, a) / target)
        out[s] = float((err - err.median()).square().mean().sqrt())
    return out


def span_summary(fits: list[dict[float, float]]) -> dict:
    """Per-frame :func:`span_fit` results -> median best scale, its error and the error at scale 1."""
    if not fits:
        return {}
    best = [min(f, key=f.get) for f in fits]

    def median(xs: list[float]) -> float:
        return float(torch.tensor(xs, dtype=torch.float64).median())

    return {"span_scale": median(best), "span_error": median([f[b] for f, b in zip(fits, best)]),
            "span_error_1": median([f[1.0] for f in fits])}


def _dataset_frames(model, path: str, frames: str | None):
    from codeslam.cli.common import open_frames

    seq, idx = open_frames(Path(path), None, frames)
    for i in idx:
        f = model.canonical(seq[i])
        yield f.image, f.depth


def _shard_frames(model, path: str, views: int):
    from codeslam.network.data import depth_metres, read_shard_to_canonical, shard_files

    files = [Path(path)] if Path(path).is_file() else shard_files(Path(path))
    left = views
    for s in files:
        img, dep = read_shard_to_canonical(s, model.camera)
        for i in range(min(left, img.shape[0])):
            yield img[i].float() / 255.0, depth_metres(dep[i])
        left -= img.shape[0]
        if left <= 0:
            return


def evaluate(model, path: str, frames: str | None, shard_views: int, batch: int = 16, span: bool = False) -> dict:
    """Zero-code prior statistics of one set (dataset folder or shard folder); with ``span`` also
    :func:`span_summary`."""
    from codeslam.network.data import shard_files

    p = Path(path)
    is_shards = p.is_file() or bool(shard_files(p))
    source = _shard_frames(model, path, shard_views) if is_shards else _dataset_frames(model, path, frames)
    stats, images, depths, n, fits = PriorStats(), [], [], 0, []

    def flush():
        feats = model.features(torch.stack(images))
        code = feats[0].new_zeros(len(images), model.code_size)
        prox = model.decode(feats, code)[0][:, 0].cpu()  # (B, H, W) finest level
        stats.add(prox, torch.stack(depths), model.avg_depth)
        if span:
            for dec, depth in zip(model.linear_decoders(feats), depths):
                lv = dec.levels[0]
                fits.append(span_fit(lv.prox0.cpu(), lv.jac.cpu(), depth.cpu(), model.avg_depth))

    for image, depth in source:
        images.append(image)
        depths.append(depth)
        n += 1
        if len(images) == batch:
            flush()
            images, depths = [], []
    if images:
        flush()
    return {"frames": n, **stats.result(), **span_summary(fits)}


_COLUMNS = [("zero-code RMSE", "zero_rmse", ".4f"), ("best constant", "const_rmse", ".4f"), ("ratio", "ratio", ".2f"),
            ("median depth ratio", "median_depth_ratio", ".2f"), ("scaled RMSE", "si_rmse", ".4f"),
            ("scale spread", "scale_spread", ".3f"), ("scale jump", "scale_jump", ".3f")]
_SPAN_COLUMNS = [("span scale", "span_scale", ".2f"), ("span error", "span_error", ".3f"),
                 ("span error at 1", "span_error_1", ".3f")]


def table_header(span: bool) -> list[str]:
    """The markdown table's two header lines; the span's columns only where --span computed them."""
    names = ["weights", "set", "frames"] + [c[0] for c in _COLUMNS + (_SPAN_COLUMNS if span else [])]
    return ["| " + " | ".join(names) + " |", "|---" * len(names) + "|"]


def table_row(weights: str, name: str, r: dict, span: bool) -> str:
    """One set's results as a row under :func:`table_header`; "-" where a figure is undefined (the scale's spread
    and jump of a one-frame set)."""
    def cell(key: str, fmt: str) -> str:
        v = r.get(key)
        return "-" if v is None or math.isnan(v) else format(v, fmt)

    cells = [weights, name, str(r["frames"])] + [cell(k, f) for _, k, f in _COLUMNS + (_SPAN_COLUMNS if span else [])]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--weights", action="append", default=None, help="weights file (repeat); 'default' = shipped")
    ap.add_argument("--set", action="append", default=None,
                    help="name=PATH[@FRAMES] (repeat): these sets instead of the defaults (beside --only's)")
    ap.add_argument("--only", default=None, help="comma list of default set names to evaluate")
    ap.add_argument("--shard-views", type=int, default=256)
    ap.add_argument("--span", action="store_true", help="also where the code's span holds the truth (slower)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--markdown", type=Path, default=None)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--data-dir", type=Path, default=REPO / "data_cache" / "depth_prior_eval",
                    help="where the real and generator sets are written on first use")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from codeslam.depthmodel import DepthModel

    defaults = default_sets(args.data_dir)
    sets = dict(defaults)
    if args.only:
        only = args.only.split(",")
        unknown = sorted(set(only) - sets.keys())
        if unknown:
            ap.error(f"--only: no default set {', '.join(unknown)} (choose from {', '.join(sets)})")
        sets = {k: sets[k] for k in only}
    if args.set:  # the given sets instead of the defaults, or beside those --only names
        bad = [s for s in args.set if "=" not in s]
        if bad:
            ap.error(f"--set takes name=PATH[@FRAMES], got {bad[0]!r}")
        given = dict(s.split("=", 1) for s in args.set)
        sets = (sets if args.only else {}) | given
    results: dict = {}
    rows = table_header(args.span)
    for w in args.weights or ["default"]:
        model = DepthModel.load(None if w == "default" else w)
        results[w] = {}
        for name, spec in sets.items():
            path, _, frames = spec.partition("@")
            if not Path(path).exists() and not (defaults.get(name) == spec
                                                 and prepare_set(name, Path(path), args.data_dir)):
                print(f"skip {name}: {path} not found", flush=True)
                continue
            t0 = time.perf_counter()
            r = evaluate(model, path, frames or None, args.shard_views, span=args.span)
            r["seconds"] = time.perf_counter() - t0
            results[w][name] = r
            row = table_row(Path(w).name if w != "default" else "shipped", name, r, args.span)
            rows.append(row)
            print(row, flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    if args.markdown:
        args.markdown.write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
