"""The runner's clock (codeslam.clock) and the core that only names its stages on it (STYLE.md: timing is the
runner's, not the core's)."""

from __future__ import annotations

import ast
import time
from pathlib import Path

import pytest

from codeslam.clock import NO_CLOCK, StageClock

PACKAGE = Path(__file__).resolve().parents[1] / "codeslam"
#: The core that must not read a clock; the SLAM runner (slam/pipeline.py) times its own loop.
CORE = ("geometry", "data", "sfm", "slam")
RUNNERS = {"slam/pipeline.py"}


def test_a_stage_clock_sums_each_stage_until_a_split_and_starts_afresh():
    clock = StageClock()
    for _ in range(2):
        with clock("a"):
            time.sleep(0.01)
    with clock("b"):
        pass
    assert clock.count == {"a": 2, "b": 1}
    ms = clock.split()
    assert set(ms) == {"a", "b"} and 15.0 <= ms["a"] < 1000.0 and 0.0 <= ms["b"] < ms["a"]
    assert clock.split() == {} and clock.count == {}
    with clock("a"):
        pass
    assert set(clock.split()) == {"a"}


def test_a_stage_that_raises_is_timed_and_the_error_passes():
    clock = StageClock()
    with pytest.raises(ValueError), clock("fails"):
        raise ValueError("x")
    assert clock.count == {"fails": 1} and "fails" in clock.split()


def test_a_fork_keeps_its_own_stages():
    clock = StageClock("cpu")
    other = clock.fork()
    assert isinstance(other, StageClock) and other is not clock and other.device == clock.device
    with other("decode"):
        pass
    assert clock.split() == {} and set(other.split()) == {"decode"}


def test_no_clock_times_nothing():
    with NO_CLOCK("track"):
        pass
    assert NO_CLOCK.split() == {} and NO_CLOCK.fork() is NO_CLOCK


def _reads_a_clock(path: Path) -> list[str]:
    """The lines of ``path`` that import ``time`` (or from it)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(a.name == "time" for a in node.names):
            out.append(f"{path.name}:{node.lineno}")
        elif isinstance(node, ast.ImportFrom) and node.module == "time":
            out.append(f"{path.name}:{node.lineno}")
    return out


def test_the_core_never_reads_a_clock():
    found = []
    for part in CORE:
        for path in sorted((PACKAGE / part).rglob("*.py")):
            if path.relative_to(PACKAGE).as_posix() not in RUNNERS:
                found += _reads_a_clock(path)
    assert found == [], f"the core imports time (pass a codeslam.clock.Clock instead): {found}"
    assert _reads_a_clock(PACKAGE / "clock.py")  # the check sees an import where there is one
