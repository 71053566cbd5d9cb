"""A TUM-layout copy of a sequence with its frames in another order, re-timed at the sequence's frame rate: the
probes of a camera that comes back the way it went (`docs/results/slam_table.md`, forty-fifth and forty-sixth
sessions). ``--frames`` of `codeslam slam` keeps a sequence's order and time; these copies change both.

``--order reverse`` plays the frames backwards (last to first); ``--order there-and-back`` plays them forwards and
then backwards to the first frame (the last frame once: at the turn the camera's velocity flips). Frame j of the
copy is stamped ``t0 + j * dt``, with ``t0`` the first frame's stamp and ``dt`` the median interval between frames,
so time always runs forwards. Each frame keeps its own colour image, depth map and ground-truth pose (the pose as
the reader associates it with the colour image; the depth map the reader pairs with it), written as one row of
``rgb.txt``, ``depth.txt`` and ``groundtruth.txt`` each; the image files are copied as they are (calibration with
them), so the reader undistorts the copy exactly as it does the source. Frames without a depth map (by the reader's
association) are left out, as the reader leaves them out.

    python scripts/reorder_copy.py ../shared/data/hololens_dvmvs OUT --order there-and-back
    python scripts/reorder_copy.py ../shared/data/tum_fr1_rpy OUT --order reverse
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from codeslam.data.association import associate
from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.data.tum import TUM_MAX_DIFF_S, TumSequence, read_list_file
from codeslam.errors import CodeSLAMError

ORDERS = ("reverse", "there-and-back")


def frame_order(n: int, order: str) -> list[int]:
    """Indices of the copy's frames into the source's ``n``."""
    if order == "reverse":
        return list(range(n - 1, -1, -1))
    if order == "there-and-back":
        return list(range(n)) + list(range(n - 2, -1, -1))
    raise ValueError(f"unknown order {order!r}")


def retimed(stamps: np.ndarray, count: int) -> np.ndarray:
    """``count`` stamps from the first of ``stamps`` at their median interval."""
    dt = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 1.0
    return stamps[0] + dt * np.arange(count)


def write_copy(src: Path, out: Path, order: str) -> int:
    """The copy in ``out`` (written beside it, then renamed into place); returns its number of frames."""
    seq = TumSequence(src)  # the reader's own association of colour, depth and ground truth
    stamps = seq.timestamps
    rgb_stamps, rgb_files = read_list_file(src / "rgb.txt", src)
    by_stamp = dict(zip(rgb_stamps.tolist(), rgb_files))
    rgb = [by_stamp[float(t)] for t in stamps]
    depth = None
    if seq.has_depth:
        d_stamps, d_files = read_list_file(src / "depth.txt", src)
        ia, ib = associate(stamps, d_stamps, TUM_MAX_DIFF_S)
        assert len(ia) == len(stamps), "the reader kept only frames with a depth map"
        depth = [d_files[j] for j in ib]
    idx = frame_order(len(stamps), order)
    new = retimed(stamps, len(idx))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", dir=out.parent))
    try:
        for name in ("calib.txt", "LICENSE", "README.md"):
            if (src / name).is_file():
                shutil.copy(src / name, tmp / name)
        rows = {"rgb": [], "depth": []}
        for kind, files in (("rgb", rgb), ("depth", depth)):
            if files is None:
                continue
            (tmp / kind).mkdir()
            for i, j in enumerate(idx):
                name = f"{kind}/{new[i]:.6f}{files[j].suffix}"
                shutil.copy(files[j], tmp / name)
                rows[kind].append(f"{new[i]:.6f} {name}\n")
            head = f"# {src.name}, order {order}, re-timed (scripts/reorder_copy.py)\n"
            (tmp / f"{kind}.txt").write_text(head + "".join(rows[kind]))
        gt = seq.gt_poses
        if gt is not None:
            keep = [i for i, j in enumerate(idx) if not bool(gt[j].isnan().any())]
            poses = gt[[idx[i] for i in keep]]
            write_tum(tmp / "groundtruth.txt", Trajectory(new[keep], poses))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return len(idx)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path, help="a TUM-layout sequence (rgb.txt, rgb/, depth.txt, groundtruth.txt)")
    ap.add_argument("out", type=Path, help="the copy's folder (replaced)")
    ap.add_argument("--order", choices=ORDERS, required=True)
    a = ap.parse_args()
    try:
        n = write_copy(a.src, a.out, a.order)
    except (CodeSLAMError, OSError) as e:
        ap.error(str(e))
    print(f"{a.out}: {n} frames")


if __name__ == "__main__":
    main()
