"""Untrusted and broken weights files: each is refused with a one-line :class:`WeightsError` naming the file,
and nothing in them is ever unpickled (files that would run code when unpickled leave a marker file if they
are; the marker must not exist afterwards).

Every command that takes ``--weights`` loads it through :func:`codeslam.network.weights.load_model`, so the
corpus runs through that call; ``test_depth_command_refuses_bad_weights`` runs a few of them through the CLI.
"""

from __future__ import annotations

import json
import os
import pickle

import pytest
import torch
from corpus import (
    TINY_NETWORK,
    assert_clean_failure,
    pickle_payload,
    run_cli,
    tiny_weights,
    torch_save_payload,
    tum_folder,
    write_shard,
)
from safetensors.torch import save_file

from codeslam.errors import WeightsError
from codeslam.network.config import NetworkConfig
from codeslam.network.weights import WEIGHTS_FORMAT, load_model, read_weights


def missing(tmp_path):
    return tmp_path / "nope.safetensors", ["not found"]


def a_folder(tmp_path):
    (tmp_path / "w.safetensors").mkdir()
    return tmp_path / "w.safetensors", ["not found"]


def empty(tmp_path):
    (tmp_path / "w.safetensors").write_bytes(b"")
    return tmp_path / "w.safetensors", ["not a readable safetensors file"]


def truncated(tmp_path):
    p = tiny_weights(tmp_path / "w.safetensors")
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    return p, ["not a readable safetensors file", "truncated"]


def truncated_header(tmp_path):
    p = tiny_weights(tmp_path / "w.safetensors")
    p.write_bytes(p.read_bytes()[:20])
    return p, ["not a readable safetensors file"]


def huge_header_length(tmp_path):
    p = tmp_path / "w.safetensors"
    p.write_bytes((2**62).to_bytes(8, "little") + b"{}")
    return p, ["not a readable safetensors file"]


def random_bytes(tmp_path):
    p = tmp_path / "w.safetensors"
    p.write_bytes(bytes([7]) + os.urandom(4095))  # not starting like a pickle
    return p, ["not a readable safetensors file"]


def text_file(tmp_path):
    p = tmp_path / "w.safetensors"
    p.write_text("network:\n  code_size: 8\n")
    return p, ["not a readable safetensors file"]


def foreign_safetensors(tmp_path):
    """A valid safetensors file of another program: no codeslam metadata."""
    p = tmp_path / "w.safetensors"
    save_file({"weight": torch.ones(3, 3)}, str(p))
    return p, ["not codeslam weights", "None"]


def shard_as_weights(tmp_path):
    return write_shard(tmp_path / "w.safetensors"), ["not codeslam weights", "codeslam-shard-v1"]


def config_not_json(tmp_path):
    p = tmp_path / "w.safetensors"
    save_file({"weight": torch.ones(1)}, str(p), metadata={"format": WEIGHTS_FORMAT, "config": "{code_size: 8"})
    return p, ["no valid network config"]


def config_invalid(tmp_path):
    p = tmp_path / "w.safetensors"
    bad = json.dumps({**TINY_NETWORK, "code_size": -3})
    save_file({"weight": torch.ones(1)}, str(p), metadata={"format": WEIGHTS_FORMAT, "config": bad})
    return p, ["no valid network config", "code_size"]


def tensors_of_another_architecture(tmp_path):
    """The metadata claims the tiny network, the tensors are of a wider one."""
    from codeslam.network.weights import read_weights as rw

    tensors, _, _ = rw(tiny_weights(tmp_path / "wide.safetensors", fc_units=32))
    p = tmp_path / "w.safetensors"
    save_file(tensors, str(p), metadata={"format": WEIGHTS_FORMAT, "config": json.dumps(TINY_NETWORK)})
    return p, ["does not match its own network config", "wrong shape"]


def missing_tensors(tmp_path):
    tensors, cfg, meta = read_weights(tiny_weights(tmp_path / "full.safetensors"))
    p = tmp_path / "w.safetensors"
    save_file(dict(list(tensors.items())[:-3]), str(p), metadata=meta)
    return p, ["does not match its own network config", "missing 3 tensor(s)"]


def nan_weights(tmp_path):
    tensors, cfg, meta = read_weights(tiny_weights(tmp_path / "full.safetensors"))
    key = sorted(tensors)[0]
    tensors[key] = torch.full_like(tensors[key], float("nan"))
    p = tmp_path / "w.safetensors"
    save_file(tensors, str(p), metadata=meta)
    return p, ["non-finite values", key]


BAD_WEIGHTS = [missing, a_folder, empty, truncated, truncated_header, huge_header_length, random_bytes, text_file,
               foreign_safetensors, shard_as_weights, config_not_json, config_invalid, tensors_of_another_architecture,
               missing_tensors, nan_weights]


