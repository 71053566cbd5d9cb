"""The viewer interface and the viewer that shows nothing (the default)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from codeslam.errors import ConfigError

if TYPE_CHECKING:  # annotations only: the viewer layer never imports the algorithm at run time
    from codeslam.data.frame import Frame
    from codeslam.slam.system import CodeSLAM, FrameResult

#: The viewers ``--viewer`` accepts.
VIEWERS = ("none", "rerun")


class Visualizer:
    """Receives every processed frame; this base class shows nothing (kiss-icp's StubVisualizer)."""

    def update(self, frame: Frame, result: FrameResult, system: CodeSLAM) -> None:
        """Called after ``system.process(frame)`` returned ``result``."""

    def close(self) -> None:
        """Called once after the last frame."""


def make_visualizer(name: str, **kwargs) -> Visualizer:
    """The viewer called ``name`` (one of :data:`VIEWERS`); ``kwargs`` go to its constructor."""
    if name == "none":
        return Visualizer()
    if name == "rerun":
        from codeslam.viz.rerun_viewer import RerunVisualizer

        return RerunVisualizer(**kwargs)
    raise ConfigError(f"unknown viewer {name!r}; choose one of {', '.join(VIEWERS)}")
