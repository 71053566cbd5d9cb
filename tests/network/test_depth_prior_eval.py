"""``scripts/depth_prior_eval.py``'s statistics (issue 13's prior table) on depths with known errors: the ratio to
the best constant, the median depth ratio, the shape error after each frame's scale and the spread and jump of
the per-frame scales."""

import math
from pathlib import Path

import torch

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "depth_prior_eval.py"


def test_per_frame_scales_give_spread_and_jump_and_no_shape_error(script):
    a = 1.5
    gen = torch.Generator().manual_seed(0)
    depth = 0.5 + 3.0 * torch.rand(4, 12, 16, generator=gen)  # (frames, H, W) metres
    depth[:, 0, :3] = 0.0  # invalid pixels are ignored
    scales = torch.tensor([0.5, 1.0, 2.0, 1.0])
    pred = depth * scales[:, None, None]
    stats = script("depth_prior_eval").PriorStats()
    stats.add(a / (pred[:2] + a), depth[:2], a)  # two batches, in order: the jump runs across them
    stats.add(a / (pred[2:] + a), depth[2:], a)
    r = stats.result()
    logs = torch.log(scales).double()
    assert math.isclose(r["scale_spread"], float(logs.std()), rel_tol=1e-5)
    assert math.isclose(r["scale_jump"], float((logs[1:] - logs[:-1]).abs().mean()), rel_tol=1e-5)
    assert r["si_rmse"] < 1e-6  # each frame exact after its own scale
    assert r["pixels"] == 4 * (12 * 16 - 3)
    assert 0.5 <= r["median_depth_ratio"] <= 2.0


def test_exact_prediction_and_constant_prediction(script):
    a = 1.5
    depth = torch.linspace(0.5, 4.0, 2 * 8 * 8).reshape(2, 8, 8)
    PriorStats = script("depth_prior_eval").PriorStats
    stats = PriorStats()
    stats.add(a / (depth + a), depth, a)
    r = stats.result()
    assert r["zero_rmse"] < 1e-6 and r["ratio"] < 1e-5 and math.isclose(r["median_depth_ratio"], 1.0, rel_tol=1e-5)
    assert r["scale_spread"] < 1e-6 and r["scale_jump"] < 1e-6
    const = PriorStats()
    g = a / (depth + a)
    const.add(torch.full_like(depth, float(g.double().mean())), depth, a)  # the best single constant
    assert math.isclose(const.result()["ratio"], 1.0, rel_tol=1e-4)


def test_an_unknown_or_malformed_set_is_a_one_line_error():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(SCRIPT), "--only", "tum,nope"], capture_output=True, text=True)
    assert out.returncode == 2 and "no default set nope" in out.stderr and "Traceback" not in out.stderr
    out = subprocess.run([sys.executable, str(SCRIPT), "--set", "a/path"], capture_output=True, text=True)
    assert out.returncode == 2 and "--set takes name=PATH" in out.stderr and "Traceback" not in out.stderr


def test_span_scale_finds_where_the_code_span_holds_the_truth(script):
    """A zero code at the true scale with a fine texture printed into it, and one code direction that reaches the
    truth at half that scale: the span holds the truth best at s = 0.5 (error ~0), worse at s = 1; one that reaches it
    at twice that scale, at s = 2."""
    module = script("depth_prior_eval")
    a = 1.5
    H, W = 24, 32
    v, u = torch.meshgrid(torch.linspace(0, 1, H, dtype=torch.float64), torch.linspace(0, 1, W, dtype=torch.float64),
                          indexing="ij")
    depth = 2.0 + 3.0 * v + 0.5 * u  # a floor-like ramp, metres
    depth[0, :4] = 0.0  # invalid pixels are ignored
    texture = 0.02 * torch.sign(torch.sin(40 * u) * torch.sin(30 * v))  # proximity the truth does not have
    prox0 = a / (depth + a) + texture
    reach = a / (0.5 * depth + a) - prox0  # the one direction: the truth at half scale
    jac = reach[None]
    fits = module.span_fit(prox0, jac, depth, a)
    assert set(fits) == set(module.SPAN_SCALES)
    assert min(fits, key=fits.get) == 0.5 and fits[0.5] < 1e-3 < fits[1.0]
    r = module.span_summary([fits, fits, fits])
    assert r["span_scale"] == 0.5 and r["span_error"] < 1e-3 and r["span_error_1"] == fits[1.0]
    assert module.span_summary([]) == {}
    # A span that holds the truth at twice the zero code's depth is read at 2, not at the grid's end (a corridor's
    # first views are held at 1.6-2.3).
    far = module.span_fit(prox0, (a / (2.0 * depth + a) - prox0)[None], depth, a)
    assert min(far, key=far.get) == 2.0 and far[2.0] < 1e-3 < far[1.5]


def test_generator_sets_are_rendered_where_the_defaults_point(tmp_path, script):
    """A missing held-out generator set is rendered under --data-dir with its data version and seed (the figures
    of docs/results come from these sets, so a fresh clone must be able to make them); an unknown set is not."""
    module = script("depth_prior_eval")
    sets = module.default_sets(tmp_path)
    assert sets["gen_v3"] == str(tmp_path / "val128_v3")
    assert sets["cabinet"] == str(tmp_path / "real_split" / "val" / "tum_fr3_cabinet_kf")
    path = Path(sets["gen_v3"])
    assert module.prepare_set("gen_v3", path, tmp_path, views=16)
    from safetensors import safe_open

    with safe_open(str(next(path.glob("shard_*.safetensors"))), "pt") as f:
        meta = f.metadata()
    assert (meta["seed"], meta["data_version"], meta["views"]) == ("4002", "3", "16")
    assert not module.prepare_set("mine", tmp_path / "mine", tmp_path)


def test_a_set_that_cannot_be_made_says_why_and_the_real_sets_are_the_split_folders(tmp_path, capsys, script):
    """A failed rendering prints its command's last error line (it was swallowed before) and makes nothing; the
    real validation sets name exactly the folders ``scripts/split_real_rgbd.py`` splits."""
    module = script("depth_prior_eval")
    assert not module.prepare_set("gen_v3", tmp_path / "v3", tmp_path, views=0)
    assert "could not make gen_v3: codeslam: error: --views must be at least 1, got 0" in capsys.readouterr().out
    assert not (tmp_path / "v3").exists()
    assert sorted(module.REAL_SETS.values()) == sorted(script("split_real_rgbd").TRAIN_FRAMES)


def test_the_table_shows_the_span_only_where_it_was_computed_and_no_nan(script):
    module = script("depth_prior_eval")
    r = {"frames": 1, "zero_rmse": 0.07, "const_rmse": 0.04, "ratio": 1.65, "median_depth_ratio": 0.81,
         "si_rmse": 0.05, "scale_spread": float("nan"), "scale_jump": float("nan")}
    header, rule = module.table_header(span=False)
    row = module.table_row("shipped", "office", r, span=False)
    assert "span" not in header and row.count("|") == header.count("|") == rule.count("|")
    assert row == "| shipped | office | 1 | 0.0700 | 0.0400 | 1.65 | 0.81 | 0.0500 | - | - |"
    r |= {"span_scale": 0.5, "span_error": 0.031, "span_error_1": 0.052}
    header, rule = module.table_header(span=True)
    row = module.table_row("w", "tum", r, span=True)
    assert "span scale" in header and row.count("|") == header.count("|") == rule.count("|")
    assert row.endswith("| - | - | 0.50 | 0.031 | 0.052 |")
