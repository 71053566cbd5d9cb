"""Bad training data, checkpoints and run folders for ``codeslam train``: one error line, exit 2, no run folder
created for a run that cannot start, and an existing checkpoint left byte-for-byte as it was.

Resuming after SIGKILL (issue 6, item 3) is tested in tests/network/test_network_train.py:
``test_resume_after_sigkill`` kills a real training process once its first checkpoint exists, resumes it with
``--resume`` and checks that it ends with the weights (rtol 1e-6) and the last logged loss (rel 1e-6) of an
uninterrupted run of the same 40 steps; ``test_resume_is_deterministic`` checks the same at step 8, and
``test_sigterm_stops_with_a_checkpoint`` the graceful stop. They are not repeated here.
"""

from __future__ import annotations

import json
import os

import pytest
import torch
from corpus import (
    assert_clean_failure,
    pickle_payload,
    run_cli,
    tiny_weights,
    tiny_yaml,
    write_shard,
)
from safetensors import safe_open
from safetensors.torch import save_file


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shards")
    write_shard(folder / "shard_00000.safetensors")
    return folder


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, shards) -> tuple[dict, dict]:
    """(tensors, metadata) of a real 1-step checkpoint of the tiny network."""
    run = tmp_path_factory.mktemp("ckpt") / "run"
    cfg = tiny_yaml(run.parent / "tiny.yaml")
    assert run_cli_plain("train", "--data", shards, "--out", run, "--config", cfg, "--steps", "2", "--stop-after",
                         "1", "--no-progress") == 0
    with safe_open(str(run / "checkpoint.safetensors"), "pt") as f:
        return {k: f.get_tensor(k) for k in f.keys()}, dict(f.metadata())


def run_cli_plain(*args) -> int:
    from codeslam.cli import main

    return main([str(a) for a in args])


def _train(capsys, tmp_path, data, out, *extra):
    cfg = tiny_yaml(tmp_path / "tiny.yaml")
    return run_cli(capsys, "train", "--data", data, "--out", out, "--config", cfg, "--steps", "2", "--no-progress",
                   *extra)


# ---------------------------------------------------------------------------------------------- training data


def _shard_with(tmp_path, shards, tensors=None, **meta):
    with safe_open(str(shards / "shard_00000.safetensors"), "pt") as f:
        t, m = {k: f.get_tensor(k) for k in f.keys()}, dict(f.metadata())
    folder = tmp_path / "data"
    folder.mkdir()
    save_file(tensors(t) if tensors else t, str(folder / "shard_00000.safetensors"), metadata={**m, **meta})
    return folder


def _camera_meta(shards, **changes):
    with safe_open(str(shards / "shard_00000.safetensors"), "pt") as f:
        cam = json.loads(f.metadata()["camera"])
    return json.dumps({**cam, **changes})


def _folder(tmp_path, files: dict[str, bytes]):
    folder = tmp_path / "data"
    folder.mkdir()
    for name, content in files.items():
        (folder / name).write_bytes(content)
    return folder


def _file(tmp_path, content: bytes):
    (tmp_path / "x.safetensors").write_bytes(content)
    return tmp_path / "x.safetensors"


BAD_DATA = {
    "empty_folder": (lambda tmp, sh: _folder(tmp, {}), ["no known dataset format"]),
    "folder_of_non_shards": (lambda tmp, sh: _folder(tmp, {"notes.txt": b"x", "a.bin": b"\0"}),
                             ["no known dataset format"]),
    "truncated_shard_in_folder": (
        lambda tmp, sh: _folder(tmp, {"shard_00000.safetensors": (sh / "shard_00000.safetensors").read_bytes()[:700]}),
        ["cannot read shard"]),
    "random_bytes_shard_file": (lambda tmp, sh: _file(tmp, b"\x07" + os.urandom(511)), ["cannot read shard"]),
    "weights_as_data": (lambda tmp, sh: tiny_weights(tmp / "w.safetensors"), ["not a codeslam training shard"]),
    "depth_factor_zero": (lambda tmp, sh: _shard_with(tmp, sh, depth_factor="0"), ["depth_factor must be positive"]),
    "depth_factor_nan": (lambda tmp, sh: _shard_with(tmp, sh, depth_factor="nan"), ["depth_factor must be positive"]),
    "camera_zero_focal": (lambda tmp, sh: _shard_with(tmp, sh, camera=_camera_meta(sh, fx=0.0)),
                          ["malformed metadata", "focal lengths must be positive"]),
    "camera_of_another_size": (lambda tmp, sh: _shard_with(tmp, sh, camera=_camera_meta(sh, width=64)),
                               ["images are 32x32 but its camera is 64x32"]),
    "camera_not_json": (lambda tmp, sh: _shard_with(tmp, sh, camera="{fx: 1"), ["malformed metadata"]),
    "float_images": (lambda tmp, sh: _shard_with(tmp, sh, lambda t: {**t, "image": t["image"].float()}),
                     ["uint8"]),
    "missing_depth_tensor": (lambda tmp, sh: _shard_with(tmp, sh, lambda t: {"image": t["image"]}),
                             ["cannot read shard"]),
    "depth_of_another_size": (
        lambda tmp, sh: _shard_with(tmp, sh, lambda t: {**t, "depth": t["depth"][:, :16].contiguous()}),
        ["does not match the images"]),
    "zero_frames": (lambda tmp, sh: _shard_with(tmp, sh, lambda t: {k: v[:0] for k, v in t.items()}),
                    ["no training frames"]),
    "no_valid_depth": (lambda tmp, sh: _shard_with(tmp, sh, lambda t: {**t, "depth": torch.zeros_like(t["depth"])}),
                       ["no valid depth value"]),
    "too_few_frames_for_a_batch": (
        lambda tmp, sh: _shard_with(tmp, sh, lambda t: {k: v[:2] for k, v in t.items()}), ["training frames"]),
}


