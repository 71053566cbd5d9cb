"""`codeslam demo`: synth + slam on the embedded default data, here with a tiny random network so the test
does not depend on the shipped weights' quality."""

import json

import torch

from codeslam.cli import main
from codeslam.data.trajectory import read_tum
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import save_weights


def test_demo_runs_synth_then_slam_and_evaluates(tmp_path):
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
                                    full_res_channels=4, bottleneck_channels=4, fc_units=16))
    save_weights(tmp_path / "tiny.safetensors", net)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--frames", "6", "--weights", str(tmp_path / "tiny.safetensors"),
                 "--threads", "1"]) == 0
    gt = read_tum(out / "data" / "scene_000" / "groundtruth.txt")
    est = read_tum(out / "slam" / "trajectory.txt")
    assert len(gt) == len(est) == 6
    summary = json.loads((out / "slam" / "result.json").read_text())
    # the run is evaluated against the generator's ground truth, beside the no-motion baseline
    assert summary["ate_se3_rmse"] >= 0
    assert summary["no_motion_ate_rmse"] > 0


def test_demo_refuses_an_output_path_that_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["demo", "--out", str(blocker / "demo"), "--frames", "6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("codeslam: error:")
