"""A video file (a phone's MP4, a screen recording) as a sequence of frames, decoded with PyAV (FFmpeg).

A video brings no depth, no ground truth and often no calibration:

* **Camera.** A calibration file (``camera.yaml``, the keys of :mod:`codeslam.data.folder`: fx, fy, cx, cy, optional
  width, height, dist) gives the intrinsics; without one they are guessed from a horizontal field of view
  (:data:`DEFAULT_FOV_DEG`, about a phone's main camera in video mode): square pixels, the principal point at the
  centre. :attr:`VideoSequence.camera_source` says which, for the run's summary and report.
* **Frames.** ``fps`` keeps at most that many frames per second of video (the first frame, then the first frame at
  or after each 1/fps step), then ``every`` keeps every N-th of those. Timestamps are the frames' presentation
  times in seconds from the first frame.
* **Orientation.** A phone stores a portrait video as landscape frames plus a display rotation; frames are turned
  as a player shows them, and the camera (calibrated or guessed) belongs to the turned frames. After a quarter
  turn the sensor's rows run along the turned frame's columns: its frames say so (``Frame.readout_axis``), for
  the rolling-shutter rectification of SLAM.

Frames are decoded on demand: reading forward (as SLAM does) continues the decoder, reading backward seeks to the
key frame before the wanted one. Rolling shutter and auto-exposure are not modelled here (SLAM chooses a readout
from the frames; the photometric tracker sees the exposure changes; see the README's notes on phone videos).
"""

from __future__ import annotations

import math
import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np
import torch

from codeslam.data.base import Sequence
from codeslam.data.folder import read_camera_yaml
from codeslam.data.frame import Frame
from codeslam.data.imageio import frame_index, undistort_frame
from codeslam.errors import CodeSLAMError, ConfigError, DatasetError
from codeslam.geometry.camera import PinholeCamera, canonical_camera

#: File name endings read as videos (lower case).
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".3gp")
#: Horizontal field of view (degrees) assumed for a video without a calibration file.
DEFAULT_FOV_DEG = 60.0
#: Forward gap (frames) beyond which reading seeks instead of decoding through the frames in between.
SEEK_AHEAD_FRAMES = 90


