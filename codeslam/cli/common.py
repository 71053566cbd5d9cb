"""What the commands share, defined once: the ``--frames`` grammar, opening a dataset, the device check, the thread
setting, the progress bar and the typer options (kiss-icp keeps them in one place too, ``tools/cmd.py``).

Options are ``Annotated`` aliases: a command declares ``frames: Frames = None`` and gets the same flag, help and
parsing as every other command. Heavy imports (torch, rich.progress, the readers) happen inside the functions, so
importing this module keeps ``codeslam --help`` fast.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer

from codeslam.errors import ConfigError, DatasetError

# ---- typer options --------------------------------------------------------------------------------------------
FRAMES_HELP = ("Frames: START:END[:STEP] (END excluded, either bound may be empty), a comma list such as 40,44,48, "
               "or one index; parts may be mixed (0:10,20).")

DatasetArg = Annotated[Path, typer.Argument(
    help="Dataset folder (TUM, EuRoC, SceneNet, TartanAir or image folder) or video file (.mp4, .mov, ...); "
    "`codeslam info` shows what it holds.")]
Format = Annotated[str | None, typer.Option(
    "--format", "-f", help="Dataset format (tum, euroc, scenenet, tartanair, folder, video); detected when omitted.")]
Weights = Annotated[Path | None, typer.Option(
    "--weights", help="Network weights (safetensors); the shipped weights when omitted.")]
Frames = Annotated[str | None, typer.Option("--frames", help=FRAMES_HELP)]
Device = Annotated[str | None, typer.Option(
    "--device", help="cpu, cuda or cuda:N (default: cpu, or the configuration's device).")]
Threads = Annotated[int | None, typer.Option(
    "--threads", help="torch CPU threads (default: torch's choice; 1 is fastest on a busy machine).")]
OutDir = Annotated[Path | None, typer.Option("--out", help="Output folder (the command's description lists what "
                                                            "it writes there).")]
JsonOut = Annotated[Path | None, typer.Option("--json", help="Also write the results as JSON to this file.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


# ---- frames ---------------------------------------------------------------------------------------------------
def _frames_error(spec: str) -> ConfigError:
    return ConfigError(f"--frames must look like START:END[:STEP], a comma list such as 40,44,48, or one index, "
                       f"got {spec!r}")


def _parse_part(part: str, spec: str, num_frames: int) -> list[int]:
    """One comma-separated part: ``I`` or ``START:END[:STEP]`` (empty START = 0, empty END = the end)."""
    fields = part.split(":")
    if len(fields) > 3:
        raise _frames_error(spec)
    try:
        vals = [int(f) if f.strip() else None for f in fields]
    except ValueError:
        raise _frames_error(spec) from None
    if len(vals) == 1:
        if vals[0] is None:
            raise _frames_error(spec)
        start, end, step = vals[0], vals[0] + 1, 1
    else:
        start = 0 if vals[0] is None else vals[0]
        end = num_frames if vals[1] is None else vals[1]
        step = 1 if len(vals) < 3 or vals[2] is None else vals[2]
    if start < 0 or end < 0 or step < 1:
        raise ConfigError(f"--frames {spec!r}: frame indices must be >= 0 and the step >= 1")
    if start >= num_frames or end > num_frames:
        last = max(start, end - 1)
        raise ConfigError(f"--frames {spec!r} reaches frame {last}, outside the sequence's {num_frames} frames "
                          f"(0..{num_frames - 1})")
    if start >= end:
        raise ConfigError(f"--frames {spec!r}: {part!r} selects no frame")
    return list(range(start, end, step))


def parse_frames(spec: str | None, num_frames: int, min_frames: int = 1, what: str = "this command",
                 increasing: bool = False) -> list[int]:
    """``--frames`` -> dataset frame indices, in the order given; None selects every frame.

    The grammar, the same for every command: comma-separated parts, each one index ``I`` or a range
    ``START:END[:STEP]`` (Python's range: END excluded, empty START = 0, empty END = the end of the sequence, no
    negative indices). ConfigError (one line) for malformed text, an index outside the sequence, a frame listed
    twice, fewer than ``min_frames`` frames (``what`` names who needs them), and with ``increasing`` frames out
    of time order.
    """
    if spec is None:
        if num_frames < min_frames:
            raise ConfigError(f"{what} needs at least {min_frames} frames; the sequence has {num_frames}")
        return list(range(num_frames))
    parts = [p.strip() for p in spec.split(",")]
    if not any(parts):
        raise _frames_error(spec)
    out = [i for part in parts if part for i in _parse_part(part, spec, num_frames)]
    seen: set[int] = set()
    for i in out:
        if i in seen:
            raise ConfigError(f"--frames {spec!r} lists frame {i} twice")
        seen.add(i)
    if len(out) < min_frames:
        raise ConfigError(f"--frames {spec!r} selects {len(out)} frame(s); {what} needs at least {min_frames} frames")
    if increasing and any(b < a for a, b in zip(out, out[1:])):
        raise ConfigError(f"--frames {spec!r}: {what} runs forward in time, so the frames must increase")
    return out


# ---- image size -----------------------------------------------------------------------------------------------
def parse_size(size: str, limits: tuple[int, int] | None = (8, 4096)) -> tuple[int, int]:
    """``--size WIDTHxHEIGHT`` -> (width, height), each within ``limits`` (None: the caller's configuration checks
    the values); ConfigError otherwise."""
    try:
        w, h = (int(p) for p in size.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size must look like WIDTHxHEIGHT (e.g. 128x96), got {size!r}") from None
    if limits is not None and not (limits[0] <= min(w, h) and max(w, h) <= limits[1]):
        lo, hi = limits
        raise ConfigError(f"--size must be between {lo}x{lo} and {hi}x{hi}, got {size!r}")
    return w, h


# ---- datasets -------------------------------------------------------------------------------------------------
@contextmanager
def reader_warnings() -> Iterator[None]:
    """Every warning raised inside the block (a skipped frame, invalid depth values, a default camera), repeated
    ones included, becomes one ``codeslam: warning:`` line on stderr when the block ends."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        print(f"codeslam: warning: {' '.join(str(w.message).split())}", file=sys.stderr)


