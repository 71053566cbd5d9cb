"""What does a tracked frame's rotation error against its keyframe follow? A diagnosis of a `codeslam slam` run.

For every tracked frame that is not a keyframe, the rotation error of its pose relative to its reference keyframe
(``T_kf``: the run's trajectory re-expresses it on the keyframe's final pose, so ``P_k^-1 P_f`` is the tracked
relative pose) against the ground truth's, and three candidate causes, each from the ground truth:

- ``velocity difference``: |omega_f - omega_k|, the difference of the two frames' angular velocities (degrees per
  frame, central differences in the camera frame). A rolling shutter distorts each image by its own angular
  velocity, so a global-shutter alignment of two images is off by about their difference;
- ``rotation from keyframe``: how far the frame has turned from its keyframe (a narrow basin or a wrong depth would
  show here);
- ``frame velocity``: |omega_f| (motion blur would show here).

Printed per cause: the correlation with the error and the error's RMS for the frames below and above the cause's
median. Measured on TUM fr1/rpy (docs/results/slam_table.md, session of 2026-11-26).

Usage::

    codeslam slam ../shared/data/tum_fr1_rpy --threads 1 --out RUN
    python scripts/rotation_error_vs_velocity.py RUN
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch

from codeslam.data.trajectory import read_tum
from codeslam.errors import CodeSLAMError
from codeslam.eval.metrics import rotation_angle
from codeslam.geometry.lie import so3_log


def angular_velocity(Q: np.ndarray, i: int) -> np.ndarray:
    """Ground-truth angular velocity of frame i in its camera frame, degrees per frame (central difference)."""
    i0, i1 = max(i - 1, 0), min(i + 1, len(Q) - 1)
    return np.degrees(so3_log(torch.from_numpy((np.linalg.inv(Q[i0]) @ Q[i1])[:3, :3])).numpy()) / max(i1 - i0, 1)


def analyse(run: Path) -> dict[str, np.ndarray]:
    """-> per tracked non-keyframe frame: 'error' (degrees) and the three candidate causes."""
    P = read_tum(run / "trajectory.txt").poses.numpy()
    Q = read_tum(run / "groundtruth.txt").poses.numpy()
    with open(run / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not (len(rows) == len(P) == len(Q)):
        raise CodeSLAMError(f"{run}: frames.csv, trajectory.txt and groundtruth.txt differ in length")
    keyframe_row = {int(r["ref_keyframe"]): i for i, r in enumerate(rows) if r["is_keyframe"] == "1"}
    out: dict[str, list[float]] = {"error": [], "velocity difference": [], "rotation from keyframe": [],
                                   "frame velocity": []}
    for i, r in enumerate(rows):
        k = keyframe_row.get(int(r["ref_keyframe"]))
        if r["status"] != "tracked" or r["is_keyframe"] == "1" or k is None or k == i:
            continue
        G = np.linalg.inv(Q[k]) @ Q[i]
        E = np.linalg.inv(G) @ (np.linalg.inv(P[k]) @ P[i])
        out["error"].append(float(np.degrees(rotation_angle(E[None, :3, :3]))[0]))
        out["velocity difference"].append(float(np.linalg.norm(angular_velocity(Q, i) - angular_velocity(Q, k))))
        out["rotation from keyframe"].append(float(np.degrees(rotation_angle(G[None, :3, :3]))[0]))
        out["frame velocity"].append(float(np.linalg.norm(angular_velocity(Q, i))))
    return {k: np.asarray(v) for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+", help="run folders of `codeslam slam --out` on a sequence with "
                    "ground truth")
    args = ap.parse_args(argv)
    try:
        for run in args.runs:
            d = analyse(run)
            err = d["error"]
            if len(err) < 4:
                raise CodeSLAMError(f"{run}: too few tracked frames to analyse ({len(err)})")
            print(f"{run}: {len(err)} frames, rotation error against the keyframe: median {np.median(err):.2f}, "
                  f"RMS {np.sqrt(np.mean(err**2)):.2f} deg")
            for name in ("velocity difference", "rotation from keyframe", "frame velocity"):
                x = d[name]
                lo, hi = err[x <= np.median(x)], err[x > np.median(x)]
                print(f"  {name:24s} corr {np.corrcoef(x, err)[0, 1]:+.2f}; error RMS below its median "
                      f"{np.sqrt(np.mean(lo**2)):.2f}, above {np.sqrt(np.mean(hi**2)):.2f} deg")
    except (CodeSLAMError, OSError, KeyError, ValueError) as e:
        print(f"rotation_error_vs_velocity: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