def is_video_file(path: str | Path) -> bool:
    """Whether ``path`` names a video file by its extension."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def check_fov(fov_deg: float) -> float:
    """A horizontal field of view in degrees, strictly between 1 and 179; ConfigError otherwise."""
    if isinstance(fov_deg, bool) or not isinstance(fov_deg, (int, float)) or not (1.0 < fov_deg < 179.0):
        raise ConfigError(f"--fov must be a horizontal field of view in degrees between 1 and 179, got {fov_deg!r}")
    return float(fov_deg)


def subsample_times(times: np.ndarray, fps: float | None = None, every: int = 1) -> np.ndarray:
    """Indices of the frames at ``times`` (seconds, increasing) kept by ``fps`` (at most that many per second: the
    first frame, then the first at or after each ``1/fps`` step; None keeps all) and then ``every`` (every N-th).
    ConfigError for a non-positive fps or an ``every`` below 1."""
    if fps is not None and (isinstance(fps, bool) or not math.isfinite(fps) or fps <= 0):
        raise ConfigError(f"--fps must be a positive number of frames per second, got {fps!r}")
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(f"--every must be a whole number >= 1, got {every!r}")
    keep = np.arange(len(times))
    if fps is not None and len(times):
        period = 1.0 / fps
        # a frame within a quarter of the video's own frame spacing of a step counts as on it (timestamps jitter)
        spacing = float(np.median(np.diff(times))) if len(times) > 1 else period
        tol = 0.25 * min(spacing, period)
        kept, next_t = [], times[0]
        for i, t in enumerate(times):
            if t >= next_t - tol:
                kept.append(i)
                next_t += period * max(1, math.floor((t - next_t + tol) / period) + 1)
        keep = np.array(kept, dtype=np.int64)
    return keep[::every]


class VideoSequence(Sequence):
    """The frames of a video file (see the module docstring).

    Args:
        root: the video file.
        camera: a calibration file (camera.yaml); None guesses the intrinsics from ``fov``.
        fov: horizontal field of view in degrees for the guess (default :data:`DEFAULT_FOV_DEG`); an error together
            with ``camera``.
        fps: keep at most this many frames per second (None: all). every: then keep every N-th frame.
        undistort: undistort frames when the calibration has distortion coefficients.
    """

    format_name = "video"

    def __init__(self, root: str | Path, camera: str | Path | None = None, fov: float | None = None,
                 fps: float | None = None, every: int = 1, undistort: bool = True) -> None:
        super().__init__(root)
        path = self.root
        if camera is not None and fov is not None:
            raise ConfigError("give either a calibration file (--camera) or a field-of-view guess (--fov), not both")
        if not path.is_file():
            raise DatasetError(f"video file not found: {path}")
        self._pts, self._time_base, info = _scan(path)
        times = (self._pts - self._pts[0]) * float(self._time_base)  # (N_all,) seconds from the first frame
        self.video_fps = info["fps"]
        self.rotation = info["rotation"]
        self.readout_axis = "columns" if round(self.rotation / 90) % 2 else "rows"  # a quarter turn: sensor rows
        self._keep = subsample_times(times, fps, every)
        if len(self._keep) == 0:
            raise DatasetError(f"{path}: no frames left after --fps {fps} / --every {every}")
        self._stamps = times[self._keep]
        w, h = info["width"], info["height"]
        if camera is not None:
            cam_file = Path(camera)
            if not cam_file.is_file():
                raise ConfigError(f"calibration file not found: {cam_file}")
            opts, dist = read_camera_yaml(cam_file)
            if (opts["width"] or w, opts["height"] or h) != (w, h):
                raise ConfigError(f"{cam_file} is for {opts['width']}x{opts['height']} images but the video's frames "
                                  f"are {w}x{h}" + (" (after its display rotation)" if self.rotation else ""))
            try:
                src = PinholeCamera(opts["fx"], opts["fy"], opts["cx"], opts["cy"], w, h, dist)
            except CodeSLAMError as e:
                raise ConfigError(f"{cam_file}: {e}") from None
            self.camera_source = f"calibration {cam_file}"
        else:
            if fov is None:
                warnings.warn(f"{path.name}: no calibration file, so the camera is guessed from a {DEFAULT_FOV_DEG:g} "
                              "deg horizontal field of view (give one with --camera camera.yaml, or --fov)",
                              stacklevel=2)
            fov = DEFAULT_FOV_DEG if fov is None else check_fov(fov)
            src = canonical_camera(w, h, hfov_deg=fov)
            self.camera_source = (f"guessed: {fov:g} deg horizontal field of view, principal point at the centre "
                                  "(no calibration file; give one with --camera)")
        self.fov_guess_deg = None if camera is not None else fov
        self.source_camera = src
        self.undistort = undistort and src.has_distortion
        self._camera = src.without_distortion()
        self._gt = None
        self._container = None
        self._frames = None  # the decoder's frame iterator
        self._next = 0  # index (into all frames) of the frame the iterator yields next

    @staticmethod
    def detect(root: Path) -> bool:
        return Path(root).is_file() and is_video_file(root)

    @property
    def has_depth(self) -> bool:
        return False

    def describe(self) -> dict:
        """What the run's summary records about the video: its own frame rate, the frames kept, the camera."""
        return {"video_fps": self.video_fps, "video_frames": int(len(self._pts)), "frames_kept": len(self),
                "display_rotation_deg": self.rotation, "camera": self.camera_source,
                **({"fov_guess_deg": self.fov_guess_deg} if self.fov_guess_deg is not None else {})}

    def frame(self, i: int, depth: bool = True) -> Frame:  # no depth to read
        i = frame_index(i, len(self))
        image = _to_tensor(self._decode(int(self._keep[i])), self.rotation)  # (3, H, W)
        if tuple(image.shape[1:]) != (self.source_camera.height, self.source_camera.width):
            raise DatasetError(f"{self.root}: frame {i} is {image.shape[2]}x{image.shape[1]}, the first was "
                               f"{self.source_camera.width}x{self.source_camera.height} (a size change mid-video is "
                               "not supported)")
        valid = None
        if self.undistort:
            image, _, valid = undistort_frame(self.source_camera, image, None)
        return Frame(float(self._stamps[i]), image, self._camera, None, None, i, valid, self.readout_axis)

    # ---- decoding ---------------------------------------------------------------------------------------------
    def _open(self, seek_pts: int | None) -> None:
        import av

        self.close()
        try:
            self._container = av.open(str(self.root))
            stream = self._container.streams.video[0]
            stream.thread_type = "AUTO"
            if seek_pts is not None:
                self._container.seek(int(seek_pts), stream=stream, backward=True, any_frame=False)
        except (av.FFmpegError, OSError) as e:
            raise DatasetError(f"cannot read video {self.root}: {e}") from None
        self._frames = self._container.decode(stream)
        self._next = None if seek_pts is not None else 0

    def _decode(self, k: int):
        """The decoded frame with index ``k`` among all the video's frames."""
        import av

        target = int(self._pts[k])
        if self._frames is None or (self._next is not None and not (self._next <= k < self._next + SEEK_AHEAD_FRAMES)):
            self._open(None if k < SEEK_AHEAD_FRAMES else target)
        try:
            for frame in self._frames:
                pts = frame.pts
                if self._next is not None:  # counting frames from the start: the k-th is the one
                    n, self._next = self._next, self._next + 1
                    if n == k:
                        return frame
                elif pts is not None and pts >= target:  # after a seek: the first frame at or past the target
                    self._next = int(np.searchsorted(self._pts, pts)) + 1
                    return frame
        except av.FFmpegError as e:
            raise DatasetError(f"cannot decode video {self.root} at frame {k}: {e}") from None
        raise DatasetError(f"{self.root} ended before frame {k} of {len(self._pts)}")

    def close(self) -> None:
        """Release the decoder (it is opened again on the next read)."""
        if self._container is not None:
            self._container.close()
        self._container, self._frames = None, None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown
            pass


