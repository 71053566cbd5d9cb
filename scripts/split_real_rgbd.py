"""Split the real RGB-D folders of ``../shared/train_data`` into a fine-tuning part and a validation part.

Each split is a TUM-layout folder with the selected lines of the list files (``rgb.txt``, ``depth.txt``,
``groundtruth.txt`` where the source has poses), copies of the files they name (the readers refuse links that
leave the folder) and of ``calib.txt``; nothing is changed. Splits are contiguous (the first frames train, the
last validate), so neighbouring frames of one recording rarely straddle them:

=========================================  ======  =====  ===========================================
folder                                     train   val    note
=========================================  ======  =====  ===========================================
tum_fr3_cabinet_kf                         0-39    40-57  58 keyframes, 0.67 s apart
realsense_room_floorlevel_felixchenfy      0-6     7-10
redwood_livingroom_synthetic_open3d        0-2     3-4    synthetic (ICL-NUIM with a noise model)
tum_fr3_office_single_open3d               -       0      one frame: validation only
=========================================  ======  =====  ===========================================

    python scripts/split_real_rgbd.py [--src ../shared/train_data] [--out /work/train_data/real_split]

writes OUT/train/<folder> and OUT/val/<folder>.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

#: folder -> number of leading frames used for fine-tuning (the rest validate)
TRAIN_FRAMES = {
    "tum_fr3_cabinet_kf": 40,
    "realsense_room_floorlevel_felixchenfy": 7,
    "redwood_livingroom_synthetic_open3d": 3,
    "tum_fr3_office_single_open3d": 0,
}


def _entries(path: Path) -> tuple[list[str], list[str]]:
    """(comment lines, data lines) of a TUM list file."""
    lines = path.read_text().splitlines()
    return [x for x in lines if x.startswith("#")], [x for x in lines if x.strip() and not x.startswith("#")]


def write_split(src: Path, dst: Path, keep: slice) -> int:
    """A TUM folder at ``dst`` holding frames ``keep`` of ``src`` by reference; returns the frame count."""
    dst.mkdir(parents=True, exist_ok=True)
    n = 0
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        if not (src / name).is_file():
            continue
        head, rows = _entries(src / name)
        rows = rows[keep]
        n = len(rows)
        (dst / name).write_text("\n".join(head + [f"# split of {src} ({keep.start}:{keep.stop})"] + rows) + "\n")
        if name != "groundtruth.txt":
            for row in rows:
                rel = row.split()[1]
                (dst / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src / rel, dst / rel)
    (dst / "calib.txt").write_text((src / "calib.txt").read_text())
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "train_data")
    ap.add_argument("--out", type=Path, default=Path("/work/train_data/real_split"))
    args = ap.parse_args()
    for folder, k in TRAIN_FRAMES.items():
        src = args.src / folder
        total = len(_entries(src / "rgb.txt")[1])
        if k > 0:
            print(f"train/{folder}: {write_split(src, args.out / 'train' / folder, slice(0, k))} frames")
        print(f"val/{folder}: {write_split(src, args.out / 'val' / folder, slice(k, total))} frames")


if __name__ == "__main__":
    main()
