"""Line-oriented text files (TUM lists and trajectories, EuRoC CSVs, TartanAir pose files, calibration files):
one reader of the lines and the checks every format repeats, so each error names ``file:line`` the same way."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from pathlib import Path

from codeslam.errors import DatasetError


def read_text(path: Path, what: str = "") -> str:
    """The file's text, or DatasetError naming it (``what`` e.g. 'trajectory file ')."""
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"cannot read {what}{path}: {e}") from None


def data_lines(path: Path, what: str = "") -> Iterator[tuple[str, str]]:
    """Yield ``(where, line)`` for every line that is neither blank nor a ``#`` comment, stripped, with
    ``where = 'path:lineno'`` for error messages."""
    for lineno, line in enumerate(read_text(path, what).splitlines(), 1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield f"{path}:{lineno}", line


def finite_floats(parts: Sequence[str], where: str, line: str) -> list[float]:
    """``parts`` as finite floats, or DatasetError naming ``where`` and quoting ``line``."""
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise DatasetError(f"{where}: not a number in {line!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise DatasetError(f"{where}: non-finite value in {line!r}")
    return vals


def check_quaternion(q: Sequence[float], where: str) -> None:
    """DatasetError when the quaternion (any component order) is (numerically) zero: it encodes no rotation."""
    if math.sqrt(sum(v * v for v in q)) < 1e-6:
        raise DatasetError(f"{where}: zero quaternion")


def check_increasing(previous: list, value, where: str, text: str) -> None:
    """DatasetError when ``value`` is not after the last of ``previous`` (timestamps must strictly increase)."""
    if previous and value <= previous[-1]:
        raise DatasetError(f"{where}: timestamp {text} is not after the previous one")
