"""The dataset formats codeslam reads, by name, and opening a folder in whichever one it is.

:data:`FORMATS` is an explicit table (no plugin discovery): adding a format means writing one reader
class implementing :class:`~codeslam.data.base.Sequence` and adding one line here.

Every reader returns :class:`~codeslam.data.frame.Frame`\\ s of an undistorted pinhole camera. Where a
format's ground truth does not cover a frame, that frame's ``pose`` is None and its row of
``Sequence.gt_poses`` is NaN.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from codeslam.data.base import Sequence
from codeslam.data.euroc import EurocSequence
from codeslam.data.folder import FolderSequence
from codeslam.data.scenenet import SceneNetSequence
from codeslam.data.tartanair import TartanAirSequence
from codeslam.data.tum import TumSequence
from codeslam.data.video import VIDEO_SUFFIXES, VideoSequence, is_video_file
from codeslam.errors import ConfigError, DatasetError

FORMATS: dict[str, type[Sequence]] = {
    "tum": TumSequence,
    "euroc": EurocSequence,
    "scenenet": SceneNetSequence,
    "tartanair": TartanAirSequence,
    "folder": FolderSequence,
    "video": VideoSequence,
}

#: What each format's detector looks for, for error messages.
FORMAT_MARKERS: dict[str, str] = {
    "tum": "rgb.txt",
    "euroc": "mav0/cam0/data.csv",
    "scenenet": "photo/ and depth/",
    "tartanair": "image_left/",
    "folder": "camera.yaml",
    "video": "a video file (" + ", ".join(VIDEO_SUFFIXES[:4]) + ", ...)",
}


def detect_format(path: str | Path) -> str:
    """The name of the one format ``path`` looks like (a file: a video, by its extension); DatasetError when it is
    missing, a file that is not a video, a folder of no known format, or looks like several."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"dataset path not found: {path}")
    if not path.is_dir():
        if is_video_file(path):
            return "video"
        raise DatasetError(f"dataset path is not a folder, nor a video file ({', '.join(VIDEO_SUFFIXES)}): {path}")
    matches = [name for name, cls in FORMATS.items() if cls.detect(path)]
    if not matches:
        expected = "; ".join(f"{name}: {marker}" for name, marker in FORMAT_MARKERS.items())
        raise DatasetError(f"{path} is in no known dataset format (looked for {expected})")
    if len(matches) > 1:
        raise DatasetError(f"{path} looks like several formats ({', '.join(matches)}); choose one with --format")
    return matches[0]


def open_dataset(path: str | Path, format: str | None = None, **kwargs: Any) -> Sequence:
    """Open the dataset folder ``path`` in ``format`` (detected when None); ``kwargs`` go to the reader."""
    path = Path(path)
    if format is None:
        format = detect_format(path)
    elif format not in FORMATS:
        raise ConfigError(f"unknown dataset format {format!r}; choose one of {', '.join(FORMATS)}")
    elif not path.exists():
        raise DatasetError(f"dataset path not found: {path}")
    return FORMATS[format](path, **kwargs)


def describe_dataset(seq: Sequence) -> dict[str, Any]:
    """A summary of ``seq`` (what ``codeslam info`` prints). Reads the first frame, so a dataset whose
    images are unreadable or not of the camera's size fails here rather than later.

    Keys: format, path, frames, width, height, fx, fy, cx, cy (the undistorted camera), distortion (the
    dataset's coefficients k1 k2 p1 p2 k3 before undistortion), undistorted, has_depth, has_pose,
    frames_with_pose, duration_s, gt_path_length_m (through the poses at the frame timestamps, None
    without poses), first_frame {timestamp, depth_min_m, depth_max_m, depth_valid_fraction}.
    """
    import numpy as np
    import torch

    cam = seq.camera
    src = getattr(seq, "source_camera", cam)
    ts = seq.timestamps
    gt = seq.gt_poses
    valid = None if gt is None else ~torch.isnan(gt).flatten(1).any(dim=1)  # (N,)
    path_length = None
    if gt is not None:
        xyz = gt[valid][:, :3, 3]  # (K, 3) camera centres
        path_length = float((xyz[1:] - xyz[:-1]).norm(dim=-1).sum()) if len(xyz) > 1 else 0.0
    first = seq[0]
    first_info: dict[str, Any] = {"timestamp": float(first.timestamp)}
    if first.depth is not None:
        d = first.depth
        ok = d > 0
        first_info["depth_valid_fraction"] = float(ok.float().mean())
        first_info["depth_min_m"] = float(d[ok].min()) if bool(ok.any()) else None
        first_info["depth_max_m"] = float(d[ok].max()) if bool(ok.any()) else None
    return {
        "format": seq.format_name,
        "path": str(seq.root),
        "frames": len(seq),
        "width": cam.width,
        "height": cam.height,
        "fx": cam.fx,
        "fy": cam.fy,
        "cx": cam.cx,
        "cy": cam.cy,
        "distortion": [float(v) for v in src.dist],
        "undistorted": bool(getattr(seq, "undistort", False)),
        "has_depth": bool(seq.has_depth),
        "has_pose": gt is not None,
        "frames_with_pose": 0 if valid is None else int(valid.sum()),
        "duration_s": float(np.ptp(ts)) if len(ts) else 0.0,
        "gt_path_length_m": path_length,
        "first_frame": first_info,
    }
