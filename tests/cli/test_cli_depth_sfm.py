"""``codeslam depth`` and ``codeslam sfm`` end to end on a tiny generator sequence with a tiny random network:
valid files and JSON, the least-squares property of the optimised code, and bad input rejected with one line and
no output."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from plyfile import PlyData
from safetensors.torch import save_file

from codeslam.cli import main
from codeslam.data.registry import open_dataset
from codeslam.data.trajectory import read_tum
from codeslam.geometry.proximity import depth_to_prox
from codeslam.network import CodeNetwork, NetworkConfig, save_weights

W, H = 64, 48
SFM_FAST = "pyramid_levels: [1, 0]\nmax_iterations: [3, 3]\n"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("depth_sfm")
    assert main(["synth", str(root / "syn"), "--scenes", "1", "--frames", "6", "--size", f"{W}x{H}", "--seed", "3",
                 "--supersample", "1"]) == 0
    seq = root / "syn" / "scene_000"
    torch.manual_seed(0)
    net = CodeNetwork(NetworkConfig(code_size=8, width=W, height=H, image_channels=(4, 8, 8, 8),
                                    depth_channels=(4, 8, 8, 8), full_res_channels=4, bottleneck_channels=4,
                                    fc_units=16))
    save_weights(root / "tiny.safetensors", net)
    (root / "fast.yaml").write_text(SFM_FAST)
    # the same sequence without depth
    nodepth = root / "nodepth"
    nodepth.mkdir()
    for name in ("rgb", "rgb.txt", "calib.txt", "groundtruth.txt"):
        src = seq / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, nodepth / name)
    (root / "junk.safetensors").write_bytes(b"\x00" * 64)
    save_file({"x": torch.zeros(3)}, str(root / "other.safetensors"), metadata={"format": "something-else"})
    return {"root": root, "seq": seq, "weights": root / "tiny.safetensors", "fast": root / "fast.yaml",
            "nodepth": nodepth, "junk": root / "junk.safetensors", "other": root / "other.safetensors"}


def test_depth_cli_writes_depth_uncertainty_panels_and_metrics(work, tmp_path: Path, capsys):
    out, js = tmp_path / "out", tmp_path / "d.json"
    rc = main(["depth", str(work["seq"]), "--frames", "0:6:2", "--mode", "zero,encode", "--mode", "optimise",
               "--weights", str(work["weights"]), "--out", str(out), "--json", str(js), "--threads", "1"])
    assert rc == 0, capsys.readouterr().err
    res = json.loads(js.read_text())
    for key in ("prox_rmse", "depth_abs_rel", "frames", "prox_rmse_constant", "prox_rmse_per_frame"):
        assert key in res
    assert res["frames"] == [0, 2, 4] and res["modes"] == ["zero", "encode", "optimise"]
    rmse = res["prox_rmse"]
    assert set(rmse) == {"zero", "encode", "optimise"} and all(v > 0 for v in rmse.values())
    # a least-squares fit of the code (with its prior) never fits the ground truth worse than the zero code
    assert rmse["optimise"] <= rmse["zero"]
    for fit, zero in zip(res["prox_rmse_per_frame"]["optimise"], res["prox_rmse_per_frame"]["zero"]):
        assert fit <= zero
    # the constant baseline is the standard deviation of the ground-truth proximity over all valid pixels
    seq = open_dataset(work["seq"])
    gt = torch.cat([depth_to_prox(seq[i].depth, res["avg_depth"])[seq[i].depth > 0] for i in (0, 2, 4)]).double()
    assert res["prox_rmse_constant"] == pytest.approx(float(gt.std(unbiased=False)), rel=1e-5)
    assert res["valid_pixels"] == gt.numel()
    for i in (0, 2, 4):
        for mode in ("zero", "encode", "optimise"):
            with Image.open(out / "depth" / mode / f"{i:06d}.png") as im:
                assert im.size == (W, H) and im.mode.startswith("I")
                d = np.asarray(im).astype(np.float64) / 5000.0
            assert (d > 0).mean() > 0.9 and d.max() < 13.2
        with Image.open(out / "uncertainty" / f"{i:06d}.png") as im:
            assert im.size == (W, H) and (np.asarray(im) > 0).all()
        with Image.open(out / "panel" / f"{i:06d}.png") as im:
            assert im.format == "PNG"
    assert json.loads((out / "camera.json").read_text())["width"] == W
    printed = capsys.readouterr().out
    assert "optimise" in printed and "best constant" in printed


def test_sfm_cli_writes_depth_poses_cloud_panel_and_metrics(work, tmp_path: Path, capsys):
    out, js = tmp_path / "sfm", tmp_path / "s.json"
    rc = main(["sfm", str(work["seq"]), "--frames", "2,0,4", "--master", "2", "--weights", str(work["weights"]),
               "--config", str(work["fast"]), "--out", str(out), "--json", str(js), "--threads", "1"])
    assert rc == 0, capsys.readouterr().err
    res = json.loads(js.read_text())
    for key in ("prox_rmse_master", "prox_rmse_master_zero_code", "rel_trans_err", "rel_rot_err_deg", "iterations",
                "ms_per_iteration", "rel_trans_err_scale_aligned", "rel_scale"):
        assert res[key] is not None, key
    assert res["master"] == 2 and res["num_pairs"] == 4 and res["iterations"] > 0 and res["ms_per_iteration"] > 0
    assert len(res["rel_per_frame"]) == 2
    traj = read_tum(out / "poses.txt")
    assert len(traj) == 3
    torch.testing.assert_close(traj.poses[1], torch.eye(4, dtype=torch.float64))  # the gauge: first listed
    assert not torch.allclose(traj.poses[0], torch.eye(4, dtype=torch.float64))
    seq = open_dataset(work["seq"])
    np.testing.assert_allclose(traj.timestamps, seq.timestamps[[0, 2, 4]])
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["000000.png", "000002.png", "000004.png"]
    ply = PlyData.read(str(out / "cloud.ply"))
    n = ply["vertex"].count
    assert 0 < n <= 3 * W * H and n == res["cloud_points"]
    xyz = np.stack([ply["vertex"][c] for c in "xyz"], axis=1)
    assert np.isfinite(xyz).all()
    assert (out / "panel.png").is_file() and (out / "sfm_config.yaml").is_file()
    assert "max_iterations" in (out / "sfm_config.yaml").read_text()


def test_sfm_cli_rolling_shutter_config_reports_the_readout_rotations(work, tmp_path: Path):
    cfg, js = tmp_path / "rs.yaml", tmp_path / "s.json"
    cfg.write_text(SFM_FAST + "rolling_shutter: true\n")
    assert main(["sfm", str(work["seq"]), "--frames", "1,3,4", "--weights", str(work["weights"]),
                 "--config", str(cfg), "--json", str(js), "--threads", "1"]) == 0
    rs = json.loads(js.read_text())["readout_rotation_rad"]
    assert len(rs) == 3 and all(len(r) == 3 and all(math.isfinite(x) for x in r) for r in rs)


def test_sfm_cli_all_pairs_without_outputs(work, tmp_path: Path):
    js = tmp_path / "s.json"
    assert main(["sfm", str(work["seq"]), "--frames", "1,3", "--pairs", "all", "--weights", str(work["weights"]),
                 "--config", str(work["fast"]), "--json", str(js), "--threads", "1"]) == 0
    res = json.loads(js.read_text())
    assert res["num_pairs"] == 2 and res["master"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]


def _bad_cases(work) -> list[list[str]]:
    seq, w = str(work["seq"]), str(work["weights"])
    return [
        ["depth", str(work["root"] / "missing"), "--frames", "0", "--weights", w],
        ["depth", seq, "--frames", "0,100", "--weights", w],
        ["depth", seq, "--frames", "0", "--mode", "magic", "--weights", w],
        ["depth", str(work["nodepth"]), "--frames", "0", "--mode", "encode", "--weights", w],
        ["depth", str(work["nodepth"]), "--frames", "0", "--mode", "optimise", "--weights", w],
        ["depth", seq, "--frames", "0", "--weights", str(work["junk"])],
        ["depth", seq, "--frames", "0", "--weights", str(work["root"] / "nothing.safetensors")],
        ["depth", seq, "--frames", "0", "--weights", w, "--fit-sigma", "0"],
        ["sfm", str(work["root"] / "missing"), "--frames", "0,1", "--weights", w],
        ["sfm", seq, "--frames", "0", "--weights", w],
        ["sfm", seq, "--frames", "0,7", "--weights", w],
        ["sfm", seq, "--frames", "0,1", "--master", "3", "--weights", w],
        ["sfm", seq, "--frames", "0,1", "--pairs", "some", "--weights", w],
        ["sfm", seq, "--frames", "0,1", "--init", "magic", "--weights", w],
        ["sfm", seq, "--frames", "0,1", "--weights", str(work["junk"])],
        ["sfm", seq, "--frames", "0,1", "--weights", w, "--config", str(work["junk"])],
        ["depth", seq, "--frames", "0", "--weights", w, "--device", "gpu"],
        ["sfm", seq, "--frames", "0,1", "--weights", w, "--threads", "0"],
        ["sfm", seq, "--frames", "0,1", "--weights", str(work["other"])],
    ]


@pytest.mark.parametrize("case", range(19))
def test_bad_input_is_one_line_nonzero_and_writes_nothing(work, tmp_path: Path, capsys, case: int):
    args = _bad_cases(work)[case]
    out, js = tmp_path / "out", tmp_path / "r.json"
    rc = main([*args, "--out", str(out), "--json", str(js)])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("codeslam: error:"), err
    assert not out.exists() and not js.exists()
