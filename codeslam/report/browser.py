"""Looking at a report in a real browser: a headless Chromium (or Chrome) renders the page, so a screenshot shows
what a reader sees, and a check run in the page says which figures plotly drew (and whether WebGL drew the 3D
view). Used by ``codeslam report --screenshot`` and by the test suite; needs a Chromium on the machine
(``apt-get install chromium``), found on PATH or named by ``$CODESLAM_CHROMIUM``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from codeslam.errors import CodeSLAMError
from codeslam.io import atomic_path

#: Executables tried, in order, when ``$CODESLAM_CHROMIUM`` is not set.
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: Headless flags that work as root in a container without a GPU: software WebGL (SwiftShader) for plotly's 3D
#: view, no sandbox (root), nothing fetched from the network.
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--hide-scrollbars", "--mute-audio",
)
#: Virtual time (ms) the page gets to load and draw before Chromium dumps or photographs it.
RENDER_BUDGET_MS = 30_000
BROWSER_TIMEOUT_S = 120
PAGE_WIDTH = 1400
MAX_PAGE_HEIGHT = 16_000

#: Run in the page after load: for every plotly figure, how many traces and SVG layers it has, and for a 3D scene
#: how many coloured pixels its WebGL drawing buffer holds (redrawn and read back); the page's height. Written as
#: JSON into <pre id="codeslam-check">.
_CHECK_JS = r"""
<script>
(() => {
  // Synchronous on purpose: Chromium dumps the page when its virtual-time budget ends, and asynchronous work
  // (image decoding, GPU read-backs through promises) may not have finished by then on a loaded machine.
  const colourful = (s) => {
    const gl = s.glplot.gl;
    s.glplot.redraw();  // draw now, then read the drawing buffer back before it is presented
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight, d = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, d);
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i + 3] > 0 && Math.max(d[i], d[i + 1], d[i + 2]) - Math.min(d[i], d[i + 1], d[i + 2]) > 60) n++;
    }
    return n;
  };
  const check = (attempt) => {
    const plots = [...document.querySelectorAll(".js-plotly-plot")];
    if (plots.some((gd) => !gd._fullLayout) && attempt < 50) {  // not drawn yet: look again shortly
      setTimeout(() => check(attempt + 1), 100);
      return;
    }
    const out = {figures: {}, height: document.documentElement.scrollHeight, attempts: attempt + 1};
    for (const gd of plots) {
      const r = {traces: (gd.data || []).length, svg: gd.querySelectorAll(".main-svg").length,
                 canvases: gd.querySelectorAll("canvas").length,
                 webgl_error: /WebGL is not supported/.test(gd.innerText)};
      const fl = gd._fullLayout || {};
      if (fl.scene) {
        try {
          const s = fl.scene._scene;
          r.scene_objects = s && s.glplot ? s.glplot.objects.length : 0;
          r.scene_colour_pixels = s && s.glplot ? colourful(s) : 0;
        } catch (e) { r.scene_error = String(e); }
      }
      out.figures[gd.id] = r;
    }
    const pre = document.createElement("pre"); pre.id = "codeslam-check"; pre.textContent = JSON.stringify(out);
    document.body.appendChild(pre);
  };
  window.addEventListener("load", () => check(0));
})();
</script>
"""


def find_chromium() -> str | None:
    """The Chromium executable: ``$CODESLAM_CHROMIUM`` when set, else the first of :data:`CHROMIUM_NAMES` on PATH."""
    env = os.environ.get("CODESLAM_CHROMIUM")
    if env:
        return env if Path(env).is_file() else shutil.which(env)
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


def _run_chromium(args: list[str], url: str) -> str:
    exe = find_chromium()
    if exe is None:
        raise CodeSLAMError("no Chromium found (install it, e.g. 'apt-get install chromium', or name it with "
                            "$CODESLAM_CHROMIUM)")
    with tempfile.TemporaryDirectory(prefix="codeslam-chromium-") as profile:
        cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--virtual-time-budget={RENDER_BUDGET_MS}",
               *args, url]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise CodeSLAMError(f"Chromium did not finish rendering {url} within {BROWSER_TIMEOUT_S} s") from None
        except OSError as e:
            raise CodeSLAMError(f"cannot run {exe}: {e.strerror or e}") from None
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise CodeSLAMError(f"Chromium failed on {url} (exit {proc.returncode}): {last}")
    return proc.stdout


def check_page(html_path: str | Path) -> dict:
    """Render ``html_path`` in headless Chromium and report what plotly drew: ``{"figures": {div id: {"traces",
    "svg", "canvases", "webgl_error", and for a 3D scene "scene_objects", "scene_colour_pixels"}}, "height": page
    height in CSS pixels}``. The page is rendered from a copy with the check script appended; the file itself is
    not changed."""
    page = Path(html_path).read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory(prefix="codeslam-check-") as tmp:
        probe = Path(tmp) / "page.html"
        probe.write_text(page.replace("</body>", _CHECK_JS + "</body>", 1), encoding="utf-8")
        dom = _run_chromium(["--dump-dom"], probe.resolve().as_uri())
    m = re.search(r'<pre id="codeslam-check">(.*?)</pre>', dom, re.S)
    if m is None:
        raise CodeSLAMError(f"the page {html_path} did not finish loading in Chromium (no check result)")
    import html as _html

    return json.loads(_html.unescape(m.group(1)))


def screenshot(html_path: str | Path, png_path: str | Path, width: int = PAGE_WIDTH, height: int | None = None) -> dict:
    """Save a PNG of the whole page ``html_path`` as headless Chromium renders it (``height`` None: the page's own
    height, measured first, at most :data:`MAX_PAGE_HEIGHT`). Returns :func:`check_page`'s result."""
    check = check_page(html_path)
    h = int(height or min(max(int(check.get("height") or 0), 600), MAX_PAGE_HEIGHT))
    with atomic_path(png_path) as tmp:
        _run_chromium([f"--window-size={int(width)},{h}", f"--screenshot={tmp}"], Path(html_path).resolve().as_uri())
        if not tmp.is_file() or tmp.stat().st_size == 0:
            raise CodeSLAMError(f"Chromium wrote no screenshot of {html_path}")
    return check