@pytest.mark.parametrize("make", BAD_WEIGHTS, ids=[f.__name__ for f in BAD_WEIGHTS])
def test_bad_weights_are_refused(tmp_path, make):
    path, needles = make(tmp_path)
    with pytest.raises(WeightsError) as info:
        load_model(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    for needle in needles:
        assert needle in msg, (needle, msg)


@pytest.mark.parametrize("protocol", [0, 2, pickle.HIGHEST_PROTOCOL])
def test_pickle_posing_as_weights_is_never_unpickled(tmp_path, protocol):
    """Protocol 0 is text (no magic byte); protocols >= 2 start with 0x80: all are refused, none is loaded."""
    marker = tmp_path / "PWNED"
    path = pickle_payload(tmp_path / "codeslam.safetensors", marker, protocol)
    with pytest.raises(WeightsError, match="codeslam.safetensors"):
        load_model(path)
    assert not marker.exists()


def test_torch_checkpoint_posing_as_weights_is_never_unpickled(tmp_path):
    marker = tmp_path / "PWNED"
    path = torch_save_payload(tmp_path / "model.pth", marker)
    with pytest.raises(WeightsError, match="pickle"):
        load_model(path)
    assert not marker.exists()


def test_the_payloads_would_run(tmp_path):
    """The markers above prove something only if unpickling the files really creates them."""
    marker = tmp_path / "PWNED"
    pickle.loads(pickle_payload(tmp_path / "a.pkl", marker, 0).read_bytes())
    assert marker.exists()
    marker.unlink()
    torch.load(torch_save_payload(tmp_path / "b.pth", marker), weights_only=False)
    assert marker.exists()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root reads files whatever their mode")
def test_unreadable_weights(tmp_path):
    path = tiny_weights(tmp_path / "w.safetensors")
    path.chmod(0)
    try:
        with pytest.raises(WeightsError, match="w.safetensors"):
            load_model(path)
    finally:
        path.chmod(0o600)


def test_mismatched_architecture_is_named(tmp_path):
    """Weights of code size 16 where a code-size-8 network is required: the message names the difference."""
    path = tiny_weights(tmp_path / "w.safetensors", code_size=16)
    with pytest.raises(WeightsError, match="code_size: file 16 vs requested 8"):
        load_model(path, config=NetworkConfig(**TINY_NETWORK))
    assert load_model(path).config.code_size == 16  # without a requirement it loads what it holds


def test_good_weights_still_load(tmp_path):
    model = load_model(tiny_weights(tmp_path / "w.safetensors"))
    assert model.config == NetworkConfig(**TINY_NETWORK) and not model.training


# ---------------------------------------------------------------------------------------------- through the CLI


def _has_command(name: str) -> bool:
    from codeslam.cli.app import app

    return any(c.name == name or (c.callback and c.callback.__name__ == name) for c in app.registered_commands)


@pytest.mark.parametrize("make", [truncated, random_bytes, foreign_safetensors, nan_weights],
                         ids=["truncated", "random_bytes", "foreign", "nan"])
def test_depth_command_refuses_bad_weights(tmp_path, capsys, make):
    assert _has_command("depth"), "codeslam depth is missing"  # a failure, not a skip
    path, needles = make(tmp_path)
    seq = tum_folder(tmp_path / "seq", n=2)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, "depth", seq, "--frames", "0", "--weights", path, "--out", out)
    assert_clean_failure(rc, err, *needles, out_dir=out)


def test_depth_command_never_unpickles(tmp_path, capsys):
    assert _has_command("depth"), "codeslam depth is missing"  # a failure, not a skip
    marker = tmp_path / "PWNED"
    path = torch_save_payload(tmp_path / "model.pth", marker)
    seq = tum_folder(tmp_path / "seq", n=2)
    rc, _, err = run_cli(capsys, "depth", seq, "--frames", "0", "--weights", path, "--out", tmp_path / "out")
    assert_clean_failure(rc, err, "pickle", out_dir=tmp_path / "out")
    assert not marker.exists()


def test_safetensors_whose_header_length_starts_like_a_pickle_loads(tmp_path):
    """A safetensors file starts with its header length (u64, little endian); when its low byte is 0x80 the file
    begins with the pickle magic byte. Such a file is valid and must load (found by this corpus: a resumed
    training checkpoint was refused as "a PyTorch pickle" depending on its metadata length)."""
    from safetensors.torch import save

    tensors, _, meta = read_weights(tiny_weights(tmp_path / "base.safetensors"))
    for pad in range(256):
        blob = save(tensors, metadata={**meta, "note": "x" * pad})
        if blob[0] == 0x80:
            break
    assert blob[0] == 0x80
    path = tmp_path / "w.safetensors"
    path.write_bytes(blob)
    assert load_model(path).config == NetworkConfig(**TINY_NETWORK)
