"""Is a SLAM run's error the map's or the tracked frames'? ATE after Sim(3) alignment over all frames and over
the keyframes alone, and each step between consecutive keyframes: the true translation (the keyframes'
baseline), the estimated one and their difference, beside the rotation error of the step.

    python scripts/keyframe_errors.py RUN_DIR [--steps]

RUN_DIR is a `codeslam slam --out` folder with ground truth (trajectory.txt, groundtruth.txt, frames.csv). The
keyframe steps are compared before any alignment (each in its first keyframe's camera), so with the network's
depth their translations carry the map's scale; read them with the dataset's depth (``--depth-model standin``),
whose scale is the truth's.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from codeslam.data.trajectory import Trajectory, read_tum
from codeslam.eval.metrics import ate, match_trajectories, relative_motion_errors, relative_poses, rotation_angle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("--steps", action="store_true", help="print every keyframe-to-keyframe step")
    args = ap.parse_args()
    est, ref = read_tum(args.run / "trajectory.txt"), read_tum(args.run / "groundtruth.txt")
    i_est, i_ref = match_trajectories(est, ref)
    P = est.poses.detach().cpu().numpy()[i_est].astype(np.float64)
    Q = ref.poses.detach().cpu().numpy()[i_ref].astype(np.float64)
    with open(args.run / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))  # in processing order, as the trajectory's rows
    is_kf = np.array([rows[i]["is_keyframe"] == "1" if i < len(rows) else False for i in i_est])
    kf = np.nonzero(is_kf)[0]
    keyframes = Trajectory(est.timestamps[i_est[kf]], est.poses[i_est[kf]])
    print(f"ATE Sim(3): {ate(est, ref, 'sim3').rmse:.4f} m over {len(P)} frames, "
          f"{ate(keyframes, ref, 'sim3').rmse:.4f} m over its {len(kf)} keyframes")
    if len(kf) < 2:
        return
    E = relative_motion_errors(P, Q, kf[:-1], kf[1:])  # each step's error, in its first keyframe's camera
    t_true = np.linalg.norm(relative_poses(Q, kf[:-1], kf[1:])[:, :3, 3], axis=1)
    t_est = np.linalg.norm(relative_poses(P, kf[:-1], kf[1:])[:, :3, 3], axis=1)
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angle(E[:, :3, :3]))
    print(f"keyframe steps: true translation median {1e3 * np.median(t_true):.1f} mm "
          f"({1e3 * t_true.min():.1f}-{1e3 * t_true.max():.1f}), estimated {1e3 * np.median(t_est):.1f} mm, "
          f"error median {1e3 * np.median(t_err):.1f} mm, rotation error median {np.median(rot):.2f} deg")
    if args.steps:
        for n, (a, b) in enumerate(zip(kf[:-1], kf[1:])):
            print(f"frames {rows[i_est[a]]['frame']:>4} -> {rows[i_est[b]]['frame']:>4}: true {1e3 * t_true[n]:6.1f} "
                  f"mm, estimated {1e3 * t_est[n]:6.1f} mm, error {1e3 * t_err[n]:6.1f} mm, rotation {rot[n]:.2f} deg")


if __name__ == "__main__":
    main()
