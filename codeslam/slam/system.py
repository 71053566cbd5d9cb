"""The SLAM system (paper Sec. 4.3), "inspired by PTAM where we alternate between tracking and mapping":
:meth:`CodeSLAM.process` tracks each frame against its reference keyframe, decides whether it becomes a keyframe,
and if so decodes its depth model, marginalises the oldest keyframe when the window is full and optimises the
window's codes and poses jointly.

Initialisation (paper: "takes two images and jointly optimises for their relative pose and the codes of each
frame"): the first frame becomes keyframe 0 at the world origin with the zero code; the following frames are
tracked against its zero-code depth (the single-view prediction) until one shows enough baseline. That frame
becomes keyframe 1, and the first window optimisation is exactly two-frame SfM: both codes (from zero) and the
relative pose (from the tracked one) optimised jointly, keyframe 0's pose fixed as the gauge.

Beyond the paper, for cameras that travel (measured on a real 14.5 m walk, where the paper's tracker lost the
map within seconds):

* **Tracking** starts from ORB matches and PnP on the keyframe's decoded depth (:mod:`codeslam.slam.frontend`)
  instead of the motion model alone, and the matches stay in the photometric alignment as reprojection
  residuals (DeepFactors' sparse factors). A frame is tracked when the photometric checks pass or enough
  matches agree with the final pose. In the parallel mode the keypoints are extracted on demand
  (``features.direct_first``): a frame whose motion the motion model predicted well is aligned from the
  prediction alone, as DSO does.
* **Mapping** keeps its map: a window solve that fails :meth:`SlidingWindow.check`, or after which the next
  frame cannot be tracked while it can against the map before the solve, is rolled back.
* **Recovery**: a frame that fails is relocalised against the window's and older keyframes (ORB + PnP; those
  nearest its predicted pose and those it looks like, by PTAM's small blurry images); after
  ``recovery.lost_frames`` lost frames the next one starts a new map segment at its predicted pose. Every
  frame's pose is marked ``tracked``, ``relocalised`` or ``predicted``. A new segment is moved into an older map
  when its keyframes are seen to match that map's (:mod:`codeslam.slam.segments`).

Every frame's pose is kept relative to its reference keyframe (``T_wc = T_wk T_kf``), so the trajectory follows
the keyframes when the window optimisation moves them; the final trajectory spreads what the window changed
between two keyframes over the frames between them (``SLAMConfig.trajectory``). The core never opens a file:
reading, timing and writing results belong to :mod:`codeslam.slam.pipeline`.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.clock import NO_CLOCK, Clock
from codeslam.data.frame import Frame, resample_frame
from codeslam.data.trajectory import Trajectory
from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.image import image_is_finite
from codeslam.geometry.lie import se3_inverse, so3_log
from codeslam.geometry.resample import resample_depth
from codeslam.geometry.rolling_shutter import rectify_image, rectify_points, source_pixels
from codeslam.sfm.decoder import LinearDecoder, ScaledDecoder
from codeslam.sfm.keyframes import Keyframe
from codeslam.slam.config import SLAMConfig
from codeslam.slam.features import Features, scaled_camera
from codeslam.slam.frontend import FrameMatches, KeyframeFeatures, SparseTrack, SparseTracker
from codeslam.slam.keyframes import MAPPING_BUSY, KeyframeDecision, decide_keyframe, motion_since_keyframe
from codeslam.slam.mapping import Mapper, MappingJob, MappingResult, torch_threads
from codeslam.slam.poses import path_fractions, project_to_se3, scale_motion, spread_correction
from codeslam.slam.readout import ReadoutChoice
from codeslam.slam.segments import SegmentMaps, SegmentMerge, motions_agree, segment_motion
from codeslam.slam.smoothing import smooth_positions
from codeslam.slam.thumbnails import most_alike, thumbnail
from codeslam.slam.tracker import PhotometricTracker, TrackResult
from codeslam.slam.window import MapKeyframe, SlidingWindow, SparseSettings, WindowReport

#: A keyframe's depth model: the frame (resampled to the model's camera) -> its linear decoder
#: ``prox_l(c) = prox0_l + J_l c`` on every pyramid level. The network's reads ``frame.image`` only
#: (:func:`codeslam.slam.depth.network_depth_model`) and says so by an attribute ``reads_depth = False``, so that
#: frames may come without their depth (:attr:`CodeSLAM.reads_frame_depth`); a stand-in reads the frame's depth.
DepthModelFactory = Callable[[Frame], LinearDecoder]

# A frame's status: the map's first keyframe and the frames before the second ('initialising'), tracked
# against a keyframe, relocalised after a failure, or only predicted by the motion model (tracking failed).
INITIALISING, TRACKED, RELOCALISED, PREDICTED = "initialising", "tracked", "relocalised", "predicted"
STATUSES = (INITIALISING, TRACKED, RELOCALISED, PREDICTED)


PERIOD_FRAMES = 30
"""The last frames whose intervals give the camera's frame period (their median: dropped frames are the exception)."""


@dataclass
class FrameResult:
    """What :meth:`CodeSLAM.process` did with one frame.

    Attributes:
        index, timestamp: the frame's.
        T_wc: (4, 4) float64 pose estimate at the time of processing (the final trajectory, after later window
            optimisations moved the keyframes, is :meth:`CodeSLAM.trajectory`).
        tracking_ok: False when the pose is only predicted (tracking and relocalisation failed).
        status: one of :data:`STATUSES`.
        keyframe_id: the keyframe this frame's pose is relative to (its own id if it became one).
        is_keyframe: whether the frame became a keyframe.
        reason: why tracking failed, or why the frame became a keyframe (baseline, rotation, overlap, first
            frame, relocalised, new segment).
        segment: the map segment (0 until tracking is lost long enough to start a new one).
        source: what the pose rests on: 'direct' (photometric only; with ``features.direct_first``, a
            frame aligned from the motion model's prediction without keypoints), 'direct+features', 'features'
            (PnP only), 'motion model'.
        track: tracking statistics (None for the first frame). keyframe: the keyframe decision (None when not
            tracked). window: the window optimisation run for a new keyframe (else None).
        marginalised_id: id of the keyframe marginalised on this frame, if any.
        rolled_back: a window solve was undone on this frame (its reason).
        timings_ms: wall time per stage (resample, features, track, relocalise, readout, decode, marginalise,
            window) as the system's clock timed them; empty with the default clock, which times nothing.
    """

    index: int
    timestamp: float
    T_wc: torch.Tensor
    tracking_ok: bool
    status: str
    keyframe_id: int
    is_keyframe: bool
    reason: str = ""
    segment: int = 0
    source: str = ""
    track: TrackResult | None = None
    keyframe: KeyframeDecision | None = None
    window: WindowReport | None = None
    marginalised_id: int | None = None
    rolled_back: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class _FrameRecord:
    """A frame's pose relative to its keyframe, re-expressed whenever the keyframe moves; and, for the motion
    model, the keyframe it was tracked against with its pose there as tracked (a frame that becomes a keyframe is
    re-expressed relative to itself, and the window then moves it)."""

    index: int
    timestamp: float
    keyframe_id: int
    T_kf: torch.Tensor
    ok: bool
    affine: torch.Tensor | None
    tracked_id: int
    T_tracked: torch.Tensor
    relocalised: bool = False  # its pose was found by relocalisation: no velocity from the frame before


@dataclass
class _Views:
    """One input frame as the system uses it: in the network's camera, and its keypoints in the feature camera."""

    frame: Frame  # without depth: only a keyframe needs one (:meth:`CodeSLAM._keyframe_frame`)
    features: Features | None
    raw: tuple[Frame, Features | None, PinholeCamera, torch.Tensor | None]  # the frame and keypoints before any
    # rolling-shutter rectification, the input camera whose rows were read out and the input's depth (or None)
    readout: torch.Tensor | None = None  # the rotation over the readout the frame was rectified by (None: not)
    input_frame: Frame | None = None  # the frame as read, kept while its keypoints are put off (features None)


def _scaled_translation(T: torch.Tensor, s: float | None) -> torch.Tensor:
    """``T`` (4, 4) with its translation times ``s``, as a new tensor (records may share one); ``T`` itself when
    ``s`` is None or 1."""
    if s is None or s == 1.0:
        return T
    T = T.clone()
    T[:3, 3] *= s
    return T


def _rectified(frame: Frame, sensor: PinholeCamera, readout: torch.Tensor) -> Frame:
    """``frame`` (in the network's camera) as a global shutter at mid-readout would have seen it; ``sensor``: the
    input camera, whose rows were read out one after the other (along the frame's ``readout_axis``) while the
    camera turned by ``readout``."""
    uv = source_pixels(frame.camera, sensor, readout, axis=frame.readout_axis)
    image, inside = rectify_image(frame.image, uv)
    depth = None if frame.depth is None else rectify_image(frame.depth[None], uv, mode="nearest")[0][0]
    valid = inside
    if frame.valid is not None:
        valid = valid & (rectify_image(frame.valid[None].float(), uv, mode="nearest")[0][0] > 0.5)
    return dataclasses.replace(frame, image=image, depth=depth, valid=None if bool(valid.all()) else valid)


