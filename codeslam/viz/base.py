"""The viewer interface and the viewer that shows nothing (the default).

The SLAM runner calls it, so it sits below the SLAM package and imports nothing of it: ``result`` and ``system``
are whatever the runner passes (a :class:`~codeslam.slam.system.FrameResult` and the
:class:`~codeslam.slam.system.CodeSLAM` that produced it).
"""

from __future__ import annotations

from typing import Any

from codeslam.data.frame import Frame


class Visualizer:
    """Receives every processed frame; this base class shows nothing (kiss-icp's StubVisualizer)."""

    def update(self, frame: Frame, result: Any, system: Any) -> None:
        """Called after ``system.process(frame)`` returned ``result``."""

    def close(self) -> None:
        """Called once after the last frame."""
