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


def test_cli_motion_preset_at_10_fps(tmp_path: Path, capsys):
    import numpy as np

    from codeslam.data.tum import TumSequence

    rc = main(["synth", str(tmp_path / "w"), "--frames", "6", "--seed", "1", "--size", "32x24", "--motion", "walk",
               "--fps", "10", "-q", "--json", str(tmp_path / "s.json")])
    assert rc == 0
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["motion"] == "walk" and summary["frame_rate"] == 10.0
    seq = TumSequence(tmp_path / "w" / "scene_000")
    pos = np.stack([seq[i].pose[:3, 3].numpy() for i in range(len(seq))])
    stamps = np.array([seq[i].timestamp for i in range(len(seq))])
    assert np.allclose(np.diff(stamps), 0.1)
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1)
    assert step.mean() > 0.03  # a walk moves centimetres per frame at 10 fps, the default path millimetres
    capsys.readouterr()
    assert main(["synth", str(tmp_path / "x"), "--motion", "jog", "--size", "16x16"]) == 2
    err = capsys.readouterr().err
    assert "--motion" in err and "walk" in err and len(err.strip().splitlines()) == 1
    assert main(["synth", str(tmp_path / "x"), "--fps", "0", "--size", "16x16"]) == 2
    assert main(["synth", str(tmp_path / "x"), "--train", "--motion", "walk"]) == 2
