"""``codeslam synth`` end to end: sequences with a JSON summary, training shards, bad options."""

from __future__ import annotations

import json
from pathlib import Path

from codeslam.cli import main
from codeslam.synth.shards import read_shard


def test_cli_writes_sequences_and_summary(tmp_path: Path):
    rc = main(["synth", str(tmp_path / "out"), "--scenes", "1", "--frames", "3", "--seed", "2", "--size", "32x24",
               "--json", str(tmp_path / "s.json")])
    assert rc == 0
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["scenes"] == 1 and summary["frames"] == 3 and summary["size"] == [32, 24]
    assert summary["fps"] > 0
    root = tmp_path / "out" / "scene_000"
    assert len(list((root / "rgb").glob("*.png"))) == 3
    assert (root / "calib.txt").read_text().split()[2] == "15.5"


def test_cli_writes_training_shards(tmp_path: Path):
    rc = main(["synth", str(tmp_path / "tr"), "--train", "--views", "5", "--views-per-scene", "5", "--shard-size",
               "5", "--size", "24x16"])
    assert rc == 0
    image, depth, cam = read_shard(tmp_path / "tr" / "shard_00000.safetensors")
    assert image.shape == (5, 3, 16, 24) and (cam.width, cam.height) == (24, 16)


def test_cli_rejects_bad_options(tmp_path: Path, capsys):
    assert main(["synth", str(tmp_path / "x"), "--size", "big"]) == 2
    err = capsys.readouterr().err
    assert "--size" in err and len(err.strip().splitlines()) == 1
    assert main(["synth", str(tmp_path / "x"), "--frames", "0", "--size", "16x16"]) == 2
    assert main(["synth", str(tmp_path / "x"), "--train", "--views", "0"]) == 2
