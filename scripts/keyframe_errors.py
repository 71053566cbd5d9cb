"""Is a SLAM run's error the map's or the tracked frames'? ATE after Sim(3) alignment over all frames and over
the keyframes alone, and each step between consecutive keyframes: the true translation (the keyframes'
baseline), the estimated one and their difference, beside the rotation error of the step. Then each keyframe's
pose in the keyframe it was tracked against, as the tracker gave it (``keyframes.npz``: ``tracked_from``,
``T_tracked``) and as the final map has it, against the truth: the rotation error and the angle between the
estimated and the true translation's direction (both scale-free). Where the final map is no better than the
tracker, the window did not correct it (e.g. solves cut short in the parallel mode).

    python scripts/keyframe_errors.py RUN_DIR [--steps]

RUN_DIR is a `codeslam slam --out` folder with ground truth (trajectory.txt, groundtruth.txt, frames.csv,
keyframes.npz). The keyframe steps are compared before any alignment (each in its first keyframe's camera), so
with the network's depth their translations carry the map's scale; read them with the dataset's depth
(``--depth-model standin``), whose scale is the truth's.
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
    npz = args.run / "keyframes.npz"
    if npz.is_file():
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        tracked_errors(arrays, ref, args.steps)


def direction_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K, 3), (K, 3) -> (K,) angle in degrees between each pair of vectors (NaN where either is zero)."""
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.einsum("ki,ki->k", a, b) / (na * nb)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def tracked_errors(kf: dict[str, np.ndarray], ref: Trajectory, steps: bool = False) -> dict[str, np.ndarray] | None:
    """Each keyframe's pose in the keyframe it was tracked against, tracked and final, against the truth (module
    docstring); prints medians (and every keyframe with ``steps``) and returns the per-keyframe arrays (frame,
    reference frame, tracked and final rotation error, tracked and final translation direction error, degrees),
    or None when the file predates the tracked poses or no keyframe has one."""
    if "tracked_from" not in kf or "T_tracked" not in kf:
        print("keyframes.npz holds no tracked poses (written before they were kept)")
        return None
    est = Trajectory(kf["timestamp"], kf["T_wc"])
    i_est, i_ref = match_trajectories(est, ref, min_matches=1)
    Q = np.full(kf["T_wc"].shape, np.nan)  # each keyframe's true pose (NaN: none matched)
    Q[i_est] = ref.poses.detach().cpu().numpy()[i_ref]
    pos = {int(i): n for n, i in enumerate(kf["id"])}
    pairs = [(pos[int(r)], n) for n, r in enumerate(kf["tracked_from"]) if int(r) in pos]
    pairs = [(m, n) for m, n in pairs if np.isfinite(Q[[m, n]]).all() and np.isfinite(kf["T_tracked"][n]).all()]
    if not pairs:
        print("no keyframe has a tracked pose with ground truth for it and its reference")
        return None
    m, n = np.array(pairs).T  # each keyframe n and the keyframe m it was tracked against
    true_rel = relative_poses(Q, m, n)
    tracked, final = kf["T_tracked"][n], relative_poses(kf["T_wc"], m, n)  # keyframe n in m, as tracked and final
    E_tracked, E_final = np.linalg.inv(true_rel) @ np.stack([tracked, final])  # each motion's error, as the RPE's
    out = {
        "frame": kf["frame_index"][n], "reference": kf["frame_index"][m],
        "tracked_rotation": np.degrees(rotation_angle(E_tracked[:, :3, :3])),
        "final_rotation": np.degrees(rotation_angle(E_final[:, :3, :3])),
        "tracked_direction": direction_angle(tracked[:, :3, 3], true_rel[:, :3, 3]),
        "final_direction": direction_angle(final[:, :3, 3], true_rel[:, :3, 3]),
    }
    gap = out["frame"] - out["reference"]
    print(f"keyframes in their tracking reference ({len(n)}, median {np.median(gap):.0f} frames apart): rotation "
          f"error median {np.median(out['tracked_rotation']):.2f} deg tracked, "
          f"{np.median(out['final_rotation']):.2f} deg in the final map; translation direction error median "
          f"{np.nanmedian(out['tracked_direction']):.1f} deg tracked, {np.nanmedian(out['final_direction']):.1f} "
          f"deg in the final map")
    if steps:
        for k in range(len(n)):
            print(f"frame {out['frame'][k]:>4} in {out['reference'][k]:>4}: rotation {out['tracked_rotation'][k]:.2f}"
                  f" -> {out['final_rotation'][k]:.2f} deg, direction {out['tracked_direction'][k]:.1f} -> "
                  f"{out['final_direction'][k]:.1f} deg")
    return out


if __name__ == "__main__":
    main()