def _depth_in_view(depth: torch.Tensor, sensor: PinholeCamera, camera: PinholeCamera,
                   readout: torch.Tensor | None, axis: str) -> torch.Tensor:
    """(H, W) depth of the input camera ``sensor`` -> the network's ``camera`` (nearest, as
    :func:`~codeslam.data.frame.resample_frame` resamples a depth), rectified by the rotation over the readout
    ``readout`` (along the image ``axis``) as the frame's image was (:func:`_rectified`; None: not rectified)."""
    if sensor != camera:
        depth = resample_depth(depth[None, None].float(), sensor, camera)[0, 0]
    if readout is None:
        return depth
    return rectify_image(depth[None], source_pixels(camera, sensor, readout, axis=axis), mode="nearest")[0][0]


class CodeSLAM:
    """Dense monocular SLAM with learned depth codes (paper Sec. 4).

    config: the system's settings; depth_model: a :data:`DepthModelFactory` called once per keyframe; camera:
    the depth model's camera, to which every frame is resampled (the paper's intrinsics correction, Sec. 5.3);
    None takes the first frame's camera. parallel: map on a thread of its own beside the tracking
    (:mod:`codeslam.slam.mapping`); mapping_threads: that thread's torch threads (default half of
    ``torch.get_num_threads()``, at least 1), the tracking thread keeps the rest while it processes a frame;
    decode_threads: the mapping thread's torch threads while it decodes a keyframe (the network's forward pass and
    code Jacobian; default all of ``torch.get_num_threads()``): the tracker mostly waits for that keyframe, so its
    share of the cores would stand idle (HoloLens walk, parallel, 2 threads: a third of the run spent waiting for
    decoding with 1 thread; see :class:`~codeslam.slam.mapping.Mapper`).
    alignment_threads: torch threads of each frame's own work, its resampling to the network's and the feature
    camera and its photometric alignment (at most the caller's; None: the caller's). Its problem, a few thousand
    pixels and 8 unknowns, gains little from OpenMP's threads, which spin between its small kernels against
    OpenCV's and the mapping's work (TUM fr1/rpy, sequential, 2 threads: track stage median 68 -> 30 ms with 1,
    3.09 -> 3.36 frames/s); the resampling on two threads contends with the thread that reads the next frame
    (the same, mean resample stage 18.7-22.8 -> 11.6-11.9 ms with 1, the whole process 0.88x the wall time).
    clock: the runner's stopwatch (:mod:`codeslam.clock`): it times each frame's stages (resample, features,
    track, relocalise, readout, decode) on the tracking thread, and a fork of it the mapping steps' (decode,
    marginalise, window), which :attr:`FrameResult.timings_ms` reports; the default times nothing.

    frame_period: the camera's frame period in seconds where the caller knows it (a live run, whose frames come
    unevenly spaced as the system skips some: :func:`codeslam.slam.pipeline.live_frames`); None (the default):
    the median interval of the last frames processed, which is the period wherever few frames are missing.
    """

    def __init__(self, config: SLAMConfig, depth_model: DepthModelFactory,
                 camera: PinholeCamera | None = None, parallel: bool = False,
                 mapping_threads: int | None = None, alignment_threads: int | None = 1,
                 decode_threads: int | None = None, clock: Clock = NO_CLOCK) -> None:
        # what restart_with_readout makes the system anew with
        self._options = dict(parallel=parallel, mapping_threads=mapping_threads, alignment_threads=alignment_threads,
                             decode_threads=decode_threads, clock=clock)
        self.config = config
        self.depth_model = depth_model
        self.device = torch.device(config.device)
        self.dtype = config.torch_dtype
        self.camera = camera
        self.tracker = PhotometricTracker(config.tracker, config.window.sfm)
        self.sparse: SparseTracker | None = None  # made with the camera (first frame)
        # parallel: the mapping thread takes half of torch's threads, the tracking thread (the caller's) the rest
        total = torch.get_num_threads()
        if mapping_threads is None:
            mapping_threads = max(1, total // 2)
        if mapping_threads < 1:
            raise CodeSLAMError(f"mapping_threads must be >= 1, got {mapping_threads}")
        self._tracking_threads = max(1, total - mapping_threads) if parallel else None
        if alignment_threads is not None and alignment_threads < 1:
            raise CodeSLAMError(f"alignment_threads must be >= 1, got {alignment_threads}")
        self._alignment_threads = alignment_threads
        if decode_threads is not None and decode_threads < 1:
            raise CodeSLAMError(f"decode_threads must be >= 1, got {decode_threads}")
        self.clock = clock
        self.mapper = Mapper(config, parallel=parallel, threads=mapping_threads if parallel else None,
                             decode_threads=(decode_threads or total) if parallel else None, clock=clock.fork())
        self.keyframes: list[MapKeyframe] = []  # every keyframe ever made, by id
        self.ref: MapKeyframe | None = None  # the keyframe frames are tracked against
        self.segment = 0
        self.maps = SegmentMaps()  # which map each segment belongs to, once merged (recovery.merge_segments)
        self.merges: list[SegmentMerge] = []
        self._merge_seen: tuple[int, torch.Tensor, int] | None = None  # the last match: (map, G, keyframe)
        self._records: list[_FrameRecord] = []
        self.frame_period: float | None = None  # see the class docstring
        self._results: list[FrameResult] = []  # what process() returned, completed when mapping finishes
        self._keyframe_record: dict[int, int] = {}  # keyframe id -> position of its frame's record
        self._matches: FrameMatches | None = None  # the last frame's keypoints matched to the reference
        self._last_tracked: tuple | None = None  # (views, ref, sparse, record position) of a tracked non-keyframe
        self._lost = 0  # consecutive frames whose pose is only predicted
        self._thumbnails: dict[int, torch.Tensor] = {}  # keyframe id -> its thumbnail, for relocalisation
        self._prediction_error = math.inf  # the last frame's tracked pose from its prediction (_deviation)
        fcfg = config.features  # keypoints on demand (FeatureConfig.direct_first): the degrees, or 0 (never)
        on_demand = fcfg.enabled and (fcfg.direct_first == "always" or (fcfg.direct_first == "parallel" and parallel))
        self._direct_first_deg = fcfg.direct_first_deg if on_demand else 0.0
        self._undo: MappingResult | None = None  # the last window solve, to undo it (sequential mode)
        self._next_id = 0
        tcfg = config.tracker
        self.readout = 0.0 if tcfg.rolling_shutter_estimate else tcfg.rolling_shutter_readout
        self.readout_choice = ReadoutChoice() if tcfg.rolling_shutter_estimate else None
        # Its alignments start at the tracked pose and move it by a pixel at most: the finest level alone
        self._readout_tracker = PhotometricTracker(
            dataclasses.replace(tcfg, pyramid_levels=tcfg.pyramid_levels[-1:], max_iterations=(8,)),
            config.window.sfm) if tcfg.rolling_shutter_estimate else None
        self._turn: dict[int, tuple[torch.Tensor, float]] = {}  # estimating: keyframe id -> (its turn from the
        # frame before it, the readout it was rectified with)
        self._readouts_used: set[float] = set()  # the readouts frames were rectified by so far
        self._chosen: dict | None = None  # the online choice that made this system anew (restart_with_readout)

    @property
    def window(self) -> SlidingWindow:
        return self.mapper.window

    @property
    def reads_frame_depth(self) -> bool:
        """Whether the system reads the frames' depth: only its depth model may, and one that never does says so
        (``reads_depth = False`` on the factory, as the network's). When it does not, a runner may hand it frames
        without depth and give the keyframes the dataset's depth afterwards (:meth:`keyframe_depth`), for the
        report: a monocular run then decodes no depth map it does not use."""
        return bool(getattr(self.depth_model, "reads_depth", True))

    def keyframe_depth(self, kf: MapKeyframe, depth: torch.Tensor) -> torch.Tensor:
        """(H, W) the input's depth of ``kf``'s frame (in the input camera, as the dataset gives it) in the
        keyframe's view: resampled to the network's camera and rectified as its image was, as a keyframe made from
        a frame with depth keeps it in ``depth_gt``."""
        if kf.input_camera is None:
            raise CodeSLAMError(f"keyframe {kf.id} does not know the camera of its input frame")
        return _depth_in_view(depth, kf.input_camera, kf.view.camera, kf.rectified_by,
                              kf.readout_axis).detach().cpu().float()

    @property
    def parallel(self) -> bool:
        return self.mapper.parallel

    # ---- the algorithm --------------------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameResult:
        """Track ``frame`` against the reference keyframe (relocalise it when that fails), maybe make it a
        keyframe, optimise the window and marginalise the oldest keyframe (paper Sec. 4.2-4.3)."""
        with self.tracking_threads():
            try:
                result = self._process(frame)
            finally:
                ms = self.clock.split()  # this frame's stages (none left over from a frame that raised)
        for k, v in ms.items():  # beside the mapping stages of a keyframe mapped inline (sequential mode)
            result.timings_ms[k] = result.timings_ms.get(k, 0.0) + v
        return result

    @contextmanager
    def tracking_threads(self) -> Iterator[None]:
        """Parallel mode: the calling thread runs with the tracker's share of torch's threads inside the block
        (and gets its own count back after it), so that what it does beside :meth:`process` (a viewer's update,
        say) does not compete with the mapping thread for the cores either. A no-op when sequential."""
        with torch_threads(self._tracking_threads):
            yield

    def _aligning_threads(self) -> AbstractContextManager[None]:
        """The photometric alignments' torch threads (``alignment_threads``, at most the caller's) inside the
        block."""
        n = self._alignment_threads
        return torch_threads(None if n is None else min(n, torch.get_num_threads()))

    def _process(self, frame: Frame) -> FrameResult:
        self._check(frame)
        self._readouts_used.add(self.readout)  # what the frame's views are rectified by (and a keyframe's)
        self._apply(self.mapper.collect())  # keyframes the mapping thread finished: track against the newest
        direct_first = self._direct_first()
        with self._aligning_threads():  # the frame's resampling and keypoints, as its alignment (alignment_threads)
            views = self._views(frame, features=not direct_first)
        if not self.keyframes:  # the first frame that can anchor a map is its origin
            return self._start_map(views)
        ref = self.ref
        T_kf_guess = self._predict(ref, frame.timestamp)
        blank = self._image_problem(views)
        if blank:  # nothing to align: no rollback, no promoted keyframe, no relocalisation for it
            return self._lost_frame(views, ref, T_kf_guess, None, blank)
        with self.clock("track"):  # Sec. 4.2: coarse-to-fine alignment, keyframe depth fixed; started from PnP
            track, sparse, source = self._track(views, ref, T_kf_guess)
        deviation = self._deviation(T_kf_guess, track, ref)
        if direct_first and not deviation <= 2.0 * self._direct_first_deg:  # (NaN: not held either)
            # The prediction's basin did not hold (the alignment failed, or moved the pose further than a held
            # prediction is off: on the generator's fast turn, 7 deg from the prediction, the alignment from level 1
            # stopped 3.7 deg short and passed its checks): keypoints and PnP, as every frame without the setting.
            views = self._with_features(views)
            with self.clock("track"):
                track, sparse, source = self._track(views, ref, T_kf_guess)
            deviation = self._deviation(T_kf_guess, track, ref)
        self._prediction_error = deviation  # after any retry below: unknown (this frame's first track failed)
        rolled_back = ""
        if not track.ok and self._undo is not None:  # the last window solve may have broken the map
            rolled_back = self._roll_back(f"frame {frame.index} failed after it: {track.reason}")
            ref = self.ref
            views = self._with_features(views)
            with self.clock("track"):
                track, sparse, source = self._track(views, ref, self._predict(ref, frame.timestamp))
        self._undo = None
        if not track.ok and self.mapper.busy:
            # Parallel mode: the keyframe asked for on an earlier frame may be decoded by now or still being
            # decoded, and this frame has left the older reference behind (a parallel HoloLens run lost frames
            # 78-80 and 148-150 so, each right after a keyframe was asked for): take it, waiting for its decoding
            # (not for the window solve), as PTAM's tracker waits only when it must, and track against it.
            if self.mapper.decoding:
                self._wait_for_mapping()  # returns once the keyframe is handed over
            self._apply(self.mapper.collect())  # one handed over meanwhile
            if self.ref is not ref:
                ref = self.ref
                views = self._with_features(views)
                with self.clock("track"):
                    track, sparse, source = self._track(views, ref, self._predict(ref, frame.timestamp))
        if not track.ok and self._promote_last():  # the previous frame, tracked, becomes the reference
            ref = self.ref
            views = self._with_features(views)
            with self.clock("track"):
                track, sparse, source = self._track(views, ref, self._predict(ref, frame.timestamp))
        if not track.ok:
            views = self._with_features(views)
            with self.clock("relocalise"):
                found = self._relocalise(views, ref, T_kf_guess)
            if found is None:
                return self._lost_frame(views, ref, T_kf_guess, track, track.reason, rolled_back)
            ref, track, sparse, source, restart = found
            self._lost = 0
            if restart:  # relocalised against a keyframe outside the window: re-anchor the map there
                return self._restart(views, ref.T_wc @ track.T_kf, track, RELOCALISED,
                                     self._relocalised_in(ref, views.frame.index, track.feature_inliers),
                                     rolled_back)
            self.ref = ref
            return self._tracked(views, ref, track, sparse, source, RELOCALISED, rolled_back)
        self._lost = 0
        return self._tracked(views, ref, track, sparse, source, TRACKED, rolled_back)

    def _tracked(self, views: _Views, ref: MapKeyframe, track: TrackResult, sparse: SparseTrack | None,
                 source: str, status: str, rolled_back: str) -> FrameResult:
        """A frame with a pose: keep its matches for the next frame, and make it a keyframe if it has moved far
        enough (Sec. 4.3)."""
        if sparse is not None and sparse.ok and views.features is not None:
            self._matches = self.sparse.matches_for_next(ref.id, views.features, sparse)
        else:
            self._matches = None
        frames_since = len(self._records) - self._keyframe_record.get(ref.id, len(self._records) - 1)
        inliers = None  # the feature criterion applies where features could have been matched
        if self.config.features.enabled and views.features is not None and ref.sparse is not None:
            inliers = sparse.num_inliers if sparse is not None and sparse.ok else 0
        decision = decide_keyframe(track.T_kf, ref.median_depth(), track.overlap, frames_since, True,
                                   self.config.keyframes, inliers)
        kcfg = self.config.keyframes
        if (decision.add and not decision.starving and track.photometric_reason
                and track.overlap >= kcfg.urgent_overlap):
            # A frame the photometric alignment could not explain makes a poor keyframe: wait for a better one.
            # Not when the matches are thinning out: the next frames would have nothing left to match.
            decision = dataclasses.replace(decision, add=False, reason="poor photometric fit")
        if decision.add and self.mapper.busy:  # PTAM: the mapping thread is still on the last keyframe
            # The reference is leaving the view, or keyframes are taken when wanted (KeyframeConfig.take_when_busy):
            # wait for the mapping thread rather than track on against a keyframe the map has outgrown.
            if decision.urgent or self.config.keyframes.take_when_busy:
                self._wait_for_mapping()
                if self.ref.id != ref.id:  # a newer keyframe arrived meanwhile: track against it next frame
                    decision = dataclasses.replace(decision, add=False, reason="keyframe arrived")
            else:
                decision = dataclasses.replace(decision, add=False, reason=MAPPING_BUSY)
        older = self._older_keyframes() if decision.add else []
        if older:  # this segment may join an older map here
            views = self._with_features(views)
            merged = self._merge(views, ref, track, older)
            if merged:  # the keyframe's reason is what the frame log says of a keyframe
                # (parallel mode: the merge's wait may have taken in a newer keyframe; track against it next frame)
                decision = dataclasses.replace(decision, reason=f"{decision.reason}; {merged}",
                                               add=self.ref is ref)
        kw = dict(track=track, decision=decision, status=status, source=source, rolled_back=rolled_back)
        T_wc = ref.T_wc @ track.T_kf
        choosing = self.readout_choice is not None and not self.readout_choice.final
        # its rotation from the last frame (None for the first), needed while the readout is being chosen and to
        # rectify a new keyframe under a readout
        wanted = choosing or (decision.add and self.readout != 0)
        turn = self._turn_from_last(T_wc, views.frame.timestamp) if wanted else None
        estimating = choosing and turn is not None and self._records[-1].ok
        if estimating:
            self._estimate_readout(views, ref, track, turn)
        if not decision.add:
            self._last_tracked = (views, ref, sparse, len(self._records))
            return self._record(views.frame, ref, track.T_kf, True, **kw)
        kid, segment = self._new_id(), self.segment
        if estimating:
            self._turn[kid] = (turn, self.readout)  # the readout and turn it is rectified by, next line
        kviews = self._rerectified(self._with_features(views), turn)  # a keyframe's keypoints are the map's
        job = MappingJob(lambda: self._make_keyframe(kviews, T_wc, kid, segment), ref, sparse, len(self._records))
        result = self._record(views.frame, ref, track.T_kf, True, **kw)  # re-expressed once mapped
        done = self.mapper.insert(job)  # Sec. 4.3: decode, marginalise, optimise the window
        if done is not None:
            self._apply([done])
        return result

    def _track(self, views: _Views, ref: MapKeyframe,
               T_kf_guess: torch.Tensor) -> tuple[TrackResult, SparseTrack | None, str]:
        """The frame's pose in ``ref``: PnP on matched keypoints (guided by the motion model's guess) starts the
        photometric alignment, and the inlier matches join it as reprojection residuals."""
        fcfg = self.config.features
        sparse, term, init = None, None, T_kf_guess
        if fcfg.enabled and views.features is not None and ref.sparse is not None:
            sparse = self.sparse.track(ref.sparse, views.features, T_kf_guess, self._matches, ref.id)
            if sparse.ok:
                init = sparse.T_kf
                if fcfg.weight > 0:
                    term = self.sparse.term(ref.sparse, views.features, sparse, self.dtype, self.device)
        frame = views.frame

        # keypoints put off (FeatureConfig.direct_first): the last prediction held within a degree or so, inside
        # the basin of the level a PnP start begins at
        start_level = None
        if views.input_frame is not None and self.config.tracker.feature_start_level >= 0:
            start_level = self.config.tracker.feature_start_level

        def align(start: torch.Tensor, every_level: bool = False) -> TrackResult:
            return self.tracker.track(ref.view, ref.code, frame.gray, frame.camera, start,
                                      self._affine_guess(ref), valid=frame.valid, reprojection=term,
                                      min_feature_inliers=fcfg.min_inliers if term is not None else 0,
                                      feature_threshold=fcfg.pnp_threshold,
                                      T_kf_prior=T_kf_guess if len(self._records) >= 2 else None,
                                      prior_dt=self._since_tracked(frame), every_level=every_level,
                                      start_level=start_level)

        with self._aligning_threads():
            track = align(init)
            if term is not None and track.feature_inliers < fcfg.retry_agreement * sparse.num_inliers:
                # PnP's pose may have been a wrong start (FeatureConfig.retry_agreement): align from the motion
                # model's prediction too, and keep the lower of the two minima of the same cost (a pose that
                # passes the checks before one that does not).
                again = align(T_kf_guess, every_level=True)

                def rank(t: TrackResult) -> tuple[bool, float]:
                    return not t.ok, t.cost if math.isfinite(t.cost) else math.inf

                if rank(again) < rank(track):
                    track = again
        source = "direct"
        if term is not None:
            source = "direct+features" if not track.photometric_reason else "features"
            if track.ok and track.feature_inliers < fcfg.min_agreement * sparse.num_inliers:
                # The alignment left the pose the matches agree on (measured on the HoloLens walk: a frame kept
                # 3 of 39 matches and, made a keyframe, turned the map by degrees): the matches' pose instead.
                track = dataclasses.replace(track, T_kf=sparse.T_kf, feature_inliers=sparse.num_inliers,
                                            photometric_reason=track.photometric_reason or "left the matches' pose")
                source = "features"
        return track, sparse, source

    def _wait_for_mapping(self) -> None:
        """Parallel mode: wait until the keyframe being decoded is handed over, or the running window solve stops
        after its current iteration (:meth:`Mapper.wait` with ``interrupt``), and take in what the mapping thread
        finished. Timed as the stage "wait": the time the tracker loses to the mapping (on the parallel HoloLens
        walk 22 of the tracking thread's 38 s, docs/results/slam_table.md, fifty-second session)."""
        with self.clock("wait"):
            done = self.mapper.wait(interrupt=True)
        self._apply(done)

    def _promote_last(self) -> bool:
        """When a frame cannot be tracked against its keyframe, make the frame before it a keyframe (it was
        tracked against the same keyframe and did not become one) so that the frame is tracked against a view
        one frame old. Measured on the HoloLens walk at every second frame: frame 108, tracked with 102 feature
        inliers 12 deg from its keyframe but held back as a keyframe (the photometric fit was poor), was followed
        by a frame 21 deg from the keyframe with no match left; against frame 108 it matches 134 keypoints."""
        last, self._last_tracked = self._last_tracked, None
        if last is None or not self.config.recovery.promote_previous:
            return False
        views, ref, sparse, pos = last
        if pos != len(self._records) - 1 or ref is not self.ref or self._records[pos].keyframe_id != ref.id:
            return False
        views = self._with_features(views)  # a keyframe's keypoints are the map's
        rec, res = self._records[pos], self._results[pos]
        T_wc = ref.T_wc @ rec.T_kf
        if res.keyframe is not None:
            res.keyframe = dataclasses.replace(res.keyframe, add=True, reason="next frame lost")
        self._apply(self.mapper.wait())  # parallel mode: the mapping thread's last keyframe first
        if self.ref is not ref:  # a newer keyframe arrived meanwhile: track against that one instead
            return True
        kid, segment = self._new_id(), self.segment  # only now: an id taken and not used would shift every later one
        done = self.mapper.insert(MappingJob(lambda: self._make_keyframe(views, T_wc, kid, segment), ref, sparse,
                                             pos))
        self._apply([done] if done is not None else self.mapper.wait())
        return self.ref is not ref

    def _relocalise(self, views: _Views, ref: MapKeyframe, T_kf_guess: torch.Tensor):
        """Match a frame that failed against stored keyframes: those nearest to its predicted pose and those it
        looks most like (:mod:`codeslam.slam.thumbnails`); a match in the window is refined by the photometric
        alignment. Returns (keyframe, track, sparse, source, restart)
        with ``restart`` True when the keyframe has left the window, or None."""
        rcfg = self.config.recovery
        if not (rcfg.relocalise and self.config.features.enabled and views.features is not None):
            return None
        T_w_pred = ref.T_wc @ T_kf_guess
        stored = [k for k in self.keyframes if k.sparse is not None]
        stored.sort(key=lambda k: float((k.T_wc[:3, 3] - T_w_pred[:3, 3]).norm()))
        cands, rest = stored[:rcfg.max_candidates], stored[rcfg.max_candidates:]
        if rcfg.appearance_candidates > 0 and rest:  # and those it looks like, wherever the prediction is
            alike = most_alike(thumbnail(views.frame.image), torch.stack([self._thumbnail(k) for k in rest]),
                               rcfg.appearance_candidates)
            cands += [rest[i] for i in alike]
        found = self.sparse.relocalise([(k.id, k.sparse) for k in cands], views.features, rcfg.min_inliers)
        if found is None:
            return None
        kid, sparse = found
        kf = self.keyframes[kid]
        if not kf.active:  # outside the window: the PnP pose, and a new keyframe anchors the map there
            track = TrackResult(T_kf=sparse.T_kf, affine=torch.zeros(2, dtype=torch.float64), ok=True, reason="",
                                overlap=float("nan"), inlier_ratio=float("nan"), explained=float("nan"),
                                cost=float("nan"), iterations=0, feature_matches=sparse.matches,
                                feature_inliers=sparse.num_inliers)
            return kf, track, sparse, "features", True
        self._matches = None
        track, sparse2, source = self._track(views, kf, sparse.T_kf)
        if not track.ok:
            return None
        return kf, track, sparse2 if sparse2 is not None and sparse2.ok else sparse, source, False

    def _relocalised_in(self, kf: MapKeyframe, frame_index: int, inliers: int) -> str:
        """A frame relocalised against ``kf``, outside the window, restarts the window in ``kf``'s map. When that is
        another map than the current segment's, the frames from here on are that map's: they start a new segment
        joined to it at once (a merge whose motion is the identity), since the current segment's frames so far lie
        in a frame of their own (before, they kept the current segment's label, and its later keyframes lay in
        another frame than its earlier ones). Returns the frame's reason."""
        into = self.maps.root(kf.segment)
        if into == self.maps.root(self.segment):
            return "relocalised"
        self._new_segment()
        self.maps.join(self.segment, into)
        self.merges.append(SegmentMerge(self.segment, into, frame_index, kf.id, inliers,
                                        torch.eye(4, dtype=torch.float64)))
        return f"relocalised in segment {into}'s map (keyframe {kf.id}): new segment {self.segment} of it"

    def _new_segment(self) -> None:
        """The frames from here on are a new map segment (a match seen for the last one's merge is forgotten)."""
        self.segment += 1
        self._merge_seen = None

    def _older_keyframes(self) -> list[MapKeyframe]:
        """The keyframes of the maps older than the current segment's, which it may merge into
        (``recovery.merge_segments``; an older map is never moved into a newer one)."""
        if not (self.config.recovery.merge_segments and self.config.features.enabled and self.segment > 0):
            return []
        here = self.maps.root(self.segment)
        return [k for k in self.keyframes if k.sparse is not None and self.maps.root(k.segment) < here]

    def _merge(self, views: _Views, ref: MapKeyframe, track: TrackResult, older: list[MapKeyframe]) -> str:
        """A frame about to become a keyframe of a segment that may join an older map (:meth:`_older_keyframes`):
        match it against the older keyframes it looks like (:mod:`codeslam.slam.segments`). When this match and
        the last one, against another keyframe of the same map, agree, move the segment's map rigidly into the
        older one: its keyframes, the window's linear prior with them (:meth:`SlidingWindow.move`), and through
        them every frame tracked in it. The window goes on as it was: restarting it there instead (a new
        keyframe, as a relocalisation outside the window does) lost the HoloLens walk coming back, 56 deg off at
        its end, as a map started afresh at that frame does. Returns the frame's reason, '' without a merge."""
        rcfg = self.config.recovery
        if views.features is None:
            return ""
        with self.clock("merge"):
            alike = most_alike(thumbnail(views.frame.image), torch.stack([self._thumbnail(k) for k in older]),
                               max(rcfg.appearance_candidates, 1))
            found = self.sparse.relocalise([(older[i].id, older[i].sparse) for i in alike], views.features,
                                           rcfg.min_inliers)
        if found is None:
            return ""
        kid, sparse = found
        there = self.keyframes[kid]
        into = self.maps.root(there.segment)
        T_here = ref.T_wc @ track.T_kf  # the frame in its own segment
        G = segment_motion(T_here, there.T_wc @ sparse.T_kf)
        seen, self._merge_seen = self._merge_seen, (into, G, kid)
        # Two matches of two frames against two keyframes: a single match can be a repeated texture (the HoloLens
        # walk's frame 180 matched frame 20's keyframe with 36 of 51 matches inliers, 3 m from it), and so can a
        # second one of the same view (the walk coming back shows frame 180 again).
        if seen is None or seen[0] != into or seen[2] == kid or not motions_agree(
                seen[1], G, T_here, there.median_depth(), rcfg.merge_agreement, rcfg.merge_agreement_deg):
            return ""
        self._apply(self.mapper.wait())  # the window's last solve lands before its keyframes move
        here = self.maps.root(self.segment)
        G = segment_motion(ref.T_wc @ track.T_kf, there.T_wc @ sparse.T_kf)  # the solve may have moved ref
        for k in self.keyframes:
            if self.maps.root(k.segment) == here and not k.active:
                k.T_wc = G @ k.T_wc
        self.mapper.move(G)
        self._undo, self._merge_seen = None, None  # the last solve's snapshot lies where the map was
        self.maps.join(here, into)
        self.merges.append(SegmentMerge(self.segment, into, views.frame.index, kid, sparse.num_inliers, G))
        return f"segment {self.segment} merged into segment {into} (keyframe {kid}, {sparse.num_inliers} inliers)"

    def _thumbnail(self, kf: MapKeyframe) -> torch.Tensor:
        """Keyframe ``kf``'s thumbnail (:func:`~codeslam.slam.thumbnails.thumbnail`), made once."""
        found = self._thumbnails.get(kf.id)
        if found is None:
            found = self._thumbnails[kf.id] = thumbnail(kf.view.image)
        return found

    def _lost_frame(self, views: _Views, ref: MapKeyframe, T_kf_guess: torch.Tensor,
                    track: TrackResult | None, reason: str, rolled_back: str = "") -> FrameResult:
        """The motion model's pose, flagged; after ``recovery.lost_frames`` such frames a new map segment."""
        self._lost += 1
        self._matches = None
        if self._lost > self.config.recovery.lost_frames and not self._anchor_problem(views):
            self._new_segment()
            return self._restart(views, ref.T_wc @ T_kf_guess, track, PREDICTED,
                                 f"new segment after {self._lost - 1} lost frames ({reason})", rolled_back)
        return self._record(views.frame, ref, T_kf_guess, False, track=track, reason=reason, status=PREDICTED,
                            source="motion model", rolled_back=rolled_back)

    def _image_problem(self, views: _Views) -> str:
        """Why a frame's image can neither be tracked nor anchor a map ('' when it can): non-finite pixels, or no
        texture (intensity std below ``tracker.min_intensity_std``: a black, white or blank frame). Such a frame
        is lost at once: a black frame in mid-run used to be aligned, then made the last frame a keyframe
        ("next frame lost") and undid the last window solve, as a failure caused by the map would."""
        frame = views.frame
        if not image_is_finite(frame.image):
            return "non-finite pixels in the image"
        valid = frame.gray[0] if frame.valid is None else frame.gray[0][frame.valid]
        std = float(valid.std()) if valid.numel() >= 2 else 0.0
        if std < self.config.tracker.min_intensity_std:
            return f"no texture in the frame (intensity std {std:.4f} below {self.config.tracker.min_intensity_std:g})"
        return ""

    def _anchor_problem(self, views: _Views) -> str:
        """Why a frame cannot start a new map segment ('' when it can): :meth:`_image_problem`, and with features
        too few keypoints to match later frames to (ORB + PnP must relocalise against it)."""
        why = self._image_problem(views)
        if not why and self.config.features.enabled:
            found = 0 if views.features is None else len(views.features)
            if found < 2 * self.config.features.min_inliers:
                return f"{found} keypoints, fewer than {2 * self.config.features.min_inliers}"
        return why

    def _restart(self, views: _Views, T_wc: torch.Tensor, track: TrackResult | None,
                 status: str, reason: str, rolled_back: str) -> FrameResult:
        """Empty the window (its keyframes stay in the map for relocalisation and output) and make this frame the
        first keyframe of a new window at ``T_wc``, its pose the new gauge."""
        self._apply(self.mapper.wait())
        self._undo, self._matches, self._lost = None, None, 0
        with self.clock("decode"):
            kf = self._make_keyframe(views, T_wc, self._new_id(), self.segment)
        self.mapper.restart(kf)
        self._append(kf)
        self.ref = kf
        ok = status != PREDICTED
        return self._record(views.frame, kf, torch.eye(4, dtype=torch.float64), ok, track=track,
                            reason=reason, status=status, source="features" if ok else "motion model",
                            rolled_back=rolled_back)

    def _apply(self, done: list[MappingResult]) -> None:
        """Take in finished mapping steps: the keyframe joins the map, its frame's record and result are
        re-expressed relative to it, and frames are tracked against it from now on."""
        for m in done:
            if m.report is not None:  # a solve (not the early hand-over of a decoded keyframe)
                self._rescale(m.report.depth_scale)
            kf = m.keyframe
            res = self._results[m.frame_position]
            res.window, res.marginalised_id = m.report, m.marginalised
            for k, v in m.ms.items():  # the mapping stages, timed where they ran
                res.timings_ms[k] = res.timings_ms.get(k, 0.0) + v
            if res.is_keyframe:  # the solve of a keyframe already handed over (parallel mode)
                continue
            self._append(kf)
            rec = self._records[m.frame_position]
            rec.keyframe_id, rec.T_kf, rec.affine = kf.id, torch.eye(4, dtype=torch.float64), None
            self._keyframe_record[kf.id] = m.frame_position
            res.is_keyframe, res.keyframe_id = True, kf.id
            res.reason = res.keyframe.reason if res.keyframe is not None else res.reason
            res.T_wc = kf.T_wc
            if res.status == INITIALISING and len(self.keyframes) >= 2:  # the second keyframe ends the start-up
                res.status = TRACKED
            self.ref = kf
            self._matches = None
            self._undo = m if not self.parallel and m.before is not None else None

    def _roll_back(self, why: str) -> str:
        m, self._undo = self._undo, None
        self.mapper.roll_back(m.before)
        self._rescale({k: 1.0 / s for k, s in m.report.depth_scale.items()})
        return why

    def _rescale(self, scale: dict[int, float]) -> None:
        """A frame's translation is in the depth units of the keyframe it was tracked against (the alignment's
        translation scales with that depth). The frames before a map segment's second keyframe were tracked
        against the first keyframe's single-view depth, which the segment's first solve rescales as it sets the
        map's scale (keyframe id -> new / old median depth, ``WindowReport.depth_scale``): their translations
        follow. Measured on the generator's hand-held preset (30 frames/s, the same run's frames re-expressed
        three ways): ATE 0.0202 m as tracked, 0.0122 m rescaled after the first solve, 0.0132 m rescaled after
        every solve; every solve's rescaling also made TUM fr1/rpy's RPE 19.6 -> 24.1 mm and the generator walk
        0.083 -> 0.086 m, so later solves leave the frames as tracked."""
        if not scale:
            return
        for rec in self._records:  # the pose now and as tracked, each in its keyframe's depth units
            rec.T_kf = _scaled_translation(rec.T_kf, scale.get(rec.keyframe_id))
            rec.T_tracked = _scaled_translation(rec.T_tracked, scale.get(rec.tracked_id))

    def finish(self) -> None:
        """Wait for the mapping thread to finish its work and stop it (parallel mode; a no-op otherwise)."""
        try:
            self._apply(self.mapper.wait())
        finally:
            self.mapper.close()

    def close(self) -> None:
        """Stop the mapping thread without taking in its work (after an error)."""
        self.mapper.close()

    def _append(self, kf: MapKeyframe) -> None:
        """Keyframe ids are their places in :attr:`keyframes` (frame records refer to them by id)."""
        if kf.id != len(self.keyframes):
            raise CodeSLAMError(f"internal error: keyframe {kf.id} would be stored at place {len(self.keyframes)}")
        self.keyframes.append(kf)

    def _new_id(self) -> int:
        kid = self._next_id
        self._next_id += 1
        return kid

    def _start_map(self, views: _Views) -> FrameResult:
        """The map's first keyframe, at the origin; a frame whose image cannot anchor it (:meth:`_image_problem`;
        its keypoints are not counted: the first frames are tracked photometrically too) waits for the next frame
        instead. A black first frame used to start the map: the frames after it failed against it until a new
        segment began (one black frame before TUM fr1/rpy: frames 1-4 lost)."""
        why = self._image_problem(views)
        if why:
            return self._before_map(views.frame, why)
        with self.clock("decode"):
            kf = self._make_keyframe(views, torch.eye(4, dtype=torch.float64), self._new_id(), self.segment)
        self.mapper.start(kf)
        self._append(kf)
        self.ref = kf
        return self._record(views.frame, kf, torch.eye(4, dtype=torch.float64), True, reason="first frame",
                            status=INITIALISING)

    def _before_map(self, frame: Frame, why: str) -> FrameResult:
        """A frame before the map has begun (``why`` it could not begin it): not tracked, placed at the origin
        that the map's first keyframe (id 0, made later) will have."""
        eye = torch.eye(4, dtype=torch.float64)
        self._records.append(_FrameRecord(frame.index, float(frame.timestamp), 0, eye, False, None, 0, eye))
        result = FrameResult(index=frame.index, timestamp=float(frame.timestamp), T_wc=eye.clone(), tracking_ok=False,
                             status=PREDICTED, keyframe_id=0, is_keyframe=False,
                             reason=f"no map: {why}", segment=self.segment)
        self._results.append(result)
        return result

    # ---- helpers --------------------------------------------------------------------------------------------
    def _check(self, frame: Frame) -> None:
        if frame.image.dim() != 3 or frame.image.shape[0] not in (1, 3):
            raise CodeSLAMError(f"frame {frame.index}: image must be (3, H, W) or (1, H, W), "
                                f"got {tuple(frame.image.shape)}")
        if self._records and frame.timestamp <= self._records[-1].timestamp:
            raise CodeSLAMError(f"frame {frame.index}: timestamp {frame.timestamp} does not increase "
                                f"(previous {self._records[-1].timestamp})")

    def _views(self, frame: Frame, features: bool = True) -> _Views:
        """The frame in the network's camera and, with ``features``, its keypoints in the feature camera (both
        resampled from the input frame, so keypoints see its full resolution); without, the input frame is kept
        for :meth:`_with_features`."""
        if self.camera is None:
            self.camera = frame.camera
        with self.clock("resample"):  # the depth is resampled for keyframes only (_keyframe_frame)
            net = resample_frame(dataclasses.replace(frame, depth=None), self.camera)
        keypoints, kept = None, None
        if self.config.features.enabled:
            if self.sparse is None:
                fcfg = self.config.features
                self.sparse = SparseTracker(fcfg, scaled_camera(self.camera, fcfg.scale), self.camera)
                self.mapper.sparse = self.sparse
                self.window.sparse = SparseSettings(self.sparse.camera, fcfg.sigma,
                                                    self.sparse.extract.orb.getScaleFactor())
            if features:
                with self.clock("features"):
                    keypoints = self.sparse.features_of(frame)
            else:
                kept = frame
        raw = (net, keypoints, frame.camera, frame.depth)
        if self.readout == 0:
            return _Views(net, keypoints, raw, input_frame=kept)
        with self.clock("resample"):
            last = self._last_motion()
            omega = None if last is None else self._readout_rotation(*last)
            return self._rectified_views(raw, omega, kept)

    def _with_features(self, views: _Views) -> _Views:
        """``views`` with the keypoints of a frame whose extraction was put off (FeatureConfig.direct_first),
        rectified as its image was; ``views`` itself when they are there or not wanted."""
        if views.input_frame is None:
            return views
        with self._aligning_threads(), self.clock("features"):  # as in _views
            keypoints = self.sparse.features_of(views.input_frame)
        net, _, sensor, depth = views.raw
        return _Views(views.frame, self._rectified_features(keypoints, sensor, views.readout, net.readout_axis),
                      (net, keypoints, sensor, depth), views.readout)

    def _direct_first(self) -> bool:
        """Whether this frame is aligned from the motion model's prediction before any keypoints are extracted:
        keypoints on demand, the last frame tracked and its prediction within ``features.direct_first_deg``."""
        return (self._direct_first_deg > 0 and bool(self._records) and self._records[-1].ok and self._lost == 0
                and self._prediction_error <= self._direct_first_deg)

    def _deviation(self, T_pred: torch.Tensor, track: TrackResult, ref: MapKeyframe) -> float:
        """How far a tracked pose ``track.T_kf`` lies from its prediction ``T_pred`` (both in ``ref``), in degrees:
        the rotation between them plus their translation's distance over the keyframe's median depth (radians of
        parallax), scale-free as the keyframe decision's baseline ratio. Infinite for a failed track, and without
        keypoints on demand (nothing reads it then, and the median depth decodes the keyframe's depth)."""
        if not track.ok or self._direct_first_deg <= 0:
            return math.inf
        D = se3_inverse(T_pred.to(torch.float64)) @ track.T_kf.to(torch.float64)
        ratio, rot = motion_since_keyframe(D, ref.median_depth())
        return rot + math.degrees(ratio)

    def _rerectified(self, views: _Views, turn: torch.Tensor | None) -> _Views:
        """A new keyframe's views rectified again with ``turn``, its tracked rotation from the last frame, instead
        of the one frame older motion-model guess."""
        if self.readout == 0 or turn is None:
            return views
        return self._rectified_views(views.raw, self.readout * turn)

    def _readout_rotation(self, motion: torch.Tensor | None, dt: float) -> torch.Tensor | None:
        """The camera's rotation over the sensor's readout: the readout (``tracker.rolling_shutter_readout`` or
        the estimate, a fraction of the frame period) times the rotation of ``motion`` (``T_prev^-1 T_cur`` over
        ``dt`` s, so R_cur = R_prev Exp(omega): in the camera frame) in one frame period (:meth:`_per_period`);
        float64 (3,) on the CPU, where frames are rectified, or None without a motion."""
        if motion is None:
            return None
        return self.readout * self._per_period(so3_log(motion[:3, :3].to(torch.float64)).cpu(), dt)

    def _periods(self, dt: float) -> float:
        """Frame periods in ``dt`` s, rounded to whole ones and at least 1: a camera's frames come at its rate, a
        dropped frame makes one interval two, and the timestamps' own jitter (TUM fr1/rpy: 29-39 ms at 30 frames/s)
        is left out, so evenly timed frames count 1 each as before. The period is :attr:`frame_period` where it is
        known, else the median interval of the last :data:`PERIOD_FRAMES` frames; NaN before there are two frames
        or without usable times."""
        if not math.isfinite(dt) or not dt > 0:
            return math.nan
        if self.frame_period is not None:
            return float(max(1, round(dt / self.frame_period)))
        t = [r.timestamp for r in self._records[-PERIOD_FRAMES:]]
        if len(t) < 2:
            return math.nan
        # statistics, not NumPy: 29 numbers, two to four times a frame (26 -> 2 us a call, the same median)
        return float(max(1, round(dt / statistics.median(b - a for a, b in zip(t, t[1:])))))

    def _per_period(self, turn: torch.Tensor, dt: float) -> torch.Tensor:
        """A rotation vector turned over ``dt`` s, as the same angular velocity turns in one frame period: the
        readout is a fraction of that period. Measured on TUM fr1/rpy (a Kinect's rolling shutter) with a tenth of
        its frames dropped at random: rectified by the rotation over two periods after each dropped frame, the run
        ended 0.0378 m and 2.8 deg off (now 0.0162 m, 1.6 deg), against 0.0117 m and 1.34 deg with every frame
        (docs/results/slam_table.md, session of 2026-12-05)."""
        k = self._periods(dt)
        return turn / k if k > 1 else turn

    def _turn_from_last(self, T_wc: torch.Tensor, timestamp: float) -> torch.Tensor | None:
        """The rotation vector (float64 (3,) on the CPU, camera frame) from the last frame to a frame at ``T_wc``
        and ``timestamp``, in one frame period (:meth:`_per_period`); None before any frame."""
        if not self._records:
            return None
        last = self._records[-1]
        turn = so3_log((se3_inverse(self._pose(last)) @ T_wc)[:3, :3].to(torch.float64)).cpu()
        return self._per_period(turn, timestamp - last.timestamp)

    def _estimate_readout(self, views: _Views, ref: MapKeyframe, track: TrackResult, turn: torch.Tensor) -> None:
        """Weigh a tracked frame (``turn`` from a tracked last frame) for the readout when it turns against its
        keyframe; a keyframe without a frame before it (the first) takes the turn of the frame after it."""
        if ref.id not in self._turn and self._keyframe_record.get(ref.id) == len(self._records) - 1:
            self._turn[ref.id] = (turn, 0.0)  # not rectified: made before any readout
        if ref.id in self._turn and self.readout_choice.informative(turn - self._turn[ref.id][0]):
            with self.clock("readout"):
                self._weigh_readouts(views, ref, track, turn, *self._turn[ref.id])

    def _weigh_readouts(self, views: _Views, ref: MapKeyframe, track: TrackResult, turn: torch.Tensor,
                        kf_turn: torch.Tensor, kf_readout: float) -> None:
        """Evidence for the readout (:mod:`codeslam.slam.readout`): the tracked frame (own turn from the last frame
        ``turn``) aligned again to ``ref`` (turn ``kf_turn``, rectified by ``kf_readout`` times it), photometrically
        from its tracked pose, under readout 0 and each candidate; the choice so far holds from the next frame."""
        net, _, sensor, _ = views.raw

        def residual(c: float) -> float:  # the frame keeps the keyframe's distortion under hypothesis c
            readout = c * (turn - kf_turn) + kf_readout * kf_turn
            frame = _rectified(net, sensor, readout) if float(readout.norm()) > 0 else net
            r = self._readout_tracker.track(ref.view, ref.code, frame.gray, frame.camera, track.T_kf,
                                            track.affine, valid=frame.valid)
            return r.residual if r.overlap > 0 else math.nan

        with self._aligning_threads():
            base = residual(0.0)
            candidates = {c: residual(c) for c in self.readout_choice.candidates}
        self.readout_choice.add(base, candidates, views.frame.index)
        if self.readout_choice.value is not None:
            self.readout = self.readout_choice.value

    def _rectified_views(self, raw: tuple[Frame, Features | None, PinholeCamera, torch.Tensor | None],
                         readout: torch.Tensor | None, input_frame: Frame | None = None) -> _Views:
        """The views of ``raw`` (the frame in the network's camera, its keypoints, the input camera whose rows were
        read out, the input's depth) rectified by the readout rotation ``readout`` (as they are for None); they
        keep ``raw`` (and ``input_frame``, the frame whose keypoints were put off)."""
        net, features, sensor, _ = raw
        if readout is None:
            return _Views(net, features, raw, input_frame=input_frame)
        return _Views(_rectified(net, sensor, readout),
                      self._rectified_features(features, sensor, readout, net.readout_axis), raw, readout, input_frame)

    def _rectified_features(self, features: Features | None, sensor: PinholeCamera,
                            readout: torch.Tensor | None, axis: str) -> Features | None:
        """Keypoints found in the input frame moved as its image is rectified by ``readout`` (None: not), the
        sensor's rows along the image ``axis``."""
        if readout is None or features is None or len(features) == 0:
            return features
        uv = rectify_points(torch.from_numpy(features.uv), self.sparse.camera, sensor, readout, axis)
        return dataclasses.replace(features, uv=uv.numpy())

    @staticmethod
    def _keyframe_frame(views: _Views) -> Frame:
        """``views.frame`` with the input's depth (if any) resampled to the network's camera and rectified as the
        frame was: the map keeps it beside the keyframe's estimate, and a stand-in depth model reads it. Tracking
        never reads depth, so the other frames skip this (TUM fr1/rpy: about 1.4 ms of every frame's 640x480 ->
        128x96 resampling and rectification, on the tracking thread)."""
        net, _, sensor, depth = views.raw
        if depth is None:
            return views.frame
        return dataclasses.replace(views.frame, depth=_depth_in_view(depth, sensor, net.camera, views.readout,
                                                                     net.readout_axis))

    def _make_keyframe(self, views: _Views, T_wc: torch.Tensor, kid: int, segment: int) -> MapKeyframe:
        """Decode the frame's depth model (the network's forward pass and code Jacobian, once per keyframe, Sec.
        4.1) and make keyframe ``kid`` of map segment ``segment`` at ``T_wc`` with the zero code."""
        frame = self._keyframe_frame(views)
        decoder = self.depth_model(frame)
        H, W = frame.image.shape[-2:]
        need = self.config.decoder_levels
        if decoder.num_levels < need:
            raise CodeSLAMError(f"the depth model gives {decoder.num_levels} pyramid levels, the tracker and window "
                                f"use {need}")
        if tuple(decoder.levels[0].prox0.shape) != (H, W):
            raise CodeSLAMError(f"the depth model's output is {tuple(decoder.levels[0].prox0.shape)}, the frame "
                                f"{(H, W)}")
        if self.keyframes and decoder.code_size != self.keyframes[0].network_code.shape[0]:  # keyframe 0 stays
            raise CodeSLAMError("the depth model changed its code size between keyframes")
        decoder = decoder.to(dtype=self.dtype, device=self.device)
        basis = None
        if self.config.window.code_directions > 0:  # the code's leading directions only (WindowConfig)
            decoder, basis = decoder.principal(self.config.window.code_directions)
        if self.config.window.free_scale:  # one more code entry, the depth's log scale (WindowConfig)
            decoder = ScaledDecoder.wrap(decoder)
        image = frame.image.to(dtype=self.dtype, device=self.device)  # RGB kept for the map's colours
        code = torch.zeros(decoder.code_size, dtype=self.dtype, device=self.device)
        depth_zero = decoder.depth(code, 0).detach().cpu().float()
        b = decoder.levels[0].uncertainty
        kf = MapKeyframe(
            id=kid, frame_index=frame.index, timestamp=float(frame.timestamp),
            view=Keyframe(image, frame.camera, decoder, frame.valid),
            T_wc=project_to_se3(T_wc), code=code, depth_zero=depth_zero,
            uncertainty=None if b is None else b.detach().cpu().float(),
            depth_gt=None if frame.depth is None else frame.depth.detach().cpu().float(), segment=segment,
            code_basis=basis, free_scale=self.config.window.free_scale, input_camera=views.raw[2],
            rectified_by=views.readout, readout_axis=views.raw[0].readout_axis,
        )
        if views.features is not None and len(views.features) > 0:
            kf.sparse = KeyframeFeatures(views.features, self.sparse.points(views.features, depth_zero))
        return kf

    def _pose(self, rec: _FrameRecord) -> torch.Tensor:
        return self.keyframes[rec.keyframe_id].T_wc @ rec.T_kf

    def _predict(self, ref: MapKeyframe, timestamp: float) -> torch.Tensor:
        """The pose in ``ref`` of the frame at ``timestamp`` predicted by the motion model: the last pose moved by
        the last inter-frame motion between two successfully tracked frames (constant velocity; a failed frame's
        guessed pose never feeds the velocity, so guesses cannot compound), or the last pose ('static'). The motion
        is that of the camera's velocity over the time to this frame: ``exp(s log M)`` with ``s`` this interval over
        the motion's, each in whole frame periods (:meth:`_periods`), so that a frame after dropped ones is
        predicted where a constant velocity takes it (a walk with four frames dropped at a turn: 29 deg from the
        last frame, against the 5 deg of one frame's motion; docs/results/slam_table.md, session of 2026-12-05)."""
        last = self._records[-1]
        T_pred = self._pose(last)
        found = self._last_motion() if self.config.tracker.motion_model == "constant_velocity" else None
        if found is not None:
            motion, dt = found
            T_pred = T_pred @ scale_motion(motion, self._periods(timestamp - last.timestamp) / self._periods(dt))
        return se3_inverse(ref.T_wc) @ T_pred

    def _since_tracked(self, frame: Frame) -> float | None:
        """Seconds from the last successfully tracked frame to ``frame`` (None before there is one): the motion
        prior's interval, so that a prediction carried over lost frames is held only as loosely as it deserves."""
        last = next((r for r in reversed(self._records) if r.ok), None)
        return None if last is None else float(frame.timestamp) - last.timestamp

    def _last_motion(self) -> tuple[torch.Tensor, float] | None:
        """``T_prev^-1 T_cur`` of the last two successfully tracked consecutive frames and the seconds between
        them (None before there are two): the motion model's velocity. When the later frame has since become a
        keyframe, the motion is taken as the two were tracked against their common keyframe: its pose now is the
        window's, and the window's correction of it is not the camera's motion. (On the generator's fast turn a
        window moved such a keyframe 7 cm while the camera moved 2 mm; with the motion prior on, the next 60 frames
        kept moving 6-9 cm per frame.) None as well from a relocalised frame on until the next frame is tracked:
        the step to a relocalised pose is where the estimate was wrong, or where the camera was carried, not the
        camera's velocity (TUM fr1/rpy carried from frame 149 back to frame 20: that step taken as the velocity
        put the next two frames off, each relocalised again, and the map 13 times too large afterwards)."""
        for prev, cur in zip(reversed(self._records[:-1]), reversed(self._records)):
            if cur.relocalised:
                return None
            if prev.ok and cur.ok:
                dt = cur.timestamp - prev.timestamp
                if cur.keyframe_id != cur.tracked_id and prev.tracked_id == cur.tracked_id:
                    return se3_inverse(prev.T_tracked) @ cur.T_tracked, dt
                return se3_inverse(self._pose(prev)) @ self._pose(cur), dt
        return None

    def _affine_guess(self, ref: MapKeyframe) -> torch.Tensor | None:
        last = self._records[-1]
        return last.affine if last.ok and last.keyframe_id == ref.id else None

    def _record(
        self, frame: Frame, kf: MapKeyframe, T_kf: torch.Tensor, ok: bool,
        track: TrackResult | None = None, decision: KeyframeDecision | None = None,
        window: WindowReport | None = None, marginalised: int | None = None, reason: str = "",
        status: str = TRACKED, source: str = "", rolled_back: str = "",
    ) -> FrameResult:
        is_kf = kf.frame_index == frame.index
        if is_kf:
            self._keyframe_record[kf.id] = len(self._records)
        affine = track.affine if (ok and track is not None and not is_kf) else None
        T_kf = T_kf.to(torch.float64)
        rec = _FrameRecord(frame.index, float(frame.timestamp), kf.id, T_kf, ok, affine, kf.id, T_kf,
                           relocalised=status == RELOCALISED)
        self._records.append(rec)
        if status == TRACKED and len(self.keyframes) < 2:
            status = INITIALISING
        result = FrameResult(
            index=frame.index, timestamp=float(frame.timestamp), T_wc=self._pose(rec), tracking_ok=ok,
            status=status, keyframe_id=kf.id, is_keyframe=is_kf, reason=reason, segment=self.segment, source=source,
            track=track, keyframe=decision, window=window, marginalised_id=marginalised, rolled_back=rolled_back,
        )
        self._results.append(result)
        return result

    # ---- results --------------------------------------------------------------------------------------------
    def trajectory(self) -> Trajectory:
        """Every processed frame's final pose: ``T_wk T_kf`` (its keyframe's latest pose), and with the config's
        ``trajectory: interpolated`` the frames between two keyframes moved toward the next one's
        (:meth:`_interpolated`); then, with ``trajectory_smoothing``, the positions smoothed (:meth:`_smooth`)."""
        if not self._records:
            raise CodeSLAMError("no frame has been processed")
        if not self.keyframes:
            last = self._results[-1].reason.removeprefix("no map: ")  # _before_map's reason
            raise CodeSLAMError(f"no map: none of the {len(self._records)} frames could start one (the last: {last})")
        poses = torch.stack([self._pose(r) for r in self._records])
        t = np.array([r.timestamp for r in self._records])
        if self.config.trajectory == "interpolated":
            poses = self._interpolated(poses)
            self._bridge_lost(poses)
        if self.config.trajectory_smoothing > 0:
            self._smooth(poses, t)
        return Trajectory(t, poses)

    def _smooth(self, poses: torch.Tensor, t: np.ndarray) -> None:
        """Smooth the positions of ``poses`` (one per record, at times ``t``) in place, each map on its own (a map
        segment with those merged into it, :mod:`codeslam.slam.segments`; :func:`~codeslam.slam.smoothing.
        smooth_positions`): the tracked and relocalised frames are its measurements, the predicted ones are placed
        by the spline alone, and the map's first frame stays where it is."""
        segment = np.array(self._record_maps())
        ok = np.array([r.ok for r in self._records])
        for s in np.unique(segment):
            at = np.nonzero(segment == s)[0]
            x = smooth_positions(t[at], poses[at, :3, 3].numpy(), ok[at], self.config.trajectory_smoothing,
                                 anchor=True)  # the segment's first keyframe is its gauge
            poses[at, :3, 3] = torch.from_numpy(x).to(poses.dtype)

    def _interpolated(self, poses: torch.Tensor) -> torch.Tensor:
        """``poses`` (one per record, ``T_wk T_kf``) with each run of frames tracked against keyframe k, between
        k's frame and the frame that became keyframe k + 1 (tracked against k too, in the same map segment),
        spread toward the poses that k + 1 implies (:func:`~codeslam.slam.poses.spread_correction`), each by how far
        along the motion tracked from k to k + 1 it lies (:func:`~codeslam.slam.poses.path_fractions`).
        Frames kept in a keyframe other than the one they were tracked against, and keyframes, keep their reference
        poses; so does every frame where k and k + 1 lie in different map segments."""
        poses = poses.clone()
        for k in range(len(self.keyframes) - 1):
            a, b = self._keyframe_record.get(k), self._keyframe_record.get(k + 1)
            if a is None or b is None:
                continue
            nxt = self._records[b]
            if nxt.tracked_id != k or self.keyframes[k + 1].segment != self.keyframes[k].segment:
                continue
            # the frames tracked against k before keyframe k + 2: with parallel mapping some come after k + 1's
            # frame, tracked on against k while k + 1 was decoded; they take the whole change (fraction 1)
            end = self._keyframe_record.get(k + 2, len(self._records))
            # (keyframe k + 1's own record is re-expressed in k + 1, so it is not among them)
            inner = [i for i in range(a + 1, end)
                     if self._records[i].keyframe_id == k and self._records[i].tracked_id == k]
            if not inner:
                continue
            # keyframe k where keyframe k + 1's final pose and its tracking against k put it
            T_k_next = self.keyframes[k + 1].T_wc @ se3_inverse(nxt.T_tracked)
            T_kf = torch.stack([self._records[i].T_kf for i in inner])
            on_path = sum(i < b for i in inner)  # those after k + 1's frame take the whole change
            f = torch.ones(len(inner), dtype=torch.float64)
            if on_path:
                path = torch.cat([T_kf[:on_path].to(torch.float64), nxt.T_tracked.to(torch.float64)[None]])
                by_motion = path_fractions(path, self.keyframes[k].median_depth())
                f[:on_path] = by_motion if by_motion is not None else self._time_fractions(inner[:on_path], a, b)
            poses[inner] = spread_correction(poses[inner], T_k_next @ T_kf, f)
        return poses

    def _bridge_lost(self, poses: torch.Tensor) -> None:
        """Each run of lost frames (pose only predicted) between two frames with a pose in the same map (one map
        segment, or two merged, :mod:`codeslam.slam.segments`) placed in ``poses`` (one per record; in place) on
        the geodesic from the frame before the run to the frame after it, by time (:func:`~codeslam.slam.poses.
        spread_correction`, :meth:`_time_fractions`): the camera's constant velocity between two known poses
        instead of the live prediction, which carries the last velocity on over the whole run. Runs at the end of
        a segment that was never merged stay as predicted: the next segment's pose is itself a prediction.
        Measured with the lens covered (grey level 3 plus noise) for 30 frames of TUM fr1/rpy, tracked again at
        frame 90 against the same keyframe: the covered frames' rotations 26.1 -> 12.6 deg RMSE off the truth (59
        -> 20 deg at worst), the run's 10.8 -> 5.5 deg; on generator presets 7.2 -> 3.9 (walk, 8 frames), 9.4 ->
        2.1 (hand-held, 15), 4.4 -> 0.9 deg (fast turn, 15); docs/results/slam_table.md, fiftieth session."""
        ok = [r.ok for r in self._records]
        segment = self._record_maps()
        i, n = 0, len(ok)
        while i < n:
            if ok[i]:
                i += 1
                continue
            j = next((k for k in range(i, n) if ok[k]), n)  # the run is records i .. j - 1
            a, b = i - 1, j
            if a >= 0 and b < n and segment[a] == segment[b]:
                poses[i:j] = spread_correction(poses[a].expand(j - i, 4, 4), poses[b].expand(j - i, 4, 4),
                                               self._time_fractions(list(range(i, j)), a, b))
            i = j

    def _record_maps(self) -> list[int]:
        """Each record's map: the root segment (:class:`~codeslam.slam.segments.SegmentMaps`) of its keyframe's."""
        return [self.maps.root(self.keyframes[r.keyframe_id].segment) for r in self._records]

    def _time_fractions(self, inner: list[int], a: int, b: int) -> torch.Tensor:
        """The records ``inner`` placed between records ``a`` and ``b`` by time (by place without usable
        timestamps): where :meth:`_interpolated` finds no motion tracked between two keyframes, and the lost frames
        that :meth:`_bridge_lost` places."""
        t0, t1 = self._records[a].timestamp, self._records[b].timestamp
        if t1 > t0:
            f = [(self._records[i].timestamp - t0) / (t1 - t0) for i in inner]
        else:
            f = [(i - a) / (b - a) for i in inner]
        return torch.tensor(f, dtype=torch.float64)

    def keyframe_trajectory(self) -> Trajectory:
        """The keyframes' final poses."""
        if not self.keyframes:
            raise CodeSLAMError("no frame has been processed")
        return Trajectory(np.array([k.timestamp for k in self.keyframes]),
                          torch.stack([k.T_wc for k in self.keyframes]))

    def keyframe_tracking(self) -> list[tuple[int, torch.Tensor | None]]:
        """For each keyframe (in :attr:`keyframes`' order) the keyframe its frame was tracked against and the
        tracked pose in it, ``T_ref,this`` (4, 4) float64, as the tracker left it before any window solve (its
        translation in the reference's depth units, rescaled with the frame records when a map segment's first
        solve sets the scale, :meth:`_rescale`); (-1, None) for a keyframe not made from a tracked frame (a map's
        first, a new segment's). It tells the tracker's error from the window's (``scripts/keyframe_errors.py``)."""
        out = []
        for k in self.keyframes:
            pos = self._keyframe_record.get(k.id)
            rec = None if pos is None else self._records[pos]
            if rec is None or rec.tracked_id == k.id:
                out.append((-1, None))
            else:
                out.append((rec.tracked_id, rec.T_tracked.detach().to(torch.float64).cpu().clone()))
        return out

    def readout_summary(self) -> dict | None:
        """The online choice of the rolling-shutter readout and its evidence; None when it is not estimated."""
        return self._chosen if self.readout_choice is None else self.readout_choice.summary()

    @property
    def readout_restart(self) -> float | None:
        """The readout to process the frames so far again with (:meth:`restart_with_readout`), or None: the online
        choice once it is final, when a frame was rectified by another readout before and no more frames than
        ``tracker.rolling_shutter_restart`` have been processed (sequential and parallel mapping alike)."""
        choice, limit = self.readout_choice, self.config.tracker.rolling_shutter_restart
        if choice is None or not choice.final or len(self._records) > limit:
            return None
        return choice.value if self._readouts_used - {choice.value} else None

    def restart_with_readout(self, readout: float) -> None:
        """Start over with every frame rectified by ``readout`` (the online choice, now final;
        ``tracker.rolling_shutter_restart``): the mapping thread stopped and the state made anew in place, so that a
        caller's reference stays valid; the choice's evidence is kept for :meth:`readout_summary`. The caller feeds
        the frames again from the first."""
        chosen = dict(self.readout_summary(), restarted_after_frames=len(self._records))
        self.close()
        tracker = dataclasses.replace(self.config.tracker, rolling_shutter_estimate=False,
                                      rolling_shutter_readout=readout)
        period = self.frame_period
        self.__init__(dataclasses.replace(self.config, tracker=tracker), self.depth_model, camera=self.camera,
                      **self._options)
        self._chosen, self.frame_period = chosen, period

    def tracking_failures(self) -> list[int]:
        """Indices of the frames whose pose is only predicted."""
        return [r.index for r in self._records if not r.ok]