@pytest.mark.parametrize("name", sorted(BAD_DATA))
def test_bad_training_data(tmp_path, capsys, shards, name):
    make, needles = BAD_DATA[name]
    data = make(tmp_path, shards)
    out = tmp_path / "run"
    rc, _, err = _train(capsys, tmp_path, data, out)
    assert_clean_failure(rc, err, *needles, out_dir=out)


def test_pickle_posing_as_a_shard_is_never_unpickled(tmp_path, capsys):
    marker = tmp_path / "PWNED"
    (tmp_path / "data").mkdir()
    pickle_payload(tmp_path / "data" / "shard_00000.safetensors", marker)
    out = tmp_path / "run"
    rc, _, err = _train(capsys, tmp_path, tmp_path / "data", out)
    assert_clean_failure(rc, err, "cannot read shard", out_dir=out)
    assert not marker.exists()


# ---------------------------------------------------------------------------------------------- run folder


@pytest.mark.parametrize("where", ["out_is_a_file", "parent_is_a_file"])
def test_unwritable_run_folder(tmp_path, capsys, shards, where):
    (tmp_path / "blocker").write_text("a file")
    out = tmp_path / "blocker" if where == "out_is_a_file" else tmp_path / "blocker" / "run"
    rc, _, err = _train(capsys, tmp_path, shards, out)
    assert_clean_failure(rc, err, "cannot write into", "blocker is a file")
    assert (tmp_path / "blocker").read_text() == "a file"


def test_resume_without_a_checkpoint_starts_a_new_run_with_a_warning(tmp_path, capsys, shards):
    """Documented handling: --resume on an empty run folder (e.g. a job killed before its first checkpoint and
    restarted by a script that always passes --resume) starts from step 0 and says so."""
    out = tmp_path / "run"
    rc, stdout, err = _train(capsys, tmp_path, shards, out, "--resume")
    assert rc == 0, err
    assert "warning: --resume:" in stdout and "holds no checkpoint.safetensors; starting a new run" in stdout
    assert "finished at step 2" in stdout and (out / "weights.safetensors").is_file()


# ---------------------------------------------------------------------------------------------- checkpoints


def _run_with_checkpoint(tmp_path, checkpoint, mutate=None, raw: bytes | None = None):
    """A run folder holding only a checkpoint: the real one, changed by ``mutate(tensors, meta)``, or ``raw``."""
    run = tmp_path / "run"
    run.mkdir()
    path = run / "checkpoint.safetensors"
    if raw is not None:
        path.write_bytes(raw)
    else:
        tensors, meta = dict(checkpoint[0]), dict(checkpoint[1])
        if mutate is not None:
            mutate(tensors, meta)
        save_file(tensors, str(path), metadata=meta)
    return run


def _first(tensors, prefix):
    return sorted(k for k in tensors if k.startswith(prefix))[0]


def _mut_drop_rng(t, m):
    del t["rng.torch_cpu"]


def _mut_model_shape(t, m):
    t[_first(t, "model.")] = torch.zeros(3)


def _mut_optim_shape(t, m):
    t[_first(t, "optim.").rsplit(".", 1)[0] + ".exp_avg"] = torch.zeros(2, 2)


def _mut_drop_optim_groups(t, m):
    del m["optim_param_groups"]


def _mut_step_text(t, m):
    m["step"] = "three"


def _mut_config_junk(t, m):
    m["config"] = "{not json"


def _mut_format(t, m):
    m["format"] = "codeslam-weights-v1"


