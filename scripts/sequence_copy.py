"""A TUM-layout copy of a sequence with its frames in another order, or seen by a camera turned upside down: the
probes of a camera that comes back the way it went and of a sensor whose rows are read from the image's bottom up
(`docs/results/slam_table.md`, forty-fifth and forty-sixth sessions). ``--frames`` of `codeslam slam` keeps a
sequence's order and time; these copies change them.

``--order reverse`` plays the frames backwards (last to first); ``--order there-and-back`` plays them forwards and
then backwards to the first frame (the last frame once: at the turn the camera's velocity flips); the default,
``forward``, keeps them. A reordered frame j is stamped ``t0 + j * dt``, with ``t0`` the first frame's stamp and
``dt`` the median interval between frames, so time always runs forwards. Each frame keeps its own colour image,
depth map and ground-truth pose (the pose as the reader associates it with the colour image; the depth map the
reader pairs with it), written as one row of ``rgb.txt``, ``depth.txt`` and ``groundtruth.txt`` each; image files
are copied as they are, and the calibration with them, so the reader undistorts the copy as it does the source.
Frames without a depth map (by the reader's association) are left out, as the reader leaves them out.

``--repeat N`` plays that order N times over, one after the other (there and back N times: a loop per repeat, the
turning frames shown once), as a long recording of the same room (`slam_table.md`, forty-seventh session); a
frame shown again is a hard link to its first copy, so the copy takes the source's space once.

``--hold F:K`` shows the copy's frame F again K times right after it (the order's frame F, counted from 0), each
time with fresh Gaussian noise of ``--hold-noise`` grey levels (default 1.5; 0: the same file), at F's depth and pose:
a camera held still for K frame intervals, as a person stops to look (`slam_table.md`, forty-ninth session). The
frame was taken by a moving camera, so its motion blur and, with a rolling shutter, its skew stay in every copy,
which a camera standing still would not show: a probe for global-shutter sequences (the HoloLens walk, the
generator's).

``--occluder F:N`` draws a band over the copy's frames F to F + N - 1, ``--occluder-width`` of the image wide (default
0.3) and as high as the image, sweeping at a constant speed from beyond the left edge to beyond the right one, with
its own fixed texture (Gaussian noise blurred by 2 px, mean grey 60, ``--occluder-contrast`` grey levels of
standard deviation, default 45; 0: a flat band): a person walking past the camera, which no depth map or pose
sees (depth and poses are the source's).

``--cover F:N`` shows a covered lens in the copy's frames F to F + N - 1: grey level 3 with Gaussian noise of one grey
level, while depth and poses go on as the source's (the camera moves under the cover; `slam_table.md`, fiftieth
session). ``--play SPEC`` plays the source frames listed, in that order, retimed as ``--order`` retimes them:
comma-separated parts, each one index ``I`` or a range ``START:END`` (END excluded), in any order and as often as
wanted; ``--play 0:100,20:70`` is a camera carried back from frame 99 to frame 20 within one frame interval (a
kidnapped camera, which the relocalisation must find again).

``--upside-down`` turns every image and depth map by 180 degrees: the camera mounted upside down. Its calibration
follows (principal point mirrored, ``cx' = W - 1 - cx``, ``cy' = H - 1 - cy``; tangential distortion negated, the
radial terms as they are) and so does its pose (``T_wc Rz(180)``: the camera's x and y axes reversed). A rolling
shutter then reads the rows from the image's bottom up.

``--video ROTATION`` writes a phone's kind of video instead: the reader's (undistorted) colour frames as an H.264
``video.mp4`` at the sequence's median frame rate, stored as the sensor saw them with a display rotation of 0, 90,
180 or 270 degrees (counter-clockwise, as a phone stores a portrait video: 90), a ``camera.yaml`` for the frames as
a player turns them (``codeslam slam OUT/video.mp4 --camera OUT/camera.yaml``) and ``groundtruth.txt`` at the
video's times (from 0) with the camera turned as the frames are (``codeslam eval``). A quarter turn puts the sensor's
rows along the turned frames' columns.

    python scripts/sequence_copy.py ../shared/data/hololens_dvmvs OUT --order there-and-back
    python scripts/sequence_copy.py ../shared/data/tum_fr1_rpy OUT --upside-down
    python scripts/sequence_copy.py ../shared/data/tum_fr1_rpy OUT --order there-and-back --repeat 10
    python scripts/sequence_copy.py ../shared/data/tum_fr1_rpy OUT --video 90
    python scripts/sequence_copy.py ../shared/data/hololens_dvmvs OUT --hold 60:40
    python scripts/sequence_copy.py ../shared/data/tum_fr1_rpy OUT --occluder 100:20 --occluder-contrast 8
    python scripts/sequence_copy.py ../shared/data/tum_fr1_rpy OUT --cover 60:30
    python scripts/sequence_copy.py ../shared/data/hololens_dvmvs OUT --play 0:100,20:70
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.data.tum import TumSequence
from codeslam.errors import CodeSLAMError

ORDERS = ("forward", "reverse", "there-and-back")
UPSIDE_DOWN = torch.diag(torch.tensor([-1.0, -1.0, 1.0, 1.0], dtype=torch.float64))  # Rz(180): the camera's turn


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """A folder beside ``out`` to write the copy in, renamed to ``out`` (replacing it) when the block ends, removed
    when it fails: never a half-written copy."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", dir=out.parent))
    try:
        yield tmp
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def frame_order(n: int, order: str, repeat: int = 1) -> list[int]:
    """Indices of the copy's frames into the source's ``n``, the order played ``repeat`` times."""
    if repeat < 1:
        raise ValueError(f"repeat must be at least 1, got {repeat}")
    if order == "forward":
        return list(range(n)) * repeat
    if order == "reverse":
        return list(range(n - 1, -1, -1)) * repeat
    if order == "there-and-back":  # each loop ends where the next begins: the first frame once between them
        return (list(range(n)) + list(range(n - 2, 0, -1))) * repeat + [0] if n > 1 else [0] * repeat
    raise ValueError(f"unknown order {order!r}")


