"""Experiment (issue 13, item 3): adapt the network's zero-code depth to a video by distilling the depths that a
`codeslam slam` run's window optimised for its keyframes (multi-view, no sensor depth), not yet a command.

The window's keyframe depths are much better in shape than the single-view prior they start from (HoloLens walk:
proximity RMSE after per-frame median scaling 0.075 -> 0.034 over 88 keyframes). Here the network is fine-tuned so
that its zero-code depth takes that shape: a scale-invariant log-depth loss against the run's final keyframe
depths (``keyframes.npz``: ``image`` and ``depth``; its ``depth_gt`` is never read), a term that holds each
image's mean log depth at the start network's (the video cannot tell the scale), and an L2 anchor to the start
weights. Pixels of the black border (an image at 0) do not count.

    codeslam slam DATA --frames 0:94 --threads 2 -q --out RUN
    python scripts/issue13/map_distil.py RUN/keyframes.npz OUT.safetensors [--steps 100] [--lr 5e-5]
    python scripts/depth_prior_eval.py --weights default --weights OUT.safetensors --set hold=DATA@94:188:2
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from codeslam.depthmodel import DepthModel
from codeslam.geometry.proximity import prox_to_depth
from codeslam.network.model import to_network_image
from codeslam.network.weights import save_weights


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("keyframes", help="keyframes.npz of a codeslam slam run")
    ap.add_argument("out", help="adapted weights (safetensors)")
    ap.add_argument("--weights", default=None, help="start weights (default: the shipped ones)")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--lr", type=float, default=5e-5)
    ap.add_argument("--anchor", type=float, default=1e-2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    torch.set_num_threads(a.threads)
    z = np.load(a.keyframes)
    img = torch.from_numpy(z["image"]).float()  # (K, 3, H, W) in the network's canonical camera
    target = torch.from_numpy(z["depth"]).float()  # (K, H, W) the window's final depths
    model = DepthModel.load(a.weights)
    net, avg, C = model.network, model.avg_depth, model.code_size
    x = to_network_image(img, model.config.in_channels)

    def zero_log_depth(xb: torch.Tensor) -> torch.Tensor:
        prox = net.decode(net.image_features(xb), torch.zeros(len(xb), C))[0][:, 0]
        return prox_to_depth(prox, avg).clamp_min(1e-3).log()

    with torch.no_grad():
        start = zero_log_depth(x).mean((1, 2))
    ok = (target > 0) & torch.isfinite(target) & (img.sum(1) > 0.02)
    p0 = [p.detach().clone() for p in net.parameters()]
    opt = torch.optim.Adam(net.parameters(), lr=a.lr)
    for step in range(a.steps):
        idx = torch.randperm(len(img))[:a.batch]
        ld, mk = zero_log_depth(x[idx]), ok[idx]
        r = torch.where(mk, ld - target[idx].clamp_min(1e-3).log(), torch.zeros(()))
        n = mk.sum((1, 2)).clamp_min(1)
        si = ((r - (r.sum((1, 2)) / n)[:, None, None]) ** 2 * mk).sum((1, 2)) / n  # shape, scale-free
        scale = (ld.mean((1, 2)) - start[idx]) ** 2
        anchor = sum(((p - q) ** 2).sum() for p, q in zip(net.parameters(), p0))
        loss = si.mean() + scale.mean() + a.anchor * anchor
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 20 == 0 or step == a.steps - 1:
            print(f"step {step}: shape {si.mean().item():.4f}, scale {scale.mean().item():.5f}, "
                  f"anchor {anchor.item():.3f}", flush=True)
    save_weights(a.out, net)


if __name__ == "__main__":
    main()
