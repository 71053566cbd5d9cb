"""The SLAM system (paper Sec. 4.3), "inspired by PTAM where we alternate between tracking and mapping":
:meth:`CodeSLAM.process` tracks each frame against the last keyframe, decides whether it becomes a keyframe,
and if so decodes its depth model, marginalises the oldest keyframe when the window is full and optimises the
window's codes and poses jointly.

Initialisation (paper: "takes two images and jointly optimises for their relative pose and the codes of each
frame"): the first frame becomes keyframe 0 at the world origin with the zero code; the following frames are
tracked against its zero-code depth (the single-view prediction) until one shows enough baseline. That frame
becomes keyframe 1, and the first window optimisation is exactly two-frame SfM: both codes (from zero) and the
relative pose (from the tracked one) optimised jointly, keyframe 0's pose fixed as the gauge.

Every frame's pose is kept relative to its reference keyframe (``T_wc = T_wk T_kf``), so the trajectory follows
the keyframes when the window optimisation moves them. The core never opens a file: reading, resampling,
timing and writing results belong to :mod:`codeslam.slam.pipeline`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.data.frame import Frame
from codeslam.data.trajectory import Trajectory
from codeslam.errors import CodeSLAMError
from codeslam.geometry.lie import se3_inverse
from codeslam.sfm.decoder import LinearDecoder
from codeslam.sfm.keyframes import Keyframe
from codeslam.slam.config import SLAMConfig
from codeslam.slam.keyframes import KeyframeDecision, decide_keyframe
from codeslam.slam.poses import project_to_se3
from codeslam.slam.tracker import PhotometricTracker, TrackResult
from codeslam.slam.window import MapKeyframe, SlidingWindow, WindowReport

#: A keyframe's depth model: the frame (resampled to the model's camera) -> its linear decoder
#: ``prox_l(c) = prox0_l + J_l c`` on every pyramid level. The network's reads ``frame.image`` only
#: (:func:`codeslam.slam.depth.network_depth_model`); a stand-in may read the frame's depth.
DepthModelFactory = Callable[[Frame], LinearDecoder]

INITIALISING, TRACKING, LOST = "initialising", "tracking", "lost"


@dataclass
class FrameResult:
    """What :meth:`CodeSLAM.process` did with one frame.

    Attributes:
        index, timestamp: the frame's.
        T_wc: (4, 4) float64 pose estimate at the time of processing (the final trajectory, after later window
            optimisations moved the keyframes, is :meth:`CodeSLAM.trajectory`).
        tracking_ok: False when tracking failed; T_wc is then the motion model's prediction.
        status: 'initialising' (one keyframe so far), 'tracking' or 'lost' (tracking failed on this frame).
        keyframe_id: the keyframe this frame's pose is relative to (its own id if it became one).
        is_keyframe: whether the frame became a keyframe.
        reason: why tracking failed, or why the frame became a keyframe (baseline, rotation, overlap).
        track: tracking statistics (None for the first frame). keyframe: the keyframe decision (None when not
            tracked). window: the window optimisation run for a new keyframe (else None).
        marginalised_id: id of the keyframe marginalised on this frame, if any.
        timings_ms: wall time per stage: track, decode, marginalise, window.
    """

    index: int
    timestamp: float
    T_wc: torch.Tensor
    tracking_ok: bool
    status: str
    keyframe_id: int
    is_keyframe: bool
    reason: str = ""
    track: TrackResult | None = None
    keyframe: KeyframeDecision | None = None
    window: WindowReport | None = None
    marginalised_id: int | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class _FrameRecord:
    """A frame's pose relative to its keyframe, re-expressed whenever the keyframe moves."""

    index: int
    timestamp: float
    keyframe_id: int
    T_kf: torch.Tensor
    ok: bool
    affine: torch.Tensor | None


