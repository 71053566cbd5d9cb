"""Bad ``--config`` YAML files and option values of ``codeslam train``: one ``codeslam: error:`` line naming
the problem, exit 2, no run folder, and YAML python tags refused by safe loading (never executed: the payload
would create a marker file)."""

from __future__ import annotations

import pytest
from corpus import TINY_YAML, assert_clean_failure, run_cli, write_shard, yaml_payload

BAD_CONFIGS = {
    "malformed_yaml": ("network: [1, 2\n", ["cannot read config file", "line"]),
    "tab_indented": ("network:\n\tcode_size: 8\n", ["cannot read config file"]),
    "not_utf8": (b"\xff\xfe\x00\x81 garbage", ["cannot read config file"]),
    "top_level_list": ("- 1\n- 2\n", ["must hold a mapping"]),
    "top_level_scalar": ("42\n", ["must hold a mapping"]),
    "unknown_section": ("optimiser:\n  lr: 0.1\n", ["unknown section(s) optimiser"]),
    "unknown_key": ("network:\n  codesize: 8\n", ["unknown network option(s): codesize"]),
    "section_not_mapping": ("network: 5\n", ["section 'network' must be a mapping"]),
    "section_list": ("train: [1, 2]\n", ["section 'train' must be a mapping"]),
    "string_for_int": ("train:\n  steps: ten\n", ["train.steps must be an integer"]),
    "float_for_int": ("train:\n  batch_size: 1.5\n", ["train.batch_size must be an integer"]),
    "bool_for_int": ("network:\n  code_size: true\n", ["network.code_size must be an integer"]),
    "string_for_float": ("train:\n  lr: fast\n", ["train.lr must be a finite number"]),
    "nan_float": ("train:\n  kl_weight: .nan\n", ["train.kl_weight must be a finite number"]),
    "inf_float": ("network:\n  avg_depth: .inf\n", ["network.avg_depth must be a finite number"]),
    "int_overflow": ("network:\n  code_size: 99999999999999999999\n", ["network.code_size is out of range"]),
    "list_of_strings": ("network:\n  image_channels: [a, b, c, d]\n", ["network.image_channels must be a list"]),
    "short_list": ("network:\n  image_channels: [4, 8]\n", ["needs 4 positive widths"]),
    "string_for_bool": ("network:\n  linear_decoder: 'yes'\n", ["network.linear_decoder must be true or false"]),
    "negative_lr": ("train:\n  lr: -0.001\n", ["must be positive"]),
    "negative_steps": ("train:\n  steps: -5\n", ["train.steps must be >= 1"]),
    "zero_batch": ("train:\n  batch_size: 0\n", ["train.batch_size must be >= 1"]),
    "negative_code_size": ("network:\n  code_size: -8\n", ["network.code_size must be >= 1"]),
    "size_not_multiple": ("network:\n  width: 100\n", ["multiple of 16"]),
    "fraction_out_of_range": ("train:\n  val_fraction: 1.5\n", ["train.val_fraction must lie in [0, 1)"]),
    "bad_schedule": ("train:\n  lr_schedule: linear\n", ["lr_schedule"]),
    "negative_noise": ("train:\n  noise_std: -0.1\n", ["train.noise_std must be >= 0"]),
    "hfov_out_of_range": ("network:\n  hfov_deg: 200\n", ["hfov_deg must lie in (0, 180)"]),
}


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shards")
    write_shard(folder / "shard_00000.safetensors")
    return folder


@pytest.mark.parametrize("name", sorted(BAD_CONFIGS))
def test_bad_config_file(tmp_path, capsys, shards, name):
    text, needles = BAD_CONFIGS[name]
    cfg = tmp_path / "bad.yaml"
    cfg.write_bytes(text if isinstance(text, bytes) else text.encode())
    out = tmp_path / "run"
    rc, _, err = run_cli(capsys, "train", "--data", shards, "--out", out, "--config", cfg, "--no-progress")
    assert_clean_failure(rc, err, *needles, out_dir=out)


def test_yaml_python_tags_are_refused_not_executed(tmp_path, capsys, shards):
    marker = tmp_path / "PWNED"
    cfg = tmp_path / "evil.yaml"
    cfg.write_text(yaml_payload(marker))
    out = tmp_path / "run"
    rc, _, err = run_cli(capsys, "train", "--data", shards, "--out", out, "--config", cfg, "--no-progress")
    assert_clean_failure(rc, err, "cannot read config file", "python/object/apply", out_dir=out)
    assert not marker.exists()


def test_yaml_payload_would_run(tmp_path):
    """The marker proves something only if unsafe loading of the payload really creates it."""
    import yaml

    marker = tmp_path / "PWNED"
    yaml.load(yaml_payload(marker), Loader=yaml.UnsafeLoader)  # noqa: S506  the point of this test
    assert marker.exists()


@pytest.mark.parametrize(
    ("path", "needles"),
    [("missing.yaml", ["config file not found"]), (".", ["cannot read config file"])],
    ids=["missing", "a_folder"],
)
def test_config_path_that_is_not_a_file(tmp_path, capsys, shards, path, needles):
    out = tmp_path / "run"
    rc, _, err = run_cli(capsys, "train", "--data", shards, "--out", out, "--config", tmp_path / path, "--no-progress")
    assert_clean_failure(rc, err, *needles, out_dir=out)


@pytest.mark.parametrize(
    ("opts", "needles"),
    [
        (["--steps", "0"], ["train.steps must be >= 1"]),
        (["--batch-size", "-2"], ["train.batch_size must be >= 1"]),
        (["--code-size", "0"], ["network.code_size must be >= 1"]),
        (["--size", "0x0"], ["multiple of 16"]),
        (["--size", "-32x32"], ["multiple of 16"]),
        (["--size", "32"], ["WIDTHxHEIGHT"]),
        (["--size", "32x32x3"], ["WIDTHxHEIGHT"]),
        (["--threads", "0"], ["--threads must be >= 1"]),
        (["--workers", "-1"], ["train.workers must be >= 0"]),
        (["--device", "tpu"], ["device"]),
        (["--steps", "ten"], ["Invalid value"]),
    ],
    ids=lambda v: "_".join(v) if isinstance(v, list) else None,
)
def test_bad_train_options(tmp_path, capsys, shards, opts, needles):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY_YAML)
    out = tmp_path / "run"
    rc, _, err = run_cli(capsys, "train", "--data", shards, "--out", out, "--config", cfg, "--no-progress", *opts)
    if opts[0] == "--steps" and opts[1] == "ten":  # typer's own usage error: exit 2, a short usage block
        assert rc == 2 and "Traceback" not in err and needles[0] in err and not out.exists()
        return
    assert_clean_failure(rc, err, *needles, out_dir=out)
