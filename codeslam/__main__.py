"""``python -m codeslam`` (and ``torchrun -m codeslam train ...``): the ``codeslam`` command."""

import sys

from codeslam.cli import entry

if __name__ == "__main__":
    sys.exit(entry())