class _StageTimer:
    """Wall time per named stage, in ms (CUDA synchronised so the time is the kernels')."""

    def __init__(self, device: torch.device) -> None:
        self.device, self.ms = device, {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        t0 = time.perf_counter()
        yield
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        self.ms[name] = self.ms.get(name, 0.0) + 1e3 * (time.perf_counter() - t0)


class CodeSLAM:
    """Dense monocular SLAM with learned depth codes (paper Sec. 4).

    config: the system's settings; depth_model: a :data:`DepthModelFactory` called once per keyframe. Frames
    must all come from one camera, the depth model's (the pipeline resamples them to it).
    """

    def __init__(self, config: SLAMConfig, depth_model: DepthModelFactory) -> None:
        self.config = config
        self.depth_model = depth_model
        self.device = torch.device(config.device)
        self.dtype = config.torch_dtype
        self.tracker = PhotometricTracker(config.tracker, config.window.sfm)
        self.window = SlidingWindow(config.window)
        self.keyframes: list[MapKeyframe] = []  # every keyframe ever made, by id
        self._records: list[_FrameRecord] = []
        self._keyframe_record: dict[int, int] = {}  # keyframe id -> position of its frame's record

    # ---- the algorithm --------------------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameResult:
        """Track ``frame`` against the last keyframe, maybe make it a keyframe, optimise the window and
        marginalise the oldest keyframe (paper Sec. 4.2-4.3)."""
        timer = _StageTimer(self.device)
        self._check(frame)
        if not self.keyframes:  # the first frame is the map's origin
            return self._start_map(frame, timer)
        ref = self.window.keyframes[-1]
        T_kf_guess = self._predict(ref)
        if not bool(torch.isfinite(frame.image).all()):
            return self._record(frame, ref, T_kf_guess, False, timer, reason="non-finite pixels in the image")
        with timer("track"):  # Sec. 4.2: coarse-to-fine photometric alignment, keyframe depth fixed
            track = self.tracker.track(ref.keyframe, ref.code, frame.gray, frame.camera, T_kf_guess,
                                       self._affine_guess(ref), valid=frame.valid)
        if not track.ok:  # never a wild pose: the motion model's guess, flagged
            return self._record(frame, ref, T_kf_guess, False, timer, track=track, reason=track.reason)
        frames_since = len(self._records) - self._keyframe_record[ref.id]  # 1 for the frame after the keyframe
        decision = decide_keyframe(track.T_kf, ref.median_depth(), track.overlap, frames_since, True,
                                   self.config.keyframes)
        if not decision.add:
            return self._record(frame, ref, track.T_kf, True, timer, track=track, decision=decision)
        kf, window, marginalised = self._add_keyframe(frame, ref.T_wc @ track.T_kf, timer)  # Sec. 4.3
        return self._record(frame, kf, torch.eye(4, dtype=torch.float64), True, timer, track=track,
                            decision=decision, window=window, marginalised=marginalised, reason=decision.reason)

    def _add_keyframe(
        self, frame: Frame, T_wc: torch.Tensor, timer: _StageTimer
    ) -> tuple[MapKeyframe, WindowReport, int | None]:
        """Decode the frame's depth model, marginalise the oldest keyframe if the window is full, add the new
        keyframe (code zero, tracked pose) and optimise the window jointly. Marginalising before the solve keeps
        every solve at K keyframes (the paper's "4-keyframes setup") and linearises the prior at the previous
        window's optimum."""
        with timer("decode"):
            kf = self._make_keyframe(frame, T_wc)
        marginalised = None
        if self.window.is_full:
            with timer("marginalise"):  # the oldest keyframe becomes a linear prior on the others
                marginalised = self.window.remove_oldest().id
        self.window.add(kf)
        self.keyframes.append(kf)
        with timer("window"):  # all codes and poses of the window, photometric + geometric pairs (Sec. 4.1)
            report = self.window.optimise()
        return kf, report, marginalised

    def _start_map(self, frame: Frame, timer: _StageTimer) -> FrameResult:
        if not bool(torch.isfinite(frame.image).all()):
            raise CodeSLAMError(f"frame {frame.index} (the first) has non-finite pixels; cannot start the map")
        with timer("decode"):
            kf = self._make_keyframe(frame, torch.eye(4, dtype=torch.float64))
        self.window.add(kf)
        self.keyframes.append(kf)
        return self._record(frame, kf, torch.eye(4, dtype=torch.float64), True, timer, reason="first frame")

    # ---- helpers --------------------------------------------------------------------------------------------
    def _check(self, frame: Frame) -> None:
        if frame.image.dim() != 3 or frame.image.shape[0] not in (1, 3):
            raise CodeSLAMError(f"frame {frame.index}: image must be (3, H, W) or (1, H, W), "
                                f"got {tuple(frame.image.shape)}")
        if self.keyframes and frame.camera != self.keyframes[0].keyframe.camera:
            raise CodeSLAMError(f"frame {frame.index} has another camera than the map's; resample every frame to "
                                "the depth model's camera first")
        if self._records and frame.timestamp <= self._records[-1].timestamp:
            raise CodeSLAMError(f"frame {frame.index}: timestamp {frame.timestamp} does not increase "
                                f"(previous {self._records[-1].timestamp})")

    def _make_keyframe(self, frame: Frame, T_wc: torch.Tensor) -> MapKeyframe:
        decoder = self.depth_model(frame)
        H, W = frame.image.shape[-2:]
        need = self.config.decoder_levels
        if decoder.num_levels < need:
            raise CodeSLAMError(f"the depth model gives {decoder.num_levels} pyramid levels, the tracker and window "
                                f"use {need}")
        if tuple(decoder.levels[0].prox0.shape) != (H, W):
            raise CodeSLAMError(f"the depth model's output is {tuple(decoder.levels[0].prox0.shape)}, the frame "
                                f"{(H, W)}")
        if self.keyframes and decoder.code_size != self.keyframes[0].code.shape[0]:
            raise CodeSLAMError("the depth model changed its code size between keyframes")
        decoder = decoder.to(dtype=self.dtype, device=self.device)
        image = frame.image.to(dtype=self.dtype, device=self.device)  # RGB kept for the map's colours
        return MapKeyframe(
            id=len(self.keyframes), frame_index=frame.index, timestamp=float(frame.timestamp),
            keyframe=Keyframe(image, frame.camera, decoder, frame.valid),
            T_wc=project_to_se3(T_wc),
            code=torch.zeros(decoder.code_size, dtype=self.dtype, device=self.device),
        )

    def _pose(self, rec: _FrameRecord) -> torch.Tensor:
        return self.keyframes[rec.keyframe_id].T_wc @ rec.T_kf

    def _predict(self, ref: MapKeyframe) -> torch.Tensor:
        """The frame's pose in ``ref`` predicted by the motion model: the last pose moved by the last inter-frame
        motion between two successfully tracked frames (constant velocity; a failed frame's guessed pose never
        feeds the velocity, so guesses cannot compound), or the last pose ('static')."""
        T_last = self._pose(self._records[-1])
        T_pred = T_last
        if self.config.tracker.motion_model == "constant_velocity":
            for prev, cur in zip(reversed(self._records[:-1]), reversed(self._records)):
                if prev.ok and cur.ok:
                    T_pred = T_last @ (se3_inverse(self._pose(prev)) @ self._pose(cur))  # T_prev^-1 T_cur
                    break
        return se3_inverse(ref.T_wc) @ T_pred

    def _affine_guess(self, ref: MapKeyframe) -> torch.Tensor | None:
        last = self._records[-1]
        return last.affine if last.ok and last.keyframe_id == ref.id else None

    def _record(
        self, frame: Frame, kf: MapKeyframe, T_kf: torch.Tensor, ok: bool, timer: _StageTimer,
        track: TrackResult | None = None, decision: KeyframeDecision | None = None,
        window: WindowReport | None = None, marginalised: int | None = None, reason: str = "",
    ) -> FrameResult:
        is_kf = kf.frame_index == frame.index
        if is_kf:
            self._keyframe_record[kf.id] = len(self._records)
        affine = track.affine if (ok and track is not None and not is_kf) else None
        rec = _FrameRecord(frame.index, float(frame.timestamp), kf.id, T_kf.to(torch.float64), ok, affine)
        self._records.append(rec)
        status = LOST if not ok else (INITIALISING if len(self.keyframes) < 2 else TRACKING)
        return FrameResult(
            index=frame.index, timestamp=float(frame.timestamp), T_wc=self._pose(rec), tracking_ok=ok,
            status=status, keyframe_id=kf.id, is_keyframe=is_kf, reason=reason, track=track, keyframe=decision,
            window=window, marginalised_id=marginalised, timings_ms=dict(timer.ms),
        )

    # ---- results --------------------------------------------------------------------------------------------
    def trajectory(self) -> Trajectory:
        """Every processed frame's final pose ``T_wk T_kf`` (its keyframe's latest pose)."""
        if not self._records:
            raise CodeSLAMError("no frame has been processed")
        return Trajectory(np.array([r.timestamp for r in self._records]),
                          torch.stack([self._pose(r) for r in self._records]))

    def keyframe_trajectory(self) -> Trajectory:
        """The keyframes' final poses."""
        if not self.keyframes:
            raise CodeSLAMError("no frame has been processed")
        return Trajectory(np.array([k.timestamp for k in self.keyframes]),
                          torch.stack([k.T_wc for k in self.keyframes]))

    def tracking_failures(self) -> list[int]:
        """Indices of the frames whose tracking failed."""
        return [r.index for r in self._records if not r.ok]
