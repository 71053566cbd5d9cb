"""`codeslam demo`: synth + slam on the embedded default data. The reported ATE is the one `codeslam eval` computes
from the files the demo wrote, and with the shipped weights it meets the accuracy the README states."""

import json
import math

import torch

from codeslam.cli import main
from codeslam.data.trajectory import read_tum
from codeslam.network.config import NetworkConfig
from codeslam.network.model import CodeNetwork
from codeslam.network.weights import save_weights

#: The README reports 0.027 m ATE after SE(3) alignment for `codeslam demo` (60 frames, seed 3, shipped weights,
#: version 3; 0.028-0.035 m at earlier commits and on other CPUs; version 1 gave 0.024), against 0.165 m for the
#: best camera that never moves. The run is deterministic up to floating-point summation order (thread count, CPU),
#: so twice the largest figure the README has stated leaves room for that and for small changes of the system, and
#: still fails a regression that doubles the error or a run no better than 40% of standing still.
README_DEMO_ATE = 0.035
DEMO_ATE_LIMIT = 2 * README_DEMO_ATE
#: trajectory.txt holds positions to 1e-9 m, so an ATE computed from the file can differ from the one computed in
#: memory by about that much (measured 6.5e-11 m, 2.4e-9 relative); any other difference (other poses, other
#: matching or alignment) is orders of magnitude larger.
FILE_PRECISION_M = 1e-8


def _eval_ate(capsys, tmp_path, demo_out) -> float:
    """ATE (SE(3) alignment) that `codeslam eval` computes from the demo's trajectory and ground-truth files."""
    js = tmp_path / "eval.json"
    assert main(["eval", str(demo_out / "slam" / "trajectory.txt"),
                 str(demo_out / "data" / "scene_000" / "groundtruth.txt"), "--json", str(js)]) == 0
    capsys.readouterr()
    ev = json.loads(js.read_text())
    assert ev["align"] == "se3"
    return ev["ate_rmse"]


def test_demo_runs_synth_then_slam_and_evaluates(tmp_path, capsys):
    """The plumbing, fast: a tiny random network (its accuracy means nothing) on 6 frames."""
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, image_channels=(4, 8, 8, 8), depth_channels=(4, 8, 8, 8),
                                    full_res_channels=4, bottleneck_channels=4, fc_units=16))
    save_weights(tmp_path / "tiny.safetensors", net)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--frames", "6", "--weights", str(tmp_path / "tiny.safetensors"),
                 "--threads", "1", "--quiet"]) == 0
    gt = read_tum(out / "data" / "scene_000" / "groundtruth.txt")
    est = read_tum(out / "slam" / "trajectory.txt")
    assert len(gt) == len(est) == 6
    summary = json.loads((out / "slam" / "result.json").read_text())
    # the run is evaluated against the generator's ground truth, beside the no-motion baseline
    assert math.isfinite(summary["ate_se3_rmse"]) and summary["n_matched"] == 6
    assert math.isclose(summary["ate_se3_rmse"], _eval_ate(capsys, tmp_path, out), rel_tol=0,
                        abs_tol=FILE_PRECISION_M)
    assert summary["no_motion_ate_rmse"] > 0


def test_demo_with_the_shipped_weights_meets_the_readme(tmp_path, capsys):
    """`codeslam demo` as the README runs it (about 30-60 s here)."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--quiet"]) == 0
    s = json.loads((out / "slam" / "result.json").read_text())
    print(f"demo ATE {s['ate_se3_rmse']:.4f} m SE(3), {s['ate_sim3_rmse']:.4f} m Sim(3); no motion "
          f"{s['no_motion_ate_rmse_aligned']:.4f} m aligned; {s['keyframes']} keyframes, "
          f"{s['tracking_failures']} tracking failures")
    ate = s["ate_se3_rmse"]
    assert math.isfinite(ate) and s["n_matched"] == s["frames"] == 60
    assert math.isclose(ate, _eval_ate(capsys, tmp_path, out), rel_tol=0, abs_tol=FILE_PRECISION_M)
    assert ate < DEMO_ATE_LIMIT, f"demo ATE {ate:.4f} m, README states {README_DEMO_ATE} m"
    assert ate < s["no_motion_ate_rmse_aligned"] / 3


def test_demo_refuses_an_output_path_that_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["demo", "--out", str(blocker / "demo"), "--frames", "6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("codeslam: error:")
