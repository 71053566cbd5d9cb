"""User-facing errors.

Anything a user can cause with bad input (a missing file, a corrupt image, nonsense intrinsics,
mismatched weights) raises :class:`CodeSLAMError` with a one-line message. The CLI prints that line
and exits non-zero; every other exception is a bug in codeslam.
"""


class CodeSLAMError(Exception):
    """An error caused by the input, reported to the user as one line."""


class DatasetError(CodeSLAMError):
    """A dataset folder or one of its files cannot be read."""


class WeightsError(CodeSLAMError):
    """A weights file cannot be read or does not match the requested network."""


class ConfigError(CodeSLAMError):
    """A configuration file or option is malformed."""


class OutputError(CodeSLAMError):
    """An output file or folder cannot be written (its folder is a file, no permission, disk full)."""
