"""The typer application shared by all sub-command modules."""

from __future__ import annotations

import sys

import typer

from codeslam.cli.common import keep_freed_memory

app = typer.Typer(
    name="codeslam",
    help="CodeSLAM: compact learned depth codes, dense N-frame SfM and monocular SLAM.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def console_error(msg: str) -> None:
    """Print one line ``codeslam: error: MSG`` on stderr."""
    msg = " ".join(str(msg).split())  # one line, whatever the exception text held
    print(f"codeslam: error: {msg}", file=sys.stderr)


@app.callback()
def _root() -> None:
    """CodeSLAM: compact learned depth codes, dense N-frame SfM and monocular SLAM.

    Add --debug to any command to see the full traceback of an error.
    """
    keep_freed_memory()
