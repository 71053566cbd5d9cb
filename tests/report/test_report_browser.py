"""The demo's report in a real browser: `codeslam demo` writes report.html, headless Chromium opens it, every figure
is drawn by plotly (SVG layers, traces), the 3D map is drawn by WebGL (coloured pixels read back from its canvas),
and a screenshot of the whole page is saved and is not blank.

Needs Chromium (`apt-get install chromium`; CI installs it). Without one the test fails, unless
CODESLAM_SKIP_BROWSER=1 says to skip it: a browser check that silently skips checks nothing.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.cli import main
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import save_weights
from codeslam.report.browser import check_page, find_chromium, screenshot

FIGURES = ["fig-trajectory", "fig-drift", "fig-status", "fig-keyframes", "fig-map"]


@pytest.fixture(scope="module")
def chromium():
    if os.environ.get("CODESLAM_SKIP_BROWSER") == "1":
        pytest.skip("CODESLAM_SKIP_BROWSER=1")
    exe = find_chromium()
    if exe is None:
        pytest.fail("no Chromium: install it (apt-get install chromium) or set CODESLAM_SKIP_BROWSER=1 to skip the "
                    "browser check")
    return exe


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """`codeslam demo` on 8 frames with a tiny random network (the report's content, not the network's quality)."""
    root = tmp_path_factory.mktemp("browser")
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
                                    full_res_channels=4, bottleneck_channels=4, fc_units=16))
    save_weights(root / "tiny.safetensors", net)
    assert main(["demo", "--out", str(root / "demo"), "--frames", "8", "--weights", str(root / "tiny.safetensors"),
                 "--threads", "1", "-q"]) == 0
    return root / "demo" / "slam"


def test_demo_report_renders_every_figure_in_chromium(chromium, demo_run, tmp_path):
    png = tmp_path / "report.png"
    check = screenshot(demo_run / "report.html", png)
    figures = check["figures"]
    assert list(figures) == FIGURES
    for fig_id, f in figures.items():
        assert f["traces"] > 0 and f["svg"] > 0 and not f["webgl_error"], (fig_id, f)
    scene = figures["fig-map"]
    assert "scene_error" not in scene, scene
    assert scene["scene_objects"] >= 2 and scene["scene_colour_pixels"] > 500, scene  # WebGL drew the map
    # the screenshot is the whole page and shows the figures (many coloured pixels, not a blank or an error page)
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape[1] == 1400 and img.shape[0] >= min(check["height"], 16_000) > 2000
    colourful = (img.max(axis=2) - img.min(axis=2)) > 60
    assert colourful.sum() > 20_000, colourful.sum()


def test_a_page_without_webgl_is_caught(chromium, demo_run, monkeypatch):
    """The check is not vacuous: with WebGL switched off the 3D map reports plotly's error and no scene."""
    from codeslam.report import browser

    monkeypatch.setattr(browser, "CHROMIUM_FLAGS", browser.CHROMIUM_FLAGS + ("--disable-webgl",))
    scene = check_page(demo_run / "report.html")["figures"]["fig-map"]
    assert scene["webgl_error"] and not scene.get("scene_colour_pixels")


def test_report_command_rebuilds_the_page_from_the_folder(demo_run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "again.html"
    assert main(["report", str(demo_run), "--out", str(out)]) == 0
    assert "report:" in capsys.readouterr().out
    page, original = out.read_text(), (demo_run / "report.html").read_text()
    for needle in ('id="fig-map"', 'id="fig-drift"', "Accuracy against ground truth"):
        assert needle in page and needle in original
    monkeypatch.setenv("CODESLAM_CHROMIUM", str(tmp_path / "no-such-browser"))
    assert main(["report", str(demo_run), "--out", str(out), "--screenshot", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("codeslam: error:") and "Chromium" in err and "\n" not in err
    assert not (tmp_path / "s.png").exists()
    assert main(["report", str(tmp_path / "nothing-here")]) == 2
    assert "not found" in capsys.readouterr().err
