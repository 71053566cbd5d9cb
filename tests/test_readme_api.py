"""The README's Python examples run as written (on a small generator sequence instead of a TUM folder), so the API
they show cannot drift from the package."""

from __future__ import annotations

import re
from pathlib import Path

from codeslam.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_the_readme_shows_the_sfm_and_the_slam_api():
    blocks = python_blocks()
    assert len(blocks) >= 2 and "sfm(" in blocks[0] and "system.process(" in blocks[1]


def test_the_readme_api_examples_run(tmp_path, capsys):
    args = ["--scenes", "1", "--frames", "50", "--seed", "3", "--size", "64x48", "-q"]
    assert main(["synth", str(tmp_path / "seq"), *args]) == 0
    capsys.readouterr()
    data = tmp_path / "seq" / "scene_000"
    blocks = python_blocks()
    sfm_block = blocks[0].replace('"path/to/tum_sequence"', repr(str(data)))
    assert sfm_block != blocks[0], "the README's SfM example no longer opens path/to/tum_sequence"
    scope: dict = {}
    exec(compile(sfm_block, "README.md (SfM)", "exec"), scope)  # frames 40, 44, 48 of the sequence
    assert scope["result"].poses.shape == (3, 4, 4)
    exec(compile(blocks[1], "README.md (SLAM)", "exec"), scope)  # with the first block's seq and model
    out = capsys.readouterr().out.splitlines()
    assert len(scope["trajectory"].poses) == len(scope["seq"]) == 50
    assert sum(line.startswith(("0 ", "1 ", "2 ")) for line in out) >= 3  # the loop printed its frames
    assert scope["r"].timings_ms.get("track", 0.0) > 0  # the clock timed the last frame's tracking