def write_video(path: str | Path, images, fps: float = 30.0, codec: str | None = None, rotation: int = 0) -> Path:
    """Encode ``images`` ((H, W, 3) uint8 RGB arrays, or (3, H, W) float tensors in [0, 1]) as a video file, atomically
    (e.g. a generator sequence, to try the video path). ``codec``: H.264 (libx264) when PyAV's FFmpeg has it, else
    MPEG-4 part 2; ``rotation``: a display rotation (degrees counter-clockwise) stored with the stream, as a phone
    does. Even frame sizes are needed by the 4:2:0 chroma of both codecs."""
    import av

    from codeslam.io import atomic_path

    path = Path(path)
    frames = [np.ascontiguousarray((img.clamp(0, 1) * 255 + 0.5).byte().permute(1, 2, 0).numpy())
              if isinstance(img, torch.Tensor) else np.ascontiguousarray(img, dtype=np.uint8) for img in images]
    if not frames:
        raise ValueError("write_video needs at least one image")
    h, w = frames[0].shape[:2]
    codec = codec or ("libx264" if "libx264" in av.codecs_available else "mpeg4")
    with atomic_path(path) as tmp:
        with av.open(str(tmp), "w", format=None if path.suffix else "mp4") as container:
            stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
            stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
            if codec == "libx264":
                stream.options = {"crf": "18"}  # near-lossless: the test compares frames
            else:
                stream.bit_rate = 4_000_000
            if rotation:
                stream.set_display_rotation(rotation)
            for img in frames:
                for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    return path


def _to_tensor(frame, rotation: int) -> torch.Tensor:
    """A decoded PyAV frame -> (3, H, W) float32 RGB in [0, 1], turned by the display rotation."""
    rgb = frame.to_ndarray(format="rgb24")  # (H, W, 3) uint8
    if rotation:
        rgb = np.rot90(rgb, k=round(rotation / 90) % 4)  # counter-clockwise, as the display matrix says
    return torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float().div_(255.0)


def _scan(path: Path) -> tuple[np.ndarray, Fraction, dict]:
    """(presentation times of every frame (N,) int64 in stream time-base units, sorted; the time base; {width,
    height (after the display rotation), fps, rotation}). Reads packet headers only, unless the packets carry no
    times (a raw stream), then decodes every frame. DatasetError when the file is not a readable video."""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise DatasetError(f"{path} holds no video stream")
            stream = container.streams.video[0]
            time_base = stream.time_base or Fraction(1, 1)
            pts = [p.pts for p in container.demux(stream) if p.size > 0]
            if pts:
                container.seek(0, stream=stream)
            first = next(container.decode(stream), None)
            if first is None:
                raise DatasetError(f"{path} holds no decodable video frame")
            rate = stream.average_rate or stream.guessed_rate
            fps = float(rate) if rate else None
            if not pts or any(p is None for p in pts):  # no packet times: decode everything
                container.seek(0, stream=stream)
                pts = [f.pts for f in container.decode(stream)]
                if any(p is None for p in pts):  # no frame times either: the nominal rate
                    step = 1.0 / (fps or 30.0) / float(time_base)
                    pts = [round(n * step) for n in range(len(pts))]
            rotation = int(round(getattr(first, "rotation", 0) or 0))
    except av.FFmpegError as e:
        raise DatasetError(f"cannot read video {path}: {' '.join(str(e).split())}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"cannot read video {path}: {e}") from None
    pts_arr = np.unique(np.asarray(pts, dtype=np.int64))  # sorted presentation order, duplicates dropped
    w, h = first.width, first.height
    if round(rotation / 90) % 2:  # a quarter turn swaps the sides
        w, h = h, w
    if fps is None and len(pts_arr) > 1:
        fps = 1.0 / float(np.median(np.diff(pts_arr)) * time_base)
    return pts_arr, time_base, {"width": w, "height": h, "fps": fps, "rotation": rotation}