def _mut_rng_float(t, m):
    t["rng.torch_cpu"] = torch.zeros(5)


BAD_CHECKPOINTS = {
    "truncated": (lambda c: dict(raw=_real_bytes(c)[:1000]), ["not a readable safetensors file"]),
    "random_bytes": (lambda c: dict(raw=b"\x07" + os.urandom(999)), ["not a readable safetensors file"]),
    "empty": (lambda c: dict(raw=b""), ["not a readable safetensors file"]),
    "weights_not_checkpoint": (lambda c: dict(mutate=_mut_format), ["not a codeslam training checkpoint"]),
    "missing_rng_state": (lambda c: dict(mutate=_mut_drop_rng), ["not a complete training checkpoint"]),
    "rng_state_of_another_type": (lambda c: dict(mutate=_mut_rng_float), ["not a complete training checkpoint"]),
    "model_tensor_of_another_shape": (lambda c: dict(mutate=_mut_model_shape), ["not a complete training checkpoint"]),
    "optimiser_state_of_another_shape": (lambda c: dict(mutate=_mut_optim_shape),
                                         ["not a complete training checkpoint"]),
    "missing_optimiser_groups": (lambda c: dict(mutate=_mut_drop_optim_groups), ["not a complete training checkpoint"]),
    "step_not_a_number": (lambda c: dict(mutate=_mut_step_text), ["not a complete training checkpoint"]),
    "config_not_json": (lambda c: dict(mutate=_mut_config_junk), ["malformed config"]),
}


def _real_bytes(checkpoint) -> bytes:
    from safetensors.torch import save

    return save(checkpoint[0], metadata=checkpoint[1])


@pytest.mark.parametrize("name", sorted(BAD_CHECKPOINTS))
def test_bad_checkpoint_on_resume(tmp_path, capsys, shards, checkpoint, name):
    make, needles = BAD_CHECKPOINTS[name]
    run = _run_with_checkpoint(tmp_path, checkpoint, **make(checkpoint))
    before = (run / "checkpoint.safetensors").read_bytes()
    rc, _, err = _train(capsys, tmp_path, shards, run, "--resume")
    assert_clean_failure(rc, err, "checkpoint.safetensors", *needles, out_dir=run, before={"checkpoint.safetensors"})
    assert (run / "checkpoint.safetensors").read_bytes() == before


def test_pickle_posing_as_a_checkpoint_is_never_unpickled(tmp_path, capsys, shards):
    marker = tmp_path / "PWNED"
    run = tmp_path / "run"
    run.mkdir()
    pickle_payload(run / "checkpoint.safetensors", marker)
    rc, _, err = _train(capsys, tmp_path, shards, run, "--resume")
    assert_clean_failure(rc, err, "pickle", out_dir=run, before={"checkpoint.safetensors"})
    assert not marker.exists()


@pytest.mark.parametrize(
    ("opts", "needles"),
    [(["--code-size", "16"], ["--resume cannot change network.code_size (8 in the checkpoint, 16 requested)"]),
     (["--size", "64x64"], ["--resume cannot change network.width"]),
     (["--batch-size", "3"], ["--resume cannot change train.batch_size"])],
    ids=["code_size", "size", "batch_size"],
)
def test_resume_with_a_changed_architecture(tmp_path, capsys, shards, checkpoint, opts, needles):
    run = _run_with_checkpoint(tmp_path, checkpoint)
    before = (run / "checkpoint.safetensors").read_bytes()
    rc, _, err = _train(capsys, tmp_path, shards, run, "--resume", *opts)
    assert_clean_failure(rc, err, *needles, out_dir=run, before={"checkpoint.safetensors"})
    assert (run / "checkpoint.safetensors").read_bytes() == before


def test_resume_with_a_config_of_another_architecture(tmp_path, capsys, shards, checkpoint):
    run = _run_with_checkpoint(tmp_path, checkpoint)
    cfg = tiny_yaml(tmp_path / "wide.yaml")
    cfg.write_text(cfg.read_text().replace("fc_units: 16", "fc_units: 32"))
    rc, _, err = run_cli(capsys, "train", "--data", shards, "--out", run, "--config", cfg, "--resume", "--no-progress")
    assert_clean_failure(rc, err, "--resume cannot change network.fc_units", out_dir=run,
                         before={"checkpoint.safetensors"})


def test_good_checkpoint_still_resumes(tmp_path, capsys, shards, checkpoint):
    run = _run_with_checkpoint(tmp_path, checkpoint)
    rc, stdout, err = _train(capsys, tmp_path, shards, run, "--resume")
    assert rc == 0, err
    assert "resuming" in stdout and "at step 1" in stdout and "finished at step 2" in stdout
