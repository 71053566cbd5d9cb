"""The ``codeslam`` command: a thin shell over the Python API.

Each sub-command lives in its own module and registers itself on :data:`app`; heavy imports (torch,
the network) happen inside the command functions so that ``codeslam --help`` is fast.
"""

from __future__ import annotations

import gc
import os
import sys
import warnings

from codeslam.cli.app import app, console_error
from codeslam.errors import CodeSLAMError

# Sub-command modules, imported for their registration side effect on `app`.
from codeslam.cli import info as _info  # noqa: E402,F401  isort: skip
from codeslam.cli import evaluate as _evaluate  # noqa: E402,F401  isort: skip
from codeslam.cli import synth as _synth  # noqa: E402,F401  isort: skip
from codeslam.cli import train as _train  # noqa: E402,F401  isort: skip
from codeslam.cli import adapt as _adapt  # noqa: E402,F401  isort: skip
from codeslam.cli import depth as _depth  # noqa: E402,F401  isort: skip
from codeslam.cli import sfm as _sfm  # noqa: E402,F401  isort: skip
from codeslam.cli import slam as _slam  # noqa: E402,F401  isort: skip
from codeslam.cli import demo as _demo  # noqa: E402,F401  isort: skip
from codeslam.cli import report as _report  # noqa: E402,F401  isort: skip
from codeslam.cli import evaluate_many as _evaluate_many  # noqa: E402,F401  isort: skip


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the typer app; turn user errors into one line on stderr and exit code 2.

    ``--debug`` anywhere on the command line (or ``CODESLAM_DEBUG=1``) shows the full traceback instead.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args or os.environ.get("CODESLAM_DEBUG") == "1"
    args = [a for a in args if a != "--debug"]
    with warnings.catch_warnings():  # restores the caller's warning display (main() also runs inside tests)
        if not debug:
            warnings.showwarning = _show_warning
        return _run(args, debug)


def entry() -> int:
    """The ``codeslam`` console script and ``python -m codeslam``: :func:`main`, then ``gc.freeze()`` before the
    process ends, so that the interpreter's garbage collections at shutdown skip the objects that torch, plotly,
    matplotlib and the run created (they are freed by reference counting as before; only the walks over them for
    reference cycles are skipped, which at exit find nothing that matters). Only for a process that ends here:
    code that goes on after a command (the tests, a notebook) calls :func:`main`.

    Written for a measured reason (farm-bench, 5 pairs alternating): ``python3 -c "import torch"`` 1.41 -> 1.13 s;
    ``codeslam slam ../shared/data/tum_fr1_rpy --frames 0:60 --threads 2`` 10.32 -> 10.00 s, 0.96x the wall time
    (every pair at most 0.98x)."""
    code = main()
    gc.freeze()
    return code


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings (a skipped frame, invalid depth values) as one ``codeslam: warning:`` line each."""
    print(f"codeslam: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _run(args: list[str], debug: bool) -> int:
    try:
        # standalone mode: typer itself reports usage errors (exit 2) and handles --help (exit 0) by
        # raising SystemExit; exceptions raised inside a command propagate to us.
        app(args=args, prog_name="codeslam")
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except CodeSLAMError as e:
        if debug:
            raise
        console_error(str(e))
        return 2
    except KeyboardInterrupt:
        console_error("interrupted")
        return 130
    except Exception as e:  # anything unexpected is a bug: still one line unless --debug
        if debug:
            raise
        console_error(f"internal error: {type(e).__name__}: {e} (run with --debug for the traceback)")
        return 1
    return 0
