"""YAML configuration shared by every config dataclass (network, training, SfM, SLAM): a safe YAML reader and the
type check of each value against its field's default, so every command refuses a bad option the same way."""

from __future__ import annotations

import math
import os
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from codeslam.errors import ConfigError

MAX_CONFIG_INT = 2**31 - 1
"""Largest integer a config accepts: a bigger one is a typo, not a setting (and overflows tensor sizes)."""


def read_yaml(path: str | os.PathLike) -> Any:
    """The YAML document in ``path`` (safe loader: no Python tags), or ConfigError naming the file; an empty
    file reads as None."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise ConfigError(f"cannot read config file {path}: {' '.join(str(e).split())}") from None


def read_yaml_mapping(path: str | os.PathLike, holds: str) -> dict:
    """The mapping in the YAML file ``path`` ({} for an empty file), or ConfigError naming the file and what it
    should hold (``holds``, e.g. "sections tracker, keyframes, window")."""
    data = read_yaml(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping ({holds})")
    return data


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and abs(v) <= MAX_CONFIG_INT


def _is_number(v: Any) -> bool:
    return (isinstance(v, float) or _is_int(v)) and math.isfinite(v)


def coerce(name: str, value: Any, default: Any) -> Any:
    """A (YAML) value converted to the type of the field's ``default`` -- true/false, an integer, a finite number,
    a string, a list of integers or of numbers (returned as a tuple) -- or ConfigError naming the field."""
    if isinstance(default, bool):
        ok, kind = isinstance(value, bool), "true or false"
    elif isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_CONFIG_INT:
            raise ConfigError(f"{name} is out of range: {value}")
        ok, kind = _is_int(value), "an integer"
    elif isinstance(default, float):
        ok, kind = _is_number(value), "a finite number"
    elif isinstance(default, str):
        ok, kind = isinstance(value, str), "a string"
    elif isinstance(default, tuple):
        elem = _is_int if all(_is_int(v) for v in default) else _is_number
        ok = isinstance(value, (list, tuple)) and all(elem(v) for v in value)
        kind = "a list of integers" if elem is _is_int else "a list of numbers"
        if ok:
            return tuple(value)
    else:
        raise AssertionError(f"unhandled config field type for {name}")  # a bug in the config dataclass
    if not ok:
        raise ConfigError(f"{name} must be {kind}, got {value!r}")
    return float(value) if isinstance(default, float) else value


def from_mapping(cls, d: Any, section: str):
    """An instance of the config dataclass ``cls`` from a (YAML) mapping of some of its fields (the others keep
    their defaults); unknown keys and mistyped values raise ConfigError naming ``section.field``."""
    if not isinstance(d, dict):
        raise ConfigError(f"config section '{section}' must be a mapping, got {type(d).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(str(k) for k in set(d) - known)
    if unknown:
        raise ConfigError(f"unknown {section} option(s): {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    defaults = cls()
    return cls(**{k: coerce(f"{section}.{k}", v, getattr(defaults, k)) for k, v in d.items()})