def held(idx: list[int], frame: int, count: int) -> tuple[list[int], list[bool]]:
    """``idx`` with its entry ``frame`` shown ``count`` more times right after it, and which entries are those
    copies."""
    if not 0 <= frame < len(idx) or count < 0:
        raise ValueError(f"--hold {frame}:{count}: the frame must be one of the copy's {len(idx)} and the count >= 0")
    out = idx[:frame + 1] + [idx[frame]] * count + idx[frame + 1:]
    return out, [frame < i <= frame + count for i in range(len(out))]


def played(spec: str, n: int) -> list[int]:
    """``--play`` text -> source frame indices in the order given (module docstring); ValueError naming the part
    that is not an index or a range of the sequence's ``n`` frames."""
    out = []
    for part in spec.split(","):
        try:
            bounds = [int(x) for x in part.split(":")]
        except ValueError:
            bounds = []
        if len(bounds) not in (1, 2):
            raise ValueError(f"--play {spec!r}: {part!r} is neither an index nor START:END")
        first, end = bounds if len(bounds) == 2 else (bounds[0], bounds[0] + 1)
        if not 0 <= first < end <= n:
            raise ValueError(f"--play {spec!r}: {part!r} is not a non-empty part of the sequence's {n} frames")
        out += range(first, end)
    return out


def frame_span(flag: str, first: int, count: int, n: int) -> range:
    """The copy's frames ``first`` .. ``first + count - 1`` of ``--cover`` or ``--occluder`` (``flag``); ValueError
    unless they are at least one and all lie in the copy's ``n``."""
    if not (0 <= first and count >= 1 and first + count <= n):
        raise ValueError(f"{flag} {first}:{count}: the frames must lie in the copy's {n}")
    return range(first, first + count)


def rewrite_image(src: Path, dst: Path, change: Callable[[np.ndarray], np.ndarray], what: str) -> None:
    """``change`` of the image in ``src`` (its bit depth and channels as stored) written to ``dst`` (may be
    ``src``); an OSError naming ``what`` was done when either file fails."""
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    if img is None or not cv2.imwrite(str(dst), change(img)):
        raise OSError(f"cannot {what} {src} into {dst}")


def grey_level(img: np.ndarray) -> float:
    """One 8-bit grey level in the units of ``img``'s dtype (257 for 16 bits, 1/255 for floats)."""
    return float(np.iinfo(img.dtype).max) / 255.0 if img.dtype.kind in "ui" else 1.0 / 255.0