def open_frames(dataset: Path, fmt: str | None, frames: str | None, min_frames: int = 1,
                what: str = "this command", increasing: bool = False, options: dict | None = None):
    """Open a dataset folder or video (format detected when ``fmt`` is None; ``options`` go to the reader; reader
    warnings as one line each) and parse ``frames`` against its length (:func:`parse_frames`) -> (sequence, frame
    indices)."""
    from codeslam.data.registry import open_dataset

    with reader_warnings():
        seq = open_dataset(dataset, format=fmt, **(options or {}))
    if len(seq) == 0:
        raise DatasetError(f"{dataset} holds no frames")
    return seq, parse_frames(frames, len(seq), min_frames, what, increasing)


# ---- device and threads ---------------------------------------------------------------------------------------
def check_device(device: str | None, default: str = "cpu") -> str:
    """``--device`` (``default`` when None) -> the same string, or ConfigError when torch cannot use it here."""
    import torch

    device = default if device is None else device
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise ConfigError(f"--device must look like cpu, cuda or cuda:N, got {device!r}") from None
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"--device must be cpu or cuda[:N], got {device!r}")
    if dev.type == "cuda" and (not torch.cuda.is_available() or (dev.index or 0) >= torch.cuda.device_count()):
        raise ConfigError(f"--device {device}: no such CUDA device on this machine")
    return device


def keep_freed_memory() -> None:
    """Ask glibc's allocator (Linux) to keep freed memory for reuse rather than hand it back to the system at once:
    large blocks from the heap instead of fresh ``mmap`` pages (threshold 32 MB), no trimming of the heap's top
    below 1 GB, and the heap grown 256 MB at a time. A process-wide setting, so the command line's and not the
    library's; elsewhere (another C library) it does nothing.

    Written for a measured reason: a keyframe's code Jacobian and the window solve allocate and free tens of MB
    per step, and every fresh page faulted in again (``codeslam slam`` on TUM fr1/rpy, 2 threads, 4 runs each
    alternating: system time 4.7 -> 1.1 s, wall time x0.92 (0.84-1.04), peak memory 678 -> 719 MB). PyTorch's
    own advice for CPU speed is an allocator such as jemalloc, which pip cannot install."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # glibc's <malloc.h>
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    mallopt(m_mmap_threshold, 32 << 20)
    mallopt(m_trim_threshold, 1 << 30)
    mallopt(m_top_pad, 256 << 20)


def set_threads(threads: int | None) -> None:
    """Apply ``--threads`` (None keeps torch's default)."""
    if threads is None:
        return
    if threads < 1:
        raise ConfigError(f"--threads must be >= 1, got {threads}")
    import torch

    torch.set_num_threads(threads)


# ---- progress -------------------------------------------------------------------------------------------------
@contextmanager
def progress_bar(label: str, total: int, quiet: bool = False) -> Iterator[Callable[[int, str], None]]:
    """A progress bar on stderr for ``total`` frames: ``label``, bar, done/total, frames per second, time left
    and a status text. Yields ``update(done, status="")``; with ``quiet`` it shows nothing. The bar disappears
    when the block ends, so the command's results stand alone."""
    if quiet:
        yield lambda done, status="": None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeRemainingColumn
    from rich.text import Text

    class FramesPerSecond(ProgressColumn):
        def render(self, task) -> Text:
            return Text("" if task.speed is None else f"{task.speed:.2f} frames/s")

    bar = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), FramesPerSecond(), TimeRemainingColumn(),
                   TextColumn("{task.fields[status]}"), console=Console(stderr=True), transient=True)
    task = bar.add_task(label, total=total, status="")
    with bar:
        yield lambda done, status="": bar.update(task, completed=done, status=status)
