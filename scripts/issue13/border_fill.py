"""The issue-13 border-fill experiment (docs/results/depth_prior_ablation.md, session of 2026-11-29): the black
border of a narrower camera filled with the nearest real pixel, in training (the bands of
``camera_effects.narrow_field_of_view``) and at inference (outside a frame's validity mask). Patches only: the
product is unchanged. Each subcommand runs a codeslam command or script with or without the fill:

    python scripts/issue13/border_fill.py train fill|black -- codeslam train ARGS     (the bands)
    python scripts/issue13/border_fill.py eval fill|black -- depth_prior_eval.py ARGS (the frames, at inference)
    python scripts/issue13/border_fill.py slam fill|black -- codeslam slam ARGS       (SLAM's keyframes)

``black`` runs the same command unpatched (the control). The fine-tune's config: ``border_fill.yaml``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

SCRIPTS = Path(__file__).resolve().parents[1]


def fill_bands_nearest(image: torch.Tensor, depth: torch.Tensor, bands: torch.Tensor):
    """As ``camera_effects.narrow_field_of_view`` (the same bands), but the image's band pixels take the nearest
    seen pixel's colour; the depth is still invalid there."""
    B, _, H, W = image.shape
    out_i, out_d = image.clone(), depth.clone()
    r = torch.arange(H, device=image.device) + 0.5
    c = torch.arange(W, device=image.device) + 0.5
    for b in range(B):
        rs = (r >= float(bands[b, 0]) * H) & (r <= H - float(bands[b, 1]) * H)
        cs = (c >= float(bands[b, 2]) * W) & (c <= W - float(bands[b, 3]) * W)
        if not (bool(rs.any()) and bool(cs.any())):
            continue
        ri = torch.arange(H, device=image.device).clamp(int(rs.nonzero()[0]), int(rs.nonzero()[-1]))
        ci = torch.arange(W, device=image.device).clamp(int(cs.nonzero()[0]), int(cs.nonzero()[-1]))
        out_i[b] = image[b][:, ri][:, :, ci]
        out_d[b] = depth[b] * (rs[:, None] & cs[None, :]).to(depth.dtype)
    return out_i, out_d


def fill_outside(image: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
    """(3, H, W) image, (H, W) bool real pixels -> every pixel outside ``valid`` takes the nearest real pixel's
    value (OpenCV's distance transform with a label per real pixel)."""
    if valid is None or bool(valid.all()) or not bool(valid.any()):
        return image
    outside = (~valid).cpu().numpy().astype(np.uint8)
    _, labels = cv2.distanceTransformWithLabels(outside, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(outside == 0)
    where = np.zeros((labels.max() + 1, 2), dtype=np.int64)
    where[labels[ys, xs]] = np.stack([ys, xs], 1)
    src = torch.from_numpy(where[labels]).to(image.device)  # (H, W, 2): the nearest real pixel of each
    return image[:, src[..., 0], src[..., 1]]


def patch_training() -> None:
    from codeslam.network import camera_effects

    camera_effects.narrow_field_of_view = fill_bands_nearest


def patch_slam() -> None:
    from codeslam.slam import depth

    network_depth_model = depth.network_depth_model

    def filled(model):
        decode = network_depth_model(model)
        return lambda frame: decode(dataclasses.replace(frame, image=fill_outside(frame.image, frame.valid)))

    depth.network_depth_model = filled


def run_eval(fill: bool, argv: list[str]) -> None:
    spec = importlib.util.spec_from_file_location("depth_prior_eval", SCRIPTS / "depth_prior_eval.py")
    dpe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dpe)
    if fill:
        def frames(model, path, frames):
            from codeslam.cli.common import open_frames

            seq, idx = open_frames(Path(path), None, frames)
            for i in idx:
                f = model.canonical(seq[i])
                yield fill_outside(f.image, f.valid), f.depth

        dpe._dataset_frames = frames
    sys.argv = ["depth_prior_eval.py", *argv]
    dpe.main()


def main() -> None:
    if len(sys.argv) < 4 or sys.argv[1] not in ("train", "eval", "slam") or sys.argv[2] not in ("fill", "black"):
        sys.exit(__doc__)
    what, fill, argv = sys.argv[1], sys.argv[2] == "fill", [a for a in sys.argv[3:] if a != "--"]
    if what == "eval":
        return run_eval(fill, argv)
    if fill:
        (patch_training if what == "train" else patch_slam)()
    from codeslam.cli import main as codeslam

    sys.argv = ["codeslam", *argv[1:]] if argv[:1] == ["codeslam"] else ["codeslam", *argv]
    codeslam()


if __name__ == "__main__":
    main()
