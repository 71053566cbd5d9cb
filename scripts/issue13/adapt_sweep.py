"""Issue 13, item 3: how far does `codeslam adapt` go when it may run long (a lent GPU)?

Two steps, so that the GPU machine needs neither ``../shared`` nor the readers' undistortion:

``pack``  (here): one recording's frames at the network's canonical camera, split into an adaptation half (images,
          validity, the poses `codeslam slam` estimated on that half alone; no depth) and a held-out half (images and
          ground-truth depth, for evaluation only), into one small safetensors file.

          python scripts/issue13/adapt_sweep.py pack DATA --train 0:94 --test 94:188 --poses SLAM/trajectory.txt \\
              --out PACK.safetensors

``run``   (anywhere): adapt the shipped weights on the adaptation half with one AdaptConfig (overrides as
          key=value), then measure the zero-code prior on the held-out half before and after (the numbers of
          scripts/depth_prior_eval.py: proximity RMSE, best constant, ratio, median depth ratio, scaled RMSE), and
          append one JSON line to --results.

          python scripts/issue13/adapt_sweep.py run PACK.safetensors --name NAME --device cuda --results R.jsonl \\
              [--keep-weights W.safetensors] --set steps=3000 --set lr=1e-4 --set anchor=1 --set trainable=all

The held-out half is never seen by the adaptation; its depth is read only by the evaluation.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # scripts/ (depth_prior_eval)


def _frames(spec: str) -> range:
    a, b = (int(x) for x in spec.split(":"))
    return range(a, b)


def pack(args) -> None:
    import numpy as np
    from safetensors.torch import save_file

    from codeslam.cli.common import open_frames
    from codeslam.data.association import interpolate_poses
    from codeslam.data.trajectory_file import load_trajectory
    from codeslam.depthmodel import DepthModel

    model = DepthModel.load(None)
    seq, _ = open_frames(Path(args.data), None, None)
    out = {}
    for part, spec in (("train", args.train), ("test", args.test)):
        imgs, valid, depth, stamps = [], [], [], []
        for i in _frames(spec):
            f = model.canonical(seq[i])
            imgs.append((f.image.clamp(0, 1) * 255).round().to(torch.uint8))  # 8 bits: the pack travels
            valid.append(torch.ones_like(f.image[0], dtype=torch.bool) if f.valid is None else f.valid)
            stamps.append(f.timestamp)
            if part == "test":
                depth.append(f.depth.float())
        out[f"{part}_images"] = torch.stack(imgs)
        out[f"{part}_valid"] = torch.stack(valid).to(torch.uint8)
        out[f"{part}_stamps"] = torch.tensor(stamps, dtype=torch.float64)
        if part == "test":
            out["test_depth"] = torch.stack(depth).to(torch.float16)
    if args.poses:
        traj = load_trajectory(Path(args.poses))
        T, ok = interpolate_poses(traj, np.array(out["train_stamps"].numpy()), max_gap=1.0)
        if not bool(ok.all()):
            raise SystemExit(f"{args.poses} does not cover every adaptation frame")
        out["train_poses"] = torch.as_tensor(np.asarray(T), dtype=torch.float64)
    save_file(out, args.out, metadata={"data": str(args.data), "train": args.train, "test": args.test,
                                       "poses": str(args.poses or "")})
    print(f"packed {args.out}: train {tuple(out['train_images'].shape)}, test {tuple(out['test_images'].shape)}")


def _zero_prox(network, x: torch.Tensor) -> torch.Tensor:
    feats = network.image_features(x)
    return network.decode(feats, feats[0].new_zeros(x.shape[0], network.code_size))[0][:, 0]


def _prior(network, images: torch.Tensor, depth: torch.Tensor, a: float, scale_from=None) -> dict:
    """The zero-code prior's statistics on ``images``; with ``scale_from`` (another network), every image's
    predicted depth is first rescaled so that its mean log depth is that network's: shape from ``network``, scale
    from ``scale_from``."""
    from depth_prior_eval import PriorStats

    from codeslam.geometry.proximity import depth_to_prox, prox_to_depth
    from codeslam.network.model import to_network_image

    stats = PriorStats()
    dev = next(network.parameters()).device
    network.eval()
    with torch.no_grad():
        for s in range(0, images.shape[0], 16):
            x = to_network_image(images[s:s + 16].to(dev).float() / 255.0, network.config.in_channels)
            prox = _zero_prox(network, x)
            if scale_from is not None:
                log_d = prox_to_depth(prox, a).log()
                log_ref = prox_to_depth(_zero_prox(scale_from, x), a).log()
                shift = (log_ref.mean(dim=(-2, -1)) - log_d.mean(dim=(-2, -1)))[:, None, None]
                prox = depth_to_prox((log_d + shift).exp(), a)
            stats.add(prox.cpu(), depth[s:s + 16].float(), a)
    return stats.result()


def evaluate_weights(args) -> None:
    """The held-out statistics of a weights file, as is and with the shipped network's scale per image."""
    from safetensors.torch import load_file

    from codeslam.depthmodel import DepthModel

    p = load_file(args.pack)
    start = DepthModel.load(None, device=args.device).network
    for w in args.weights:
        net = DepthModel.load(None if w == "default" else w, device=args.device).network
        row = {"weights": w, "pack": Path(args.pack).name,
               "as_is": _prior(net, p["test_images"], p["test_depth"], start.avg_depth),
               "start_scale": _prior(net, p["test_images"], p["test_depth"], start.avg_depth, scale_from=start)}
        r0, r1 = row["as_is"], row["start_scale"]
        print(f"{w}: zero RMSE {r0['zero_rmse']:.4f} (median {r0['median_depth_ratio']:.3f}), with the start "
              f"network's scale {r1['zero_rmse']:.4f} (median {r1['median_depth_ratio']:.3f}); scaled "
              f"{r0['si_rmse']:.4f}", flush=True)
        if args.results:
            with open(args.results, "a") as f:
                f.write(json.dumps(row) + "\n")


