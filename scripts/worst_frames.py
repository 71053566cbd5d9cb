"""Where did a SLAM run go wrong? The frames with the largest frame-to-frame rotation error, beside what the run's
per-frame log says about them (status, keyframe decision, reference keyframe, pose source, overlap, explained
variance, feature inliers, window rollbacks).

    python scripts/worst_frames.py RUN_DIR [--top 12]

RUN_DIR is a `codeslam slam --out` folder with ground truth (trajectory.txt, groundtruth.txt, frames.csv).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from codeslam.data.trajectory import read_tum
from codeslam.eval.metrics import match_trajectories, relative_motion_errors, rotation_angle

LOG_COLUMNS = ("status", "is_keyframe", "keyframe_reason", "ref_keyframe", "source", "overlap", "explained",
               "feature_inliers", "feature_matches", "rolled_back", "reason")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("--top", type=int, default=12)
    args = ap.parse_args()
    est, ref = read_tum(args.run / "trajectory.txt"), read_tum(args.run / "groundtruth.txt")
    i_est, i_ref = match_trajectories(est, ref)
    P = est.poses.detach().cpu().numpy()[i_est]
    Q = ref.poses.detach().cpu().numpy()[i_ref]
    k = np.arange(len(P) - 1)
    E = relative_motion_errors(P, Q, k, k + 1)
    rot = np.degrees(rotation_angle(E[:, :3, :3]))
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    with open(args.run / "frames.csv", newline="") as f:
        log = {int(r["frame"]): r for r in csv.DictReader(f)}
    frames = [int(r) for r in sorted(log)]  # frame indices in processing order, as the trajectory's rows
    print(f"{len(rot)} frame pairs; rotation error median {np.median(rot):.2f} deg, max {rot.max():.2f} deg")
    for n in np.argsort(-rot)[: args.top]:
        frame = frames[i_est[n + 1]] if i_est[n + 1] < len(frames) else i_est[n + 1]
        row = log.get(frame, {})
        info = "  ".join(f"{c}={row.get(c, '')}" for c in LOG_COLUMNS if row.get(c, ""))
        print(f"frame {frame}: rot {rot[n]:.2f} deg, trans {trans[n] * 1000:.0f} mm  {info}")


if __name__ == "__main__":
    main()