def covered_copy(src: Path, dst: Path, seed: int) -> None:
    """A covered lens in ``src``'s format to ``dst``: grey level 3 with Gaussian noise of one grey level."""
    def dark(img: np.ndarray) -> np.ndarray:
        g = grey_level(img)
        level = np.random.default_rng(seed).normal(3.0 * g, g, img.shape)
        return np.clip(level, 0, 255 * g).round().astype(img.dtype)
    rewrite_image(src, dst, dark, "cover")


def noisy_copy(src: Path, dst: Path, sigma: float, seed: int) -> None:
    """``src`` with Gaussian noise of ``sigma`` grey levels (of its own bit depth's range over 255) to ``dst``."""
    def noisy(img: np.ndarray) -> np.ndarray:
        g = grey_level(img)
        noise = np.random.default_rng(seed).normal(0.0, sigma * g, img.shape)
        return np.clip(img + noise, 0, 255 * g).round().astype(img.dtype)
    rewrite_image(src, dst, noisy, "add noise to")


@dataclass(frozen=True)
class Occluder:
    """A band sweeping across frames ``first`` .. ``first + count - 1`` (module docstring)."""

    first: int
    count: int
    width: float = 0.3
    contrast: float = 45.0

    def covers(self, i: int) -> bool:
        return self.first <= i < self.first + self.count

    def draw(self, src: Path, dst: Path, i: int) -> None:
        """``src`` with the band at its place in frame ``i`` (of the copy) to ``dst``."""
        def with_band(img: np.ndarray) -> np.ndarray:
            h, w = img.shape[:2]
            bw = max(1, round(self.width * w))
            t = cv2.GaussianBlur(np.random.default_rng(0).normal(0.0, 1.0, (h, bw, 3)), (0, 0), 2.0)
            band = np.clip(60.0 + self.contrast * t / t.std(), 0, 255)  # the same texture in every frame
            x0 = round(-bw + (w + bw) * (i - self.first + 0.5) / self.count)  # its left edge, left to right
            a, b = max(0, x0), min(w, x0 + bw)
            part = band[:, a - x0:b - x0] * grey_level(img)
            img[:, a:b] = (part[..., :img.shape[2]] if img.ndim == 3 else part[..., 0]).round().astype(img.dtype)
            return img
        rewrite_image(src, dst, with_band, "draw the occluder on")


def frame_interval(stamps: np.ndarray) -> float:
    """The median interval between ``stamps`` (s); 1/30 s for a single frame."""
    return float(np.median(np.diff(stamps))) if len(stamps) > 1 else 1.0 / 30.0


def retimed(stamps: np.ndarray, count: int) -> np.ndarray:
    """``count`` stamps from the first of ``stamps`` at their median interval."""
    return stamps[0] + frame_interval(stamps) * np.arange(count)


def upside_down_calibration(seq: TumSequence) -> str:
    """``calib.txt`` of the source camera turned by 180 degrees (module docstring)."""
    cam = seq.source_camera
    k1, k2, p1, p2, k3 = (tuple(cam.dist) + (0.0,) * 5)[:5]
    vals = (cam.fx, cam.fy, cam.width - 1 - cam.cx, cam.height - 1 - cam.cy, k1, k2, -p1, -p2, k3)
    return " ".join(f"{v:.9g}" for v in vals) + "\n"


def copy_image(src: Path, dst: Path, upside_down: bool) -> None:
    """``src`` to ``dst`` as it is, or turned by 180 degrees (8 or 16 bits kept)."""
    if not upside_down:
        shutil.copy(src, dst)
        return
    rewrite_image(src, dst, lambda img: cv2.rotate(img, cv2.ROTATE_180), "turn")


