"""Mapping (paper Sec. 4.3): a new keyframe is decoded, the oldest keyframe marginalised when the window is full,
and the window's codes and poses optimised jointly. "Inspired by PTAM", it runs either inline after the
tracking of the frame that asked for it (``parallel=False``, deterministic: tests and debugging) or on a thread
of its own beside the tracking (``parallel=True``), so that tracking never waits for a window optimisation:
torch releases the GIL inside its kernels, and the two threads share the map as follows.

* The mapping thread owns the window: only it changes keyframes' poses, codes and 3D points, and it replaces
  those attributes (never mutates them in place), so a tracking thread reading ``ref.T_wc`` or ``ref.code``
  sees one solve's values or the next one's, never a torn tensor.
* The two threads split the CPU: torch's thread count is per calling thread, so the mapping thread sets its own
  (``threads``) and the tracker keeps the rest (:class:`~codeslam.slam.system.CodeSLAM`). Each thread with its
  own torch threads on its own cores, rather than two OpenMP teams of the full size on the same cores: measured
  on the 2-core machine, a team's workers waiting for the next region cost the tracking thread 4x (TUM fr1/rpy,
  tracking median 68 ms against 13 ms when the workers do not wait actively). The one exception is a
  keyframe's decoding (``decode_threads``, all of the cores by default), which the tracker mostly waits for: on
  the HoloLens walk, parallel, 2 threads, the tracker spent 10 of 30 s waiting for decodings, and decoding with
  both threads took the whole run 0.90x the time (farm-bench, 4 pairs; TUM fr1/rpy 1.01x, accuracy unchanged).
* A keyframe is asked for by :meth:`Mapper.insert`; in parallel mode it is refused while the mapping thread is
  still busy with the previous one (the tracker asks again on a later frame), as PTAM's tracker does.
* What the mapping thread finished (:class:`MappingResult`) is collected by the tracking thread with
  :meth:`Mapper.collect`, which is where the tracker switches to the new keyframe; the tracking thread is the only
  writer of the frame records.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch

from codeslam.clock import NO_CLOCK, Clock
from codeslam.geometry.lie import se3_inverse
from codeslam.geometry.splat import splat_depth
from codeslam.slam.config import SLAMConfig
from codeslam.slam.frontend import SparseTrack, SparseTracker
from codeslam.slam.map_prior import map_prior
from codeslam.slam.solve_process import SolverProcess
from codeslam.slam.window import MapKeyframe, SlidingWindow, WindowReport, WindowSnapshot


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """torch's intra-op threads of the calling thread set to ``n`` inside the block (None: unchanged)."""
    if n is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@dataclass
class MappingJob:
    """A keyframe to add: ``decode()`` makes it (the network's forward pass and code Jacobian); ``ref`` and
    ``sparse`` are the keyframe it was tracked against and the tracking's matches (reused as the pair's matched
    keypoints); ``frame_position`` is the frame's place among the tracker's records."""

    decode: Callable[[], MapKeyframe]
    ref: MapKeyframe | None
    sparse: SparseTrack | None
    frame_position: int


@dataclass
class MappingResult:
    """What one mapping step did: the new keyframe, the window solve, the keyframe marginalised (if any), the
    window state before the solve (for a later rollback) and wall time per stage in ms (what the mapper's clock
    timed: decode, marginalise, window; empty without a clock). In parallel mode the
    keyframe is handed over twice: as soon as it is decoded (``report`` None: the tracker can track against it
    while the window is optimised) and again when the solve is done."""

    keyframe: MapKeyframe
    report: WindowReport | None
    marginalised: int | None
    frame_position: int
    before: WindowSnapshot | None = None
    ms: dict[str, float] = field(default_factory=dict)


