"""Network weights on disk: safetensors only (never pickle), with the architecture in the metadata.

A weights file holds the model's tensors and the metadata ``{"format": "codeslam-weights-v1", "config":
<NetworkConfig as JSON>, ...extra}``; :func:`load_model` rebuilds the network from that config, so a file
always loads into the architecture it was trained with, and a caller that needs a particular architecture
(e.g. code size 32) gets a :class:`~codeslam.errors.WeightsError` naming the mismatch. A training checkpoint
(``codeslam-checkpoint-v1``, see :mod:`codeslam.network.train`) loads as weights too.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from codeslam.errors import ConfigError, WeightsError
from codeslam.io import atomic_path
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork

WEIGHTS_FORMAT = "codeslam-weights-v1"
CHECKPOINT_FORMAT = "codeslam-checkpoint-v1"
#: prefix of the model tensors inside a training checkpoint
MODEL_PREFIX = "model."
#: the weights every command loads unless ``--weights FILE`` is given (package data)
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "codeslam_default.safetensors"

_PICKLE_MAGIC = (b"PK\x03\x04", b"\x80")  # torch.save zip archive, raw pickle protocol >= 2


def _starts_like_pickle(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4).startswith(_PICKLE_MAGIC)
    except OSError:
        return False


def save_tensors(path: str | os.PathLike, tensors: dict[str, torch.Tensor], metadata: dict[str, str]) -> None:
    """Write ``tensors`` (moved to CPU, made contiguous) and string ``metadata`` to ``path`` atomically."""
    from safetensors.torch import save_file

    flat = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    with atomic_path(path) as tmp:
        save_file(flat, str(tmp), metadata=metadata)


def read_tensors(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    """Read all tensors and the metadata of a safetensors file; anything else (a pickle, a truncated or corrupt
    file) -> WeightsError naming the file."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"weights file not found: {path}")
    try:  # safetensors parses a length-prefixed JSON header and raw tensor bytes: nothing in the file is executed
        with safe_open(str(path), framework="pt") as f:
            metadata = dict(f.metadata() or {})
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        # The pickle test comes only after parsing failed: a valid safetensors file whose header length has
        # 0x80 as its low byte also starts with the pickle magic byte.
        if _starts_like_pickle(path):
            raise WeightsError(
                f"{path} looks like a PyTorch pickle checkpoint; codeslam only reads safetensors weights "
                "(it never unpickles files, which can run arbitrary code)"
            ) from None
        msg = " ".join(str(e).split())
        raise WeightsError(f"{path} is not a readable safetensors file (truncated or corrupt?): {msg}") from None
    return tensors, metadata


def save_weights(
    path: str | os.PathLike,
    model: CodeNetwork,
    config: NetworkConfig | None = None,
    extra_metadata: dict[str, object] | None = None,
) -> None:
    """Write ``model``'s weights with its config (``config`` defaults to ``model.config``) and ``extra_metadata``
    (values stored as strings; non-strings as JSON) to ``path``, atomically."""
    config = config or model.config
    meta = {k: v if isinstance(v, str) else json.dumps(v) for k, v in (extra_metadata or {}).items()}
    meta.update({"format": WEIGHTS_FORMAT, "config": config.to_json()})
    save_tensors(path, dict(model.state_dict()), meta)


def read_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], NetworkConfig, dict[str, str]]:
    """-> (model state dict, its NetworkConfig, all metadata) of a weights file or training checkpoint."""
    tensors, meta = read_tensors(path)
    fmt = meta.get("format")
    if fmt == CHECKPOINT_FORMAT:
        tensors = {k[len(MODEL_PREFIX) :]: v for k, v in tensors.items() if k.startswith(MODEL_PREFIX)}
    elif fmt != WEIGHTS_FORMAT:
        raise WeightsError(f"{path} is a safetensors file but not codeslam weights (format {fmt!r})")
    try:
        config = NetworkConfig.from_dict(json.loads(meta["config"]))
    except (KeyError, json.JSONDecodeError, ConfigError) as e:
        raise WeightsError(f"{path} has no valid network config in its metadata ({e})") from None
    return tensors, config, meta


def _config_diff(a: NetworkConfig, b: NetworkConfig) -> str:
    da, db = a.to_dict(), b.to_dict()
    return ", ".join(f"{k}: file {da[k]} vs requested {db[k]}" for k in da if da[k] != db[k])


def load_model(
    path: str | os.PathLike | None = None,
    device: torch.device | str = "cpu",
    config: NetworkConfig | None = None,
) -> CodeNetwork:
    """Build the network from a weights file (the default weights when ``path`` is None) in eval mode on
    ``device``. With ``config``, the file must hold exactly that architecture."""
    if path is None:
        path = DEFAULT_WEIGHTS
        if not path.is_file():
            raise WeightsError(
                f"no default weights are installed ({path} is missing); train them with "
                "`codeslam train --data DIR --out RUN` and pass --weights RUN/weights.safetensors"
            )
    tensors, file_config, _ = read_weights(path)
    if config is not None and config != file_config:
        raise WeightsError(f"{path} holds a different network: {_config_diff(file_config, config)}")
    model = CodeNetwork(file_config)
    expected = model.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    wrong = sorted(k for k in expected if k in tensors and tensors[k].shape != expected[k].shape)
    if missing or unexpected or wrong:
        parts = []
        if missing:
            parts.append(f"missing {len(missing)} tensor(s) e.g. {missing[0]}")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected tensor(s) e.g. {unexpected[0]}")
        if wrong:
            k = wrong[0]
            shapes = f"{tuple(tensors[k].shape)} vs {tuple(expected[k].shape)}"
            parts.append(f"{len(wrong)} of the wrong shape e.g. {k} {shapes}")
        raise WeightsError(f"{path} does not match its own network config: " + "; ".join(parts))
    # a diverged training run saves NaN weights: refuse them rather than predict NaN depth everywhere
    bad = sorted(k for k, v in tensors.items() if v.is_floating_point() and not bool(torch.isfinite(v).all()))
    if bad:
        raise WeightsError(f"{path} holds non-finite values (NaN or inf) in {len(bad)} tensor(s), e.g. {bad[0]}")
    model.load_state_dict(tensors)
    return model.to(device).eval()
