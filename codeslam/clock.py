"""Stage timing belongs to the runner, not to the core.

The core (tracking, mapping, the solvers) never reads a clock itself: it names its stages, ``with clock("track"):``,
on a :class:`Clock` that the runner passes in (kiss-icp times its pipeline around ``register_frame`` the same way).
The default, :data:`NO_CLOCK`, does nothing, so the maths runs free of timing; a runner that wants the times
(``codeslam slam``, ``codeslam sfm``, the benchmarks) passes a :class:`StageClock`.

A clock belongs to one thread. A part of the core that runs on a thread of its own (the SLAM mapping thread) takes
``clock.fork()``, a clock of the same kind, and measures itself on it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from typing import Protocol

import torch


class Clock(Protocol):
    """What the core asks of a clock."""

    def __call__(self, stage: str) -> AbstractContextManager[None]:
        """A context that times the block as ``stage`` (times of one stage add up)."""

    def split(self) -> dict[str, float]:
        """The ms per stage timed since the last split (or since the clock was made), and start afresh."""

    def fork(self) -> Clock:
        """A clock of the same kind, for another thread."""


class _NoClock:
    """Times nothing: the core's default."""

    def __call__(self, stage: str) -> AbstractContextManager[None]:
        return nullcontext()

    def split(self) -> dict[str, float]:
        return {}

    def fork(self) -> _NoClock:
        return self


#: The clock that times nothing.
NO_CLOCK: Clock = _NoClock()


class StageClock:
    """Wall time per named stage in ms, summed over the stage's blocks since the last :meth:`split`, and how many
    blocks each stage had (``count``, also since the last split). On a CUDA ``device`` each block is synchronised
    at both ends, so its time is the kernels', not their launch."""

    def __init__(self, device: torch.device | str | None = None) -> None:
        self.device = torch.device(device if device is not None else "cpu")
        self.ms: dict[str, float] = {}
        self.count: dict[str, int] = {}

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        self._sync()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._sync()
            self.ms[stage] = self.ms.get(stage, 0.0) + 1e3 * (time.perf_counter() - t0)
            self.count[stage] = self.count.get(stage, 0) + 1

    def split(self) -> dict[str, float]:
        ms, self.ms, self.count = self.ms, {}, {}
        return ms

    def fork(self) -> StageClock:
        return StageClock(self.device)