class Mapper:
    """The window and the steps that change it; inline or on a background thread (module docstring).

    config: the system's settings; sparse: the feature tracker (None without features), for matching keyframes;
    threads: torch threads of the mapping thread (parallel mode; None: torch's default for a new thread);
    decode_threads: its torch threads while it decodes a keyframe (None: ``threads``). The tracker waits for a
    keyframe's decoding whenever it cannot go on without it, so more threads than ``threads`` use the cores it
    leaves idle then; the window solve, which the tracker does not wait for, keeps ``threads``.
    clock: times each step's stages (decode, marginalise, window) on the thread that runs the steps
    (:mod:`codeslam.clock`; a clock of its own, not the tracker's).
    """

    def __init__(self, config: SLAMConfig, sparse: SparseTracker | None = None, parallel: bool = False,
                 threads: int | None = None, decode_threads: int | None = None, clock: Clock = NO_CLOCK) -> None:
        self.config = config
        self.clock = clock
        self.threads = threads
        self.decode_threads = decode_threads
        self.window = SlidingWindow(config.window)
        self.sparse = sparse
        self.parallel = parallel
        self._jobs: queue.Queue[MappingJob | None] = queue.Queue()
        self._done: queue.Queue[MappingResult | BaseException] = queue.Queue()
        self._busy = threading.Event()
        self._decoded = threading.Event()  # the keyframe of the running job is handed over (its solve may run)
        self._decoded.set()
        self._stop_solve = threading.Event()  # set by the tracker that needs the thread: end the solve early
        self._thread: threading.Thread | None = None
        self._solver: SolverProcess | None = None  # window.solve_process: the child that solves windows
        in_process = config.window.solve_process and torch.device(config.device).type == "cpu"
        if parallel and in_process and SolverProcess.supported():
            self._solver = SolverProcess(threads or 1)  # starts now, beside the first frames; used once ready
        self.updates = 0  # window solves finished

    # ---- asking for keyframes -----------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        return self._busy.is_set()

    @property
    def decoding(self) -> bool:
        """The keyframe asked for last is still being decoded (parallel mode): not yet handed to the tracker."""
        return self._thread is not None and not self._decoded.is_set()

    def insert(self, job: MappingJob) -> MappingResult | None:
        """Add a keyframe. Inline: do it now and return the result. Parallel: hand it to the mapping thread and
        return None (collect the result later); refused (returns None and sets ``job`` aside) while busy —
        check :attr:`busy` first."""
        if not self.parallel:
            return self._step(job)
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="codeslam-mapping", daemon=True)
            self._thread.start()
        self._busy.set()
        self._decoded.clear()
        self._jobs.put(job)
        return None

    def collect(self) -> list[MappingResult]:
        """The mapping steps finished since the last call (parallel mode); re-raises an error of the thread."""
        out = []
        while True:
            try:
                item = self._done.get_nowait()
            except queue.Empty:
                return out
            if isinstance(item, BaseException):
                raise item
            out.append(item)

    def wait(self, interrupt: bool = False) -> list[MappingResult]:
        """Block until the mapping thread is idle; returns what it finished (see :meth:`collect`). With
        ``interrupt`` (and ``window.interruptible``) a running window solve ends after its current iteration;
        while the keyframe asked for last is still being decoded, only that is waited for instead (the tracker
        needs the keyframe, not the end of its solve: stopping the solve before it starts left most keyframes of
        a parallel HoloLens run unoptimised, 54 of 60 solves interrupted)."""
        if self._thread is not None:
            if interrupt and not self._decoded.is_set():
                self._decoded.wait()
            else:
                if interrupt and self.config.window.interruptible:
                    self._stop_solve.set()
                self._jobs.join()
                self._stop_solve.clear()
        return self.collect()

    def close(self) -> None:
        """Finish the queued work and stop the thread."""
        if self._thread is not None:
            self._jobs.join()
            self._jobs.put(None)
            self._thread.join()
            self._thread = None
        if self._solver is not None:
            self._solver.close()
            self._solver = None

    def _loop(self) -> None:
        if self.threads is not None:  # this thread's own OpenMP team (the tracker keeps its count)
            torch.get_num_threads()  # first touch: torch gives a new thread the last count set by any thread...
            torch.set_num_threads(self.threads)  # ...so set ours after it, or the tracker's would replace it
        while True:
            job = self._jobs.get()
            if job is None:
                self._jobs.task_done()
                return
            try:
                self._done.put(self._step(job))
            except BaseException as e:  # handed to the tracking thread, which re-raises it
                self._done.put(e)
            finally:
                self._decoded.set()  # also when the step failed before handing the keyframe over
                self._busy.clear()
                self._jobs.task_done()

    # ---- one mapping step (Sec. 4.3) ----------------------------------------------------------------------
    def _step(self, job: MappingJob) -> MappingResult:
        """Decode the keyframe, marginalise the oldest one if the window is full, add the new one (code zero,
        tracked pose), match its keypoints with the window's, optimise the window jointly and roll the solve back
        if it fails the window's checks. Marginalising before the solve keeps every solve at K keyframes (the
        paper's "4-keyframes setup") and linearises the prior at the previous window's optimum."""
        with torch_threads(self.decode_threads if self.parallel else None), self.clock("decode"):
            kf = self._prior_from_map(job.decode())
        if self.parallel:  # the tracker may switch to the keyframe now, before the window solve
            self._done.put(MappingResult(kf, None, None, job.frame_position, None, self.clock.split()))
            self._decoded.set()
        marginalised = None
        with self.clock("marginalise"):
            if self.window.is_full:  # the oldest keyframe becomes a linear prior on the others
                marginalised = self.window.remove_oldest(self._marginal()).id
        self.window.add(kf)
        self._match(kf, job.ref, job.sparse)
        before = self.window.snapshot()
        depth_before = {k.id: k.median_depth() for k in self.window.keyframes}
        with self.clock("window"):
            report = self._optimise()  # codes and poses: photometric, geometric, keypoints
            if self.config.window.rollback:
                # The new keyframe's depth before its first solve is the network's single view, not a map estimate:
                # that solve may rightly rescale it by any factor (the map's scale and the view's can differ 3x).
                report.rejected = self.window.check(before, {i: d for i, d in depth_before.items() if i != kf.id})
                if report.rejected:
                    self.window.restore(before)
            self.refresh_points()
            if len(self.window.keyframes) == 2 and not report.rejected:  # a map segment's first solve sets its scale
                report.depth_scale = {k.id: k.median_depth() / depth_before[k.id] for k in self.window.keyframes}
        self.updates += 1
        return MappingResult(kf, report, marginalised, job.frame_position,
                             before if self.config.window.rollback and not report.rejected else None,
                             self.clock.split())  # parallel: the decoding's time went with the keyframe

    def _ready_solver(self) -> SolverProcess | None:
        """The solver process once it has started (``window.solve_process``), else None: work here."""
        return self._solver if self._solver is not None and self._solver.ready else None

    def _marginal(self):
        """What computes the marginal prior: the solver process's method, or None (here)."""
        solver = self._ready_solver()
        return None if solver is None else solver.marginal_prior

    def _optimise(self) -> WindowReport:
        """The window solve, in the solver process or here."""
        solver = self._ready_solver()
        if solver is not None:
            return solver.optimise(self.window, self._stop_solve.is_set)
        return self.window.optimise(self._stop_solve.is_set)

    def _prior_from_map(self, kf: MapKeyframe) -> MapKeyframe:
        """The new keyframe with its zero-code depth moved toward the map's (``window.map_prior_weight``,
        :mod:`codeslam.slam.map_prior`): the window's newest keyframe of the same map segment, at its current code,
        splatted into the new view; its keypoints' 3D points follow. Unchanged before the segment's second keyframe
        or where the map covers too little of the view."""
        cfg = self.config.window
        src = self.window.keyframes[-1] if self.window.keyframes else None
        if cfg.map_prior_weight <= 0 or src is None or src.segment != kf.segment or not src.active:
            return kf
        depth = splat_depth(src.depth_map(0), src.view.camera, se3_inverse(kf.T_wc) @ src.T_wc, src.view.valid)
        decoder = map_prior(kf.view.decoder, depth, cfg.map_prior_weight, cfg.map_prior_blur, kf.view.valid,
                            cfg.map_prior_span)
        if decoder is kf.view.decoder:
            return kf
        kf = dataclasses.replace(kf, view=dataclasses.replace(kf.view, decoder=decoder))
        self._refresh_points(kf)  # its features object is the network keyframe's, which nothing else holds
        return kf

    def _match(self, kf: MapKeyframe, ref: MapKeyframe | None, sparse: SparseTrack | None) -> None:
        """Matched keypoints between the new keyframe and the window's others, for the window's reprojection
        residuals: the tracking's inliers against its reference, guided matching at the current poses for the
        rest."""
        if kf.sparse is None or self.sparse is None:
            return
        for other in self.window.keyframes[:-1]:
            if other.sparse is None:
                continue
            if ref is not None and other.id == ref.id and sparse is not None and sparse.ok:
                ia, ib = sparse.point, sparse.frame_kp
            else:
                ia, ib = self.sparse.match_keyframes(other.sparse, kf.sparse.features,
                                                     se3_inverse(kf.T_wc) @ other.T_wc)
            if len(ia) >= self.config.features.min_inliers // 2:
                self.window.matches[(other.id, kf.id)] = (ia, ib)

    def refresh_points(self) -> None:
        """The window's keyframe points follow their codes after a solve."""
        for k in self.window.keyframes:
            self._refresh_points(k)

    def _refresh_points(self, k: MapKeyframe) -> None:
        """``k``'s keypoints' 3D points at its current depth (a new array, not an in-place edit)."""
        if k.sparse is not None and self.sparse is not None:
            k.sparse.xyz = self.sparse.points(k.sparse.features, k.depth_map())

    # ---- map maintenance from the tracking thread ----------------------------------------------------------
    def roll_back(self, before: WindowSnapshot) -> None:
        """Undo the last solve (sequential mode: the next frame could not be tracked after it)."""
        self.window.restore(before)
        self.refresh_points()

    def restart(self, kf: MapKeyframe) -> None:
        """Empty the window and make ``kf`` its first keyframe, the new gauge: a new map segment, or a
        relocalisation against a keyframe that has left the window. The caller waits for the mapping thread
        first (:meth:`wait`) and applies what it finished."""
        self.window.reset()
        self.window.add(kf)

    def move(self, G: torch.Tensor) -> None:
        """Move the window's map rigidly (``T_wc <- G T_wc``): a map segment merged into an older map. The caller
        waits for the mapping thread first (:meth:`wait`) and applies what it finished."""
        self.window.move(G)

    def start(self, kf: MapKeyframe) -> None:
        """The map's first keyframe."""
        self.window.add(kf)

