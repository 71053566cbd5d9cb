"""A TUM-layout copy of a sequence with its exposure changed, to measure what a brightness change does to the
depth prior (`codeslam depth --mode zero`) and to SLAM (`docs/results/depth_prior_ablation.md`, "The zero code's
scale follows the image's brightness"; `docs/results/slam_table.md`, forty-third session, "Exposure changes").

Every frame from ``--start`` on has its 8-bit values multiplied by ``--gain`` and clipped at 255, as a sensor
saturates (a step, the default start 0 changes every frame); with ``--ramp N`` the gain moves linearly from 1 to
``--gain`` over frames start..start+N and back to 1 by start+2N. Depth, poses and calibration are copied as they are.

    python scripts/issue13/exposure_copy.py ../shared/data/tum_fr1_rpy OUT --gain 0.6
    python scripts/issue13/exposure_copy.py ../shared/data/hololens_dvmvs OUT --gain 0.6 --start 90
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import numpy as np

from codeslam.data.tum import read_list_file
from codeslam.errors import CodeSLAMError


def gain_at(i: int, start: int, gain: float, ramp: int) -> float:
    """The gain of frame i: a step at ``start``, or with ``ramp`` > 0 a triangle peaking at start + ramp."""
    if ramp <= 0:
        return gain if i >= start else 1.0
    x = (i - start) / ramp
    return 1.0 + (gain - 1.0) * max(0.0, 1.0 - abs(x - 1.0)) if 0 <= x <= 2 else 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path, help="a TUM-layout sequence (rgb.txt, rgb/, depth, groundtruth.txt, calib.txt)")
    ap.add_argument("out", type=Path, help="the copy's folder (replaced)")
    ap.add_argument("--gain", type=float, required=True, help="factor on the 8-bit values")
    ap.add_argument("--start", type=int, default=0, help="first frame changed (default 0: every frame)")
    ap.add_argument("--ramp", type=int, default=0, help="frames over which the gain ramps in and out again")
    a = ap.parse_args()
    if a.gain <= 0:
        ap.error("--gain must be positive")
    try:  # the readers' own parser and checks: two fields a line, files inside the folder
        _, files = read_list_file(a.src / "rgb.txt", a.src)
    except (CodeSLAMError, OSError) as e:
        ap.error(str(e))
    shutil.rmtree(a.out, ignore_errors=True)
    a.out.mkdir(parents=True)
    for name in ("depth", "depth.txt", "groundtruth.txt", "calib.txt", "rgb.txt"):
        p = a.src / name
        if p.is_dir():
            shutil.copytree(p, a.out / name)
        elif p.exists():
            shutil.copy(p, a.out / name)
    for i, rel in enumerate(f.relative_to(a.src) for f in files):
        g = gain_at(i, a.start, a.gain, a.ramp)
        img = cv2.imread(str(a.src / rel), cv2.IMREAD_UNCHANGED)
        if g != 1.0:
            img = np.clip(img.astype(np.float32) * g, 0, 255).astype(np.uint8)
        (a.out / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(a.out / rel), img)
    print(a.out)


if __name__ == "__main__":
    main()