def run(args) -> None:
    from safetensors.torch import load_file

    from codeslam.depthmodel import DepthModel
    from codeslam.network.adapt import AdaptConfig, adapt

    torch.manual_seed(0)
    p = load_file(args.pack)
    model = DepthModel.load(None, device=args.device)
    net = model.network
    overrides = {}
    for kv in args.overrides:
        k, v = kv.split("=", 1)
        field = AdaptConfig.__dataclass_fields__[k]
        overrides[k] = tuple(int(x) for x in v.split(",")) if k == "neighbours" else type(field.default)(v)
    cfg = dataclasses.replace(AdaptConfig(), **overrides)
    a = model.avg_depth
    before = _prior(net, p["test_images"], p["test_depth"], a)
    t0 = time.perf_counter()
    # in chunks, so that a job that runs slower than planned still reports how far it got (resume is exact)
    done, res = 0, None
    while done < cfg.steps:
        res = adapt(net, p["train_images"].float() / 255.0, Path(args.work) / args.name, cfg,
                    valid=p["train_valid"].bool(), poses=p.get("train_poses"), resume=done > 0,
                    stop_after=min(done + args.chunk, cfg.steps))
        done = res.step
        if time.perf_counter() - t0 > args.max_seconds and done < cfg.steps:
            print(f"{args.name}: stopped at step {done} of {cfg.steps} after {args.max_seconds} s", flush=True)
            break
    secs = time.perf_counter() - t0
    after = _prior(net, p["test_images"], p["test_depth"], a)
    row = {"name": args.name, "pack": Path(args.pack).name, "config": overrides, "trainable": cfg.trainable,
           "lr": cfg.lr, "seconds": round(secs, 1),
           "steps_done": done, "finished": bool(res.finished),
           "device": args.device, "last": res.last, "before": before, "after": after}
    with open(args.results, "a") as f:
        f.write(json.dumps(row) + "\n")
    print(f"{args.name}: {secs:.0f} s, held-out zero RMSE {before['zero_rmse']:.4f} -> {after['zero_rmse']:.4f}, "
          f"scaled {before['si_rmse']:.4f} -> {after['si_rmse']:.4f}, median {before['median_depth_ratio']:.2f} -> "
          f"{after['median_depth_ratio']:.2f}", flush=True)
    if args.keep_weights and res.finished:
        import shutil

        shutil.copyfile(Path(args.work) / args.name / "weights.safetensors", args.keep_weights)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    pk = sub.add_parser("pack")
    pk.add_argument("data")
    pk.add_argument("--train", required=True)
    pk.add_argument("--test", required=True)
    pk.add_argument("--poses", default=None)
    pk.add_argument("--out", required=True)
    ev = sub.add_parser("eval")
    ev.add_argument("pack")
    ev.add_argument("--weights", action="append", required=True)
    ev.add_argument("--device", default="cpu")
    ev.add_argument("--results", default=None)
    rn = sub.add_parser("run")
    rn.add_argument("pack")
    rn.add_argument("--name", required=True)
    rn.add_argument("--device", default="cpu")
    rn.add_argument("--results", required=True)
    rn.add_argument("--work", default="/tmp/adapt_sweep")
    rn.add_argument("--keep-weights", default=None)
    rn.add_argument("--threads", type=int, default=1)
    rn.add_argument("--chunk", type=int, default=250, help="steps between time checks")
    rn.add_argument("--max-seconds", type=float, default=1e9, help="stop after the chunk that passes this")
    rn.add_argument("--set", dest="overrides", action="append", default=[], help="AdaptConfig field=value")
    args = ap.parse_args()
    if args.cmd == "pack":
        pack(args)
    elif args.cmd == "eval":
        evaluate_weights(args)
    else:
        torch.set_num_threads(args.threads)
        run(args)


if __name__ == "__main__":
    main()
