"""Weights files: safetensors round trip with the config, and every kind of bad file refused clearly."""

from __future__ import annotations

import pickle

import pytest
import torch
from safetensors.torch import save_file

from codeslam.errors import WeightsError
from codeslam.network import weights as weights_mod
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import load_model, read_weights, save_weights


def _saved(tmp_path, cfg, name="w.safetensors"):
    torch.manual_seed(0)
    model = CodeNetwork(cfg)
    path = tmp_path / name
    save_weights(path, model, extra_metadata={"steps": 12, "note": "tiny"})
    return model, path


def test_round_trip(tmp_path, tiny_config):
    cfg = tiny_config(linear_decoder=False, in_channels=3)
    model, path = _saved(tmp_path, cfg)
    loaded = load_model(path)
    assert loaded.config == cfg and not loaded.training
    for k, v in model.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k])
    _, file_cfg, meta = read_weights(path)
    assert file_cfg == cfg
    assert meta["format"] == "codeslam-weights-v1" and meta["steps"] == "12" and meta["note"] == "tiny"
    image, prox = torch.rand(1, 3, 32, 32), torch.rand(1, 1, 32, 32)
    model.eval()
    torch.testing.assert_close(loaded(image, prox).mu[0], model(image, prox).mu[0])
    assert load_model(path, config=cfg).config == cfg  # the requested architecture matches


def test_mismatched_config_is_refused(tmp_path, tiny_config):
    _, path = _saved(tmp_path, tiny_config())
    with pytest.raises(WeightsError, match="code_size: file 8 vs requested 32"):
        load_model(path, config=tiny_config(code_size=32))


def test_tensors_not_matching_their_config_are_refused(tmp_path, tiny_config):
    model, path = _saved(tmp_path, tiny_config())
    other = CodeNetwork(tiny_config(code_size=16))  # tensors of a code-16 network ...
    save_file({k: v.contiguous() for k, v in other.state_dict().items()}, str(path),
              metadata={"format": "codeslam-weights-v1", "config": model.config.to_json()})  # ... labelled code 8
    with pytest.raises(WeightsError, match="does not match its own network config"):
        load_model(path)


def test_pickle_is_refused(tmp_path, tiny_config):
    model = CodeNetwork(tiny_config())
    zipped = tmp_path / "model.pt"
    torch.save(model.state_dict(), zipped)
    with pytest.raises(WeightsError, match="pickle"):
        load_model(zipped)
    raw = tmp_path / "model.pkl"
    raw.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(WeightsError, match="pickle"):
        load_model(raw)


def test_truncated_and_foreign_files_are_refused(tmp_path, tiny_config):
    _, path = _saved(tmp_path, tiny_config())
    data = path.read_bytes()
    cut = tmp_path / "cut.safetensors"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match="truncated or corrupt"):
        load_model(cut)
    header_only = tmp_path / "header.safetensors"
    header_only.write_bytes(data[:20])
    with pytest.raises(WeightsError, match="truncated or corrupt"):
        load_model(header_only)
    foreign = tmp_path / "foreign.safetensors"
    save_file({"x": torch.zeros(2)}, str(foreign))
    with pytest.raises(WeightsError, match="not codeslam weights"):
        load_model(foreign)
    with pytest.raises(WeightsError, match="not found"):
        load_model(tmp_path / "missing.safetensors")


def test_missing_default_weights_say_how_to_train(tmp_path, monkeypatch):
    monkeypatch.setattr(weights_mod, "DEFAULT_WEIGHTS", tmp_path / "none.safetensors")
    with pytest.raises(WeightsError, match="no default weights are installed.*codeslam train"):
        load_model(None)


def test_save_is_atomic_on_failure(tmp_path, tiny_config, monkeypatch):
    model, path = _saved(tmp_path, tiny_config())
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr("safetensors.torch.save_file", boom)
    with pytest.raises(RuntimeError):
        save_weights(path, model)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.safetensors"]
