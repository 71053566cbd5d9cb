"""The viewers ``--viewer`` names, each created on demand: the rerun viewer's module (and its optional library)
is imported only when it is asked for."""

from __future__ import annotations

from codeslam.errors import ConfigError
from codeslam.viz.base import Visualizer

#: The viewers ``--viewer`` accepts.
VIEWERS = ("none", "rerun")


def make_visualizer(name: str, **kwargs) -> Visualizer:
    """The viewer called ``name`` (one of :data:`VIEWERS`); ``kwargs`` go to its constructor."""
    if name == "none":
        return Visualizer()
    if name == "rerun":
        from codeslam.viz.rerun_viewer import RerunVisualizer

        return RerunVisualizer(**kwargs)
    raise ConfigError(f"unknown viewer {name!r}; choose one of {', '.join(VIEWERS)}")
