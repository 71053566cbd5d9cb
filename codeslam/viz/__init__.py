"""Live viewers for the SLAM runner. Viewers are optional and never branch the core: :class:`Visualizer` does
nothing, and the rerun viewer (:class:`~codeslam.viz.rerun_viewer.RerunVisualizer`) imports the optional
``rerun-sdk`` package only when it is asked for."""

from codeslam.viz.base import Visualizer
from codeslam.viz.registry import VIEWERS, make_visualizer

__all__ = ["VIEWERS", "Visualizer", "make_visualizer"]
