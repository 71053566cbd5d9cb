"""Viewers: the stub does nothing, an unknown viewer is a config error, a missing rerun-sdk is one clear error,
and the rerun viewer logs cameras, images, the trajectory and keyframe clouds (checked against a recording fake
of the rerun module, so the test runs without the optional package)."""

from __future__ import annotations

import dataclasses
import sys
import types

import numpy as np
import pytest
import torch

from codeslam.errors import CodeSLAMError, ConfigError
from codeslam.viz import Visualizer, make_visualizer


def test_stub_visualizer_does_nothing():
    viz = make_visualizer("none")
    assert type(viz) is Visualizer
    assert viz.update(None, None, None) is None and viz.close() is None


def test_unknown_viewer_is_a_config_error():
    with pytest.raises(ConfigError, match="unknown viewer"):
        make_visualizer("opengl")


def test_missing_rerun_is_one_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # makes `import rerun` raise ImportError
    with pytest.raises(CodeSLAMError, match="rerun-sdk"):
        make_visualizer("rerun")


class _Archetype:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _fake_rerun():
    calls = []
    rr = types.ModuleType("rerun")
    rr.calls = calls
    rr.init = lambda app_id, spawn=False: calls.append(("init", app_id, spawn))
    rr.save = lambda path: calls.append(("save", path))
    rr.log = lambda path, item, static=False: calls.append(("log", path, item))
    rr.set_time = lambda timeline, sequence: calls.append(("time", timeline, sequence))
    rr.disconnect = lambda: calls.append(("disconnect",))
    rr.ViewCoordinates = types.SimpleNamespace(RIGHT_HAND_Y_DOWN="RDF")
    for name in ("Transform3D", "Pinhole", "Image", "LineStrips3D", "TextLog", "Points3D"):
        setattr(rr, name, type(name, (_Archetype,), {}))
    return rr


def _frames(n: int = 4):
    """n frames of a generator room at 64x48 along its trajectory at 7.5 frames per second."""
    from codeslam.data.frame import Frame
    from codeslam.geometry.camera import canonical_camera
    from codeslam.synth.render import RenderConfig, render
    from codeslam.synth.scene import build_scene
    from codeslam.synth.trajectory import random_trajectory

    scene = build_scene(3)
    poses = random_trajectory(scene, 16, np.random.default_rng(np.random.SeedSequence([3, 0x7247])), fps=7.5)[:n]
    cam = canonical_camera(64, 48)
    image, depth = render(scene, cam, poses, RenderConfig(ao_samples=0, supersample=2))
    return [Frame(1000.0 + i / 7.5, image[i], cam, depth[i], poses[i], i) for i in range(n)]


def test_rerun_viewer_logs_the_run(monkeypatch):
    from codeslam.slam.config import SLAMConfig, overlay_config
    from codeslam.slam.depth import standin_depth_model
    from codeslam.slam.system import CodeSLAM

    rr = _fake_rerun()
    monkeypatch.setitem(sys.modules, "rerun", rr)
    viz = make_visualizer("rerun", spawn=False)
    frames = _frames()
    cfg = overlay_config(SLAMConfig(), {"tracker": {"pyramid_levels": [2, 1, 0], "max_iterations": [8, 6, 5]},
                                        "window": {"sfm": {"pyramid_levels": [2, 1, 0], "max_iterations": [6, 5, 4]}}})
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3))
    for f in frames:
        viz.update(f, system.process(f), system)
    viz.close()
    logs = [(c[1], c[2]) for c in rr.calls if c[0] == "log"]
    paths = [p for p, _ in logs]
    assert rr.calls[0] == ("init", "codeslam", False) and rr.calls[-1] == ("disconnect",)
    assert [c[2] for c in rr.calls if c[0] == "time"] == [0, 1, 2, 3]
    assert paths.count("world/camera/image") >= 8  # a pinhole and an image per frame
    images = [item for p, item in logs if type(item).__name__ == "Image"]
    assert len(images) == 4 and images[0].args[0].shape == (48, 64, 3) and images[0].args[0].dtype == np.uint8
    strips = [item for p, item in logs if p == "world/trajectory"]
    assert strips[-1].args[0][0].shape == (4, 3)
    clouds = [item for p, item in logs if p.endswith("/points")]
    assert clouds and all(np.isfinite(c.args[0]).all() and c.args[0].shape[1] == 3 for c in clouds)
    assert clouds[0].kwargs["colors"].shape == clouds[0].args[0].shape
    cam = [item for p, item in logs if p == "world/camera" and type(item).__name__ == "Transform3D"][-1]
    # the viewer shows the live pose: the written trajectory before its smoothing spline
    system.config = dataclasses.replace(system.config, trajectory_smoothing=0.0)
    np.testing.assert_allclose(cam.kwargs["translation"], system.trajectory().poses[-1][:3, 3].numpy(), atol=1e-9)
    assert torch.is_tensor(system.keyframes[0].T_wc)