def write_copy(src: Path, out: Path, order: str, upside_down: bool = False, repeat: int = 1,
               hold: tuple[int, int] | None = None, hold_noise: float = 1.5, occluder: Occluder | None = None,
               cover: tuple[int, int] | None = None, play: str | None = None) -> int:
    """The copy in ``out`` (written beside it, then renamed into place); returns its number of frames."""
    seq = TumSequence(src)  # the reader's own association of colour, depth and ground truth
    stamps, rgb, depth = seq.timestamps, seq.image_files, seq.depth_files
    idx = frame_order(len(stamps), order, repeat) if play is None else played(play, len(stamps))
    still = [False] * len(idx)
    if hold is not None:
        idx, still = held(idx, *hold)
    if occluder is not None:
        frame_span("--occluder", occluder.first, occluder.count, len(idx))
        if not (0 < occluder.width <= 1 and occluder.contrast >= 0):
            raise ValueError(f"--occluder: the width must lie in (0, 1] and the contrast be >= 0, got "
                             f"{occluder.width} and {occluder.contrast}")
    covered = range(0) if cover is None else frame_span("--cover", *cover, len(idx))
    unchanged = len(idx) == len(stamps) and order == "forward" and play is None
    new = stamps if unchanged else retimed(stamps, len(idx))
    with staged(out) as tmp:
        for name in ("calib.txt", "LICENSE", "README.md"):
            if (src / name).is_file():
                shutil.copy(src / name, tmp / name)
        if upside_down:
            (tmp / "calib.txt").write_text(upside_down_calibration(seq))
        what = ", ".join([f"order {order}"] + ([f"{repeat} times"] if repeat > 1 else [])
                         + ([f"frame {hold[0]} held {hold[1]} more"] if hold else [])
                         + ([f"an occluder over frames {occluder.first}-{occluder.first + occluder.count - 1}"]
                            if occluder else [])
                         + ([f"the lens covered over frames {covered[0]}-{covered[-1]}"] if cover else [])
                         + ([f"frames {play}"] if play else [])
                         + (["upside down"] if upside_down else []))
        for kind, files in (("rgb", rgb), ("depth", depth)):
            if files is None:
                continue
            (tmp / kind).mkdir()
            rows, first = [], {}  # source index -> its first copy's path
            for i, j in enumerate(idx):
                name = f"{kind}/{new[i]:.6f}{files[j].suffix}"
                if kind == "rgb" and i in covered:  # the lens covered: the camera sees nothing, and moves on
                    covered_copy(files[j], tmp / name, seed=i)
                elif kind == "rgb" and occluder is not None and occluder.covers(i):  # someone walks past the camera
                    copy_image(files[j], tmp / name, upside_down)
                    occluder.draw(tmp / name, tmp / name, i)  # left to right in the copy as it is seen
                elif kind == "rgb" and still[i] and hold_noise > 0:  # held still: the same view, new sensor noise
                    noisy_copy(first[j], tmp / name, hold_noise, seed=i)
                elif j in first:  # shown again: the same file, inside the copy
                    try:
                        os.link(first[j], tmp / name)
                    except OSError:  # a file system without hard links: a second copy
                        shutil.copy(first[j], tmp / name)
                else:
                    copy_image(files[j], tmp / name, upside_down)
                    first[j] = tmp / name
                rows.append(f"{new[i]:.6f} {name}\n")
            head = f"# {src.name}, {what} (scripts/sequence_copy.py)\n"
            (tmp / f"{kind}.txt").write_text(head + "".join(rows))
        gt = seq.gt_poses
        if gt is not None:
            keep = [i for i, j in enumerate(idx) if not bool(gt[j].isnan().any())]
            poses = gt[[idx[i] for i in keep]]
            if upside_down:
                poses = poses @ UPSIDE_DOWN
            write_tum(tmp / "groundtruth.txt", Trajectory(new[keep], poses))
    return len(idx)


