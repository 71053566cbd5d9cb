"""The window solve in a process of its own, for parallel mapping (issue 12; ``window.solve_process``, off by
default, see its measurements in :class:`~codeslam.slam.config.WindowConfig`).

Why. Parallel mapping runs the window solve on a thread beside the tracking (:mod:`codeslam.slam.mapping`).
torch releases the GIL inside its kernels, but both threads are mostly Python between small kernels, and the
GIL serialises that part. Measured on the 2-core machine (TUM fr1/rpy, frames 0-99, sequential, 1 thread, a
captured window solve repeated beside it): a non-keyframe's time on the tracking thread, median, 70.6 ms alone,
**124.3 ms with the solves on a thread of the same process, 95.2 ms with them in another process**; the
tracking stage alone 35.3 / 43.6 / 38.1 ms (docs/results/slam_table.md, thirty-fifth session). The solve reads
the window and returns its result (:meth:`SlidingWindow.solve`), so it can run on a copy elsewhere.

How. A child interpreter (:func:`main`, started with the parallel mapper; a fresh interpreter rather than a fork of
a process that runs OpenMP and reader threads) receives a pickled copy of the window and sends back its
:class:`~codeslam.slam.window.WindowSolution`, which the mapping thread applies. A keyframe's view (its images and
decoder, the bulk of the bytes) is sent once and kept there while the keyframe is in the window; each solve sends
the small rest (poses, codes, matches, the marginal prior). The mapping thread waits for the answer in ``poll``,
which releases the GIL. The tracker's wish to interrupt a solve (``Mapper.wait(interrupt=True)``) reaches the child
as a message that its solve checks before every iteration. The marginalisation of the window's oldest keyframe
(:meth:`SlidingWindow.marginal_prior`: a median 103 ms sequential, 209 ms parallel on TUM, bench_slam) runs there
the same way. Until the child has started (importing torch takes seconds) solves run on the mapping thread as
before; the same solve in either place gives the same values (tested).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import pickle
import subprocess
import sys
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path

from codeslam.errors import CodeSLAMError
from codeslam.sfm.variables import LinearPrior
from codeslam.slam.window import SlidingWindow, WindowReport, WindowSolution

_READY = b"ready"
_STOP = b"stop"
_CHILD = "import sys; from codeslam.slam.solve_process import main; main(sys.argv[1:])"
_POLL_S = 0.002  # how often the waiting mapping thread looks at the tracker's wish to interrupt


def _dumps(obj) -> bytes:
    # Plain pickle: tensors by value. (multiprocessing's own pickler would move every tensor into shared
    # memory and pass a file descriptor per tensor: measured 0.2-0.45 s a solve for a 4-keyframe window.)
    return pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)


class SolverProcess:
    """A child process that solves windows (module docstring). ``threads``: its torch threads."""

    @staticmethod
    def supported() -> bool:
        """Whether this platform can start one (it hands the child its pipes by descriptor: POSIX)."""
        return os.name == "posix"

    def __init__(self, threads: int = 1) -> None:
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[2])  # the folder codeslam was imported from
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD, str(to_child_r), str(from_child_w), str(int(threads))],
                pass_fds=(to_child_r, from_child_w), env=env, stdin=subprocess.DEVNULL)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
        self._tx = Connection(to_child_w, readable=False)
        self._rx = Connection(from_child_r, writable=False)
        self._ready = False
        self._sent: dict[int, object] = {}  # keyframe id -> the view object the child holds for it
        self.solves = 0  # windows solved (or marginalised) there

    @property
    def ready(self) -> bool:
        """The child has started and waits for windows (never blocks)."""
        if not self._ready and self.alive and self._rx.poll(0):
            try:
                self._ready = self._rx.recv_bytes() == _READY
            except (EOFError, OSError):
                return False
        return self._ready

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def solve(self, window: SlidingWindow, interrupted: Callable[[], bool] | None = None) -> WindowSolution:
        """``window.solve(interrupted)`` in the child (only once :attr:`ready`)."""
        return self._ask("solve", window, interrupted)

    def marginal_prior(self, window: SlidingWindow) -> LinearPrior | None:
        """``window.marginal_prior()`` in the child (only once :attr:`ready`); for ``window.remove_oldest``."""
        return self._ask("marginal", window)

    def _ask(self, what: str, window: SlidingWindow, interrupted: Callable[[], bool] | None = None):
        views = {k.id: k.view for k in window.keyframes}
        new = {i: v for i, v in views.items() if self._sent.get(i) is not v}
        lite = copy.copy(window)  # pickled below: the child gets its own copy of everything but the views
        lite.keyframes = [dataclasses.replace(k, view=None, depth=None, depth_zero=None, uncertainty=None,
                                              depth_gt=None) for k in window.keyframes]
        try:
            self._tx.send_bytes(_dumps((what, lite, new)))
            self._sent = views
            stop_sent = False
            while not self._rx.poll(_POLL_S):
                if not stop_sent and interrupted is not None and interrupted():
                    self._tx.send_bytes(_STOP)
                    stop_sent = True
                if not self.alive:
                    raise EOFError
            kind, value = pickle.loads(self._rx.recv_bytes())
        except (EOFError, OSError, BrokenPipeError) as e:
            raise CodeSLAMError(f"the window's solver process ended (exit code {self._proc.poll()})") from e
        if kind == "error":
            raise CodeSLAMError(f"window {what} in the solver process failed: {value}")
        self.solves += 1
        return value

    def optimise(self, window: SlidingWindow, interrupted: Callable[[], bool] | None = None) -> WindowReport:
        """``window.optimise(interrupted)`` with the solve in the child."""
        return window.apply(self.solve(window, interrupted))

    def close(self) -> None:
        """Stop the child (it ends by itself when the pipes close)."""
        for conn in (self._tx, self._rx):
            conn.close()
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


def _serve(rx: Connection, tx: Connection) -> None:
    """The child's loop: windows in, solutions out, until the parent closes the pipe."""
    views: dict[int, object] = {}
    tx.send_bytes(_READY)
    while True:
        try:
            msg = rx.recv_bytes()
        except EOFError:
            return
        if msg == _STOP:  # a wish to interrupt that came after its solve had ended
            continue
        what, window, new = pickle.loads(msg)
        views = {k.id: new[k.id] if k.id in new else views[k.id] for k in window.keyframes}
        for k in window.keyframes:
            k.view = views[k.id]
        try:
            result = ("ok", window.solve(lambda: rx.poll(0)) if what == "solve" else window.marginal_prior())
        except Exception:  # reported to the mapping thread, which raises it
            result = ("error", traceback.format_exc(limit=3).strip().splitlines()[-1])
        tx.send_bytes(_dumps(result))


def main(argv: list[str]) -> None:
    """The child's entry: ``argv`` = the descriptors of its two pipes (in, out) and its torch threads."""
    import torch

    rx_fd, tx_fd, threads = (int(a) for a in argv)
    torch.set_num_threads(threads)
    _serve(Connection(rx_fd, writable=False), Connection(tx_fd, readable=False))
