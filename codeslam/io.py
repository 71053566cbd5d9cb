"""Safe file output: every result is written to a temporary name in the target folder and then renamed,
so an interrupted run leaves either the previous complete file or none (never a half-written one)."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from codeslam.errors import OutputError


def check_output_dir(folder: str | os.PathLike) -> Path:
    """OutputError when ``folder`` could not be created as an output folder because it, or the nearest of its
    existing parents, is a file; checks only (creates nothing), so a command can fail before doing its work."""
    folder = Path(folder)
    for p in (folder, *folder.parents):
        if p.exists():
            if not p.is_dir():
                raise OutputError(f"cannot write into {folder}: {p} is a file, not a folder")
            break
    return folder


def ensure_dir(folder: str | os.PathLike) -> Path:
    """Create the output folder ``folder`` and its parents; OutputError (one line) when it cannot be, e.g.
    because one of them is a file."""
    folder = check_output_dir(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create the folder {folder}: {e.strerror or e}") from None
    return folder


def check_output_file(path: str | os.PathLike) -> Path:
    """OutputError when the file ``path`` could not be written because it is a folder or a file is in the way
    of its folder; checks only, so that a command can refuse a bad ``--json`` before its work."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"cannot write {path}: it is a folder")
    check_output_dir(path.parent)
    return path


def _temp_beside(path: Path, suffix: str) -> tuple[int, str]:
    """(fd, name) of a new temporary file next to ``path``, after checking that ``path`` can be written."""
    check_output_file(path)
    ensure_dir(path.parent)
    try:
        return tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    except OSError as e:
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from None


@functools.cache
def _umask() -> int:
    """The process umask, read once (the only portable way to read it is to set it and put it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _commit(tmp: str | Path, path: Path) -> None:
    try:
        # mkstemp creates 0600 files; a result gets the permissions of any newly created file (0666 & ~umask).
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as e:
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from None


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success rename it over ``path``.

    On an exception the temporary file is removed and ``path`` is left untouched. A ``path`` that cannot be
    written (its folder is a file, it is a folder, no permission, disk full) is an OutputError.
    """
    path = Path(path)
    fd, tmp = _temp_beside(path, ".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            try:
                f.flush()
                os.fsync(f.fileno())
            except OSError as e:
                raise OutputError(f"cannot write {path}: {e.strerror or e}") from None
        _commit(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for libraries that want a file name (PIL, safetensors,
    matplotlib); rename it over ``path`` when the block succeeds, delete it otherwise."""
    path = Path(path)
    fd, tmp = _temp_beside(path, path.suffix or ".tmp")
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _commit(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically."""
    with atomic_write(path, "w") as f:
        json.dump(obj, f, indent=2, sort_keys=True)
        f.write("\n")


def check_outputs(out_dir: str | os.PathLike | None, json_file: str | os.PathLike | None) -> None:
    """Check a command's ``--out`` folder and ``--json`` file (either may be None) before it does any work, so a
    bad path fails at once instead of after a complete-looking output folder was written."""
    if out_dir is not None:
        check_output_dir(out_dir)
    if json_file is not None:
        check_output_file(json_file)