QUARTER = torch.tensor([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
                       dtype=torch.float64)  # the camera turned as np.rot90 turns its image: x' = y, y' = -x


def turned_camera(fx: float, fy: float, cx: float, cy: float, w: int, h: int, quarters: int) -> tuple:
    """Pinhole intrinsics (fx, fy, cx, cy, W, H) of an image turned ``quarters`` times counter-clockwise (pixel
    (u, v) -> (v, W - 1 - u) each time)."""
    for _ in range(quarters % 4):
        fx, fy, cx, cy, w, h = fy, fx, cy, w - 1 - cx, h, w
    return fx, fy, cx, cy, w, h


def write_video_copy(src: Path, out: Path, order: str, rotation: int, repeat: int = 1) -> int:
    """``out``/video.mp4, camera.yaml and groundtruth.txt (module docstring; written beside ``out``, then renamed
    into place); returns the number of frames."""
    from codeslam.data.video import write_video

    seq = TumSequence(src)
    idx = frame_order(len(seq), order, repeat)
    fps = 1.0 / frame_interval(seq.timestamps)
    cam, quarters = seq.camera, rotation // 90
    with staged(out) as tmp:  # frames read one at a time: the encoder keeps 8 bits, not every float image
        write_video(tmp / "video.mp4", (seq.frame(i, depth=False).image for i in idx), fps=fps, rotation=rotation)
        fx, fy, cx, cy, w, h = turned_camera(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, quarters)
        (tmp / "camera.yaml").write_text(f"fx: {fx!r}\nfy: {fy!r}\ncx: {cx!r}\ncy: {cy!r}\nwidth: {w}\nheight: {h}\n")
        gt = seq.gt_poses
        if gt is not None:
            keep = [j for j, i in enumerate(idx) if not bool(gt[i].isnan().any())]
            turn = torch.linalg.matrix_power(QUARTER, quarters % 4)
            write_tum(tmp / "groundtruth.txt", Trajectory(np.array(keep) / fps, gt[[idx[j] for j in keep]] @ turn))
    return len(idx)


def frame_pair(ap: argparse.ArgumentParser, text: str, flag: str, form: str) -> tuple[int, int]:
    """``text`` "A:B" as two integers; a one-line usage error naming ``flag`` and its ``form`` otherwise."""
    try:
        first, second = (int(x) for x in text.split(":"))
    except ValueError:
        ap.error(f"{flag} wants {form}, got {text!r}")
    return first, second


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path, help="a TUM-layout sequence (rgb.txt, rgb/, depth.txt, groundtruth.txt)")
    ap.add_argument("out", type=Path, help="the copy's folder (replaced)")
    ap.add_argument("--order", choices=ORDERS, default="forward")
    ap.add_argument("--repeat", type=int, default=1, metavar="N", help="play the order N times over (a long recording)")
    ap.add_argument("--hold", default=None, metavar="F:K", help="frame F shown K more times: a camera held still")
    ap.add_argument("--hold-noise", type=float, default=1.5, metavar="SIGMA",
                    help="grey levels of sensor noise in each held frame (0: the same image)")
    ap.add_argument("--occluder", default=None, metavar="F:N", help="a band sweeping across frames F..F+N-1")
    ap.add_argument("--occluder-width", type=float, default=0.3, metavar="W", help="its width over the image's")
    ap.add_argument("--occluder-contrast", type=float, default=45.0, metavar="C",
                    help="its texture's standard deviation in grey levels (0: flat)")
    ap.add_argument("--cover", default=None, metavar="F:N", help="frames F..F+N-1 with the lens covered")
    ap.add_argument("--play", default=None, metavar="SPEC",
                    help="these source frames in this order, e.g. 0:100,20:70 (a camera carried back)")
    ap.add_argument("--upside-down", action="store_true", help="images, depth, calibration and poses turned 180 deg")
    ap.add_argument("--video", type=int, choices=(0, 90, 180, 270), default=None, metavar="ROTATION",
                    help="an H.264 video with this display rotation (0, 90, 180, 270) instead of a TUM copy")
    a = ap.parse_args()
    if a.video is not None and a.upside_down:
        ap.error("--upside-down turns a TUM copy; a video's turn is --video 180")
    if a.repeat < 1:
        ap.error(f"--repeat must be at least 1, got {a.repeat}")
    hold = None if a.hold is None else frame_pair(ap, a.hold, "--hold", "FRAME:COUNT")
    if hold is not None and a.video is not None:
        ap.error("--hold writes a TUM copy, not a video")
    occluder = None
    if a.occluder is not None:
        first, count = frame_pair(ap, a.occluder, "--occluder", "FIRST:COUNT")
        if a.video is not None or a.hold is not None:
            ap.error("--occluder writes a TUM copy, one probe at a time: not with --video or --hold")
        occluder = Occluder(first, count, a.occluder_width, a.occluder_contrast)
    cover = None if a.cover is None else frame_pair(ap, a.cover, "--cover", "FIRST:COUNT")
    if (a.cover is not None or a.play is not None) and a.video is not None:
        ap.error("--cover and --play write a TUM copy, not a video")
    if a.play is not None and (a.order != "forward" or a.repeat != 1):
        ap.error("--play gives the order itself: not with --order or --repeat")
    if not (a.hold_noise >= 0):
        ap.error(f"--hold-noise must be >= 0, got {a.hold_noise}")
    try:
        if a.video is not None:
            n = write_video_copy(a.src, a.out, a.order, a.video, a.repeat)
        else:
            n = write_copy(a.src, a.out, a.order, a.upside_down, a.repeat, hold, a.hold_noise, occluder, cover,
                           a.play)
    except (CodeSLAMError, OSError, ValueError) as e:
        ap.error(str(e))
    print(f"{a.out}: {n} frames")


if __name__ == "__main__":
    main()
