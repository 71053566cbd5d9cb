"""`codeslam evaluate DATASET... --out DIR`: one run folder per dataset and one table (results.md, results.csv)
whose numbers equal those of single `codeslam slam` runs with the same settings; a dataset without ground truth
(a video) gets n/a instead of metrics; bad input fails before any run."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch
from PIL import Image

from codeslam.cli import main
from codeslam.cli.evaluate_many import COLUMNS, run_names
from codeslam.data.video import write_video
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import save_weights

SLAM_YAML = (
    "tracker:\n  pyramid_levels: [2, 1, 0]\n  max_iterations: [8, 6, 5]\n"
    "window:\n  size: 3\n  sfm:\n    pyramid_levels: [2, 1, 0]\n    max_iterations: [6, 5, 4]\n"
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A 12-frame generator sequence (TUM layout, ground truth), a video of another room, tiny weights, config."""
    root = tmp_path_factory.mktemp("evaluate")
    assert main(["synth", str(root / "a"), "--scenes", "1", "--frames", "12", "--seed", "3", "--size", "128x96",
                 "-q"]) == 0
    assert main(["synth", str(root / "b"), "--scenes", "1", "--frames", "10", "--seed", "5", "--size", "128x96",
                 "-q"]) == 0
    images = [np.asarray(Image.open(p).convert("RGB")) for p in sorted((root / "b/scene_000/rgb").glob("*.png"))]
    video = write_video(root / "phone.mp4", images)
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
                                    full_res_channels=4, bottleneck_channels=4, fc_units=16))
    save_weights(root / "tiny.safetensors", net)
    (root / "slam.yaml").write_text(SLAM_YAML)
    return root / "a" / "scene_000", video, root / "tiny.safetensors", root / "slam.yaml"


def test_table_numbers_equal_the_single_runs(inputs, tmp_path, capsys):
    seq, video, weights, config = inputs
    settings = ["--weights", str(weights), "--config", str(config), "--threads", "1", "-q"]
    out = tmp_path / "table"
    rc = main(["evaluate", str(seq), str(video), "--fov", "60", "--out", str(out), *settings])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["sequence"] for r in rows] == ["scene_000", "phone"]
    assert list(rows[0]) == [c for c, _, _, _ in COLUMNS]
    for name in ("scene_000", "phone"):
        assert (out / name / "report.html").is_file() and (out / name / "result.json").is_file()

    single = tmp_path / "single"
    assert main(["slam", str(seq), "--out", str(single), *settings]) == 0
    capsys.readouterr()
    s = json.loads((single / "result.json").read_text())
    for col, _, key, _ in COLUMNS[1:]:
        if key == "fps":  # wall time, not a result
            continue
        assert float(rows[0][col]) == s[key], (col, rows[0][col], s[key])  # the same run, bit for bit
    assert s["ate_sim3_rmse"] > 0
    # the video has no ground truth: its metrics are empty, not an error
    assert rows[1]["ate_sim3_m"] == "" and int(rows[1]["frames"]) == 10 and float(rows[1]["fps"]) > 0
    md = (out / "results.md").read_text()
    assert "| phone | 10 |" in md and "n/a" in md and f"{s['ate_sim3_rmse']:.4f}" in md
    assert "ATE Sim(3) [m]" in md and "never-moving ATE [m]" in md
    assert "scene_000" in captured.out and "n/a" in captured.out  # the table, printed


def test_bad_input_fails_before_any_run(inputs, tmp_path, capsys):
    seq, video, weights, config = inputs
    out = tmp_path / "out"
    rc = main(["evaluate", str(seq), str(tmp_path / "missing"), "--out", str(out), "--weights", str(weights), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("codeslam: error:") and "not found" in err and "\n" not in err
    assert not out.exists()  # the first dataset did not run
    rc = main(["evaluate", str(seq), "--fov", "60", "--out", str(out), "--weights", str(weights), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "video files only" in err and not out.exists()


def test_run_names_are_unique(tmp_path):
    for p in ("x/scene_000", "y/scene_000", "z"):
        (tmp_path / p).mkdir(parents=True)
    (tmp_path / "z" / "clip.mp4").write_bytes(b"")
    names = run_names([tmp_path / "x/scene_000", tmp_path / "y/scene_000", tmp_path / "z/clip.mp4",
                       tmp_path / "z/clip.mp4"])
    assert names == ["x_scene_000", "y_scene_000", "z_clip", "z_clip_2"]
