"""Reading a trajectory file whatever its format (TUM text or EuRoC CSV)."""

from __future__ import annotations

from pathlib import Path

from codeslam.data.euroc_csv import read_euroc_csv
from codeslam.data.trajectory import Trajectory, read_tum
from codeslam.errors import DatasetError

FORMATS = ("tum", "euroc")


def detect_format(path: str | Path) -> str:
    """Tell a TUM file from an EuRoC CSV by its first pose line.

    EuRoC: comma-separated, the first field an integer (nanoseconds). TUM: 8 fields separated by spaces
    (or commas) with the timestamp in seconds. Anything else raises :class:`DatasetError`.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"trajectory file not found: {path}")
    try:
        with open(path) as f:
            for lineno, raw in enumerate(f, 1):
                line = raw.strip()
                if not line or line.startswith("#"):
                    continue
                if "," in line and line.split(",", 1)[0].strip().isdigit():
                    return "euroc"
                if len(line.replace(",", " ").split()) == 8:
                    return "tum"
                raise DatasetError(
                    f"{path}:{lineno}: cannot tell the trajectory format (neither 'timestamp tx ty tz qx qy qz qw' "
                    f"nor 'timestamp[ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z')"
                )
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"cannot read trajectory file {path}: {e}") from None
    raise DatasetError(f"trajectory file {path} holds no poses")


def load_trajectory(path: str | Path, format: str | None = None) -> Trajectory:
    """Read a trajectory file: ``format`` is ``'tum'``, ``'euroc'`` or None to detect it from the content."""
    if format is None:
        format = detect_format(path)
    if format == "tum":
        return read_tum(path)
    if format == "euroc":
        return read_euroc_csv(path)
    raise DatasetError(f"unknown trajectory format {format!r}; expected one of {', '.join(FORMATS)}")
