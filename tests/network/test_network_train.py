"""Training: the network can fit a batch, runs resume deterministically (also after SIGKILL), DDP works."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from codeslam.cli import main
from codeslam.errors import ConfigError
from codeslam.network.config import RunConfig, TrainConfig
from codeslam.network.loss import network_loss, proximity_pyramid
from codeslam.network.model import CodeNetwork
from codeslam.network.train import kl_weight_at, learning_rate
from codeslam.network.weights import load_model, read_weights

REPO = Path(__file__).resolve().parents[2]


def _train_cli(shards: Path, out: Path, cfg: Path, *extra: str) -> int:
    return main(["train", "--data", str(shards), "--out", str(out), "--config", str(cfg), "--no-progress", *extra])


def _last_row(path: Path) -> dict:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))[-1]


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return read_weights(path)[0]


def test_overfits_a_single_batch(tiny_config, synthetic_frames):
    torch.manual_seed(0)
    model = CodeNetwork(tiny_config()).train()
    images, depth = synthetic_frames(4, 32, 32)
    image = images.float().mean(1, keepdim=True) / 255
    prox = proximity_pyramid(depth[:, None], 2.0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses, rmse = [], []
    for _ in range(150):
        out = model(image, prox[0])
        parts = network_loss(out.mu, out.b, prox, out.code_mean, out.code_logvar, kl_weight=1.0)
        opt.zero_grad()
        parts.total.backward()
        opt.step()
        losses.append(float(parts.total.detach()))
        valid = prox[0] > 0
        rmse.append(float((out.mu[0].detach() - prox[0])[valid].square().mean().sqrt()))
    assert losses[-1] < losses[0] - 1.0  # nats per pixel
    assert rmse[-1] < 0.5 * rmse[0]


def test_schedules():
    cfg = TrainConfig(steps=101, lr=1e-4, lr_final=1e-6, kl_weight=2.0, kl_warmup_steps=10)
    for sched in ("cosine", "exponential"):
        c = TrainConfig(**{**cfg.to_dict(), "lr_schedule": sched})
        lrs = [learning_rate(s, c) for s in range(101)]
        assert lrs[0] == pytest.approx(1e-4) and lrs[-1] == pytest.approx(1e-6)
        assert all(a >= b for a, b in zip(lrs, lrs[1:], strict=False))
    assert learning_rate(50, TrainConfig(**{**cfg.to_dict(), "lr_schedule": "exponential"})) == pytest.approx(1e-5)
    assert [kl_weight_at(s, cfg) for s in (0, 5, 10, 50)] == [0.0, 1.0, 2.0, 2.0]


def test_resume_is_deterministic(tmp_path, tiny_shards, tiny_yaml):
    """Stopping after 3 steps (as if interrupted) and resuming to 8 gives the same weights and loss as a straight
    run to 8. Exact on one machine; compared to 1e-6 so that a change of BLAS threading cannot flake."""
    straight, split = tmp_path / "straight", tmp_path / "split"
    assert _train_cli(tiny_shards, straight, tiny_yaml, "--steps", "8") == 0
    assert _train_cli(tiny_shards, split, tiny_yaml, "--steps", "8", "--stop-after", "3") == 0
    assert (split / "checkpoint.safetensors").is_file() and not (split / "weights.safetensors").exists()
    assert _train_cli(tiny_shards, split, tiny_yaml, "--steps", "8") == 2  # refuses to overwrite without --resume
    assert main(["train", "--data", str(tiny_shards), "--out", str(split), "--resume", "--no-progress"]) == 0
    assert _train_cli(tiny_shards, split, tiny_yaml, "--resume", "--batch-size", "2") == 2  # can't change batch
    a, b = _weights(straight / "weights.safetensors"), _weights(split / "weights.safetensors")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-6, atol=1e-7)
    row_a, row_b = _last_row(straight / "log.csv"), _last_row(split / "log.csv")
    assert row_a["step"] == row_b["step"] == "8"
    assert float(row_a["loss"]) == pytest.approx(float(row_b["loss"]), rel=1e-6)
    assert _last_row(straight / "val.csv") == _last_row(split / "val.csv")
    assert load_model(split / "checkpoint.safetensors").config == load_model(straight / "weights.safetensors").config


def test_resume_after_sigkill(tmp_path, tiny_shards, tiny_yaml):
    """A real SIGKILL in the middle of a run: resuming from the last checkpoint ends like an uninterrupted run."""
    cfg = tmp_path / "ckpt2.yaml"
    cfg.write_text(tiny_yaml.read_text() + "  checkpoint_every: 2\n")
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    args = ["train", "--data", str(tiny_shards), "--config", str(cfg), "--steps", "40", "--no-progress"]
    proc = subprocess.Popen([sys.executable, "-m", "codeslam", *args, "--out", str(killed), "--threads", "1"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not (killed / "checkpoint.safetensors").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()
    assert not (killed / "weights.safetensors").exists()  # it really was interrupted
    # the same command with --resume (one thread here, by the fixture, like the killed process)
    assert main([*args, "--out", str(killed), "--resume"]) == 0
    assert main([*args, "--out", str(straight)]) == 0
    a, b = _weights(straight / "weights.safetensors"), _weights(killed / "weights.safetensors")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-6, atol=1e-7)
    assert float(_last_row(killed / "log.csv")["loss"]) == pytest.approx(float(_last_row(straight / "log.csv")["loss"]),
                                                                        rel=1e-6)


def test_sigterm_stops_with_a_checkpoint(tmp_path, tiny_shards, tiny_yaml):
    """SIGTERM (a scheduler, or Ctrl-C as SIGINT) finishes the step, writes a checkpoint and exits cleanly."""
    out = tmp_path / "term"
    proc = subprocess.Popen([sys.executable, "-m", "codeslam", "train", "--data", str(tiny_shards), "--out", str(out),
                             "--config", str(tiny_yaml), "--steps", "100000", "--no-progress", "--threads", "1"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (out / "log.csv").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "stopped by signal" in stdout and not (out / "weights.safetensors").exists()
    from codeslam.network.train import read_run_config
    from codeslam.network.weights import read_tensors

    _, meta = read_tensors(out / "checkpoint.safetensors")
    assert 2 <= int(meta["step"]) < 100000
    assert int(_last_row(out / "log.csv")["step"]) == int(meta["step"])  # the log ends where the checkpoint is
    assert read_run_config(out).train.steps == 100000


def test_ddp_two_processes(tmp_path, tiny_shards, tiny_yaml):
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "codeslam", "train", "--data", str(tiny_shards), "--out", str(out), "--config", str(tiny_yaml),
           "--steps", "4", "--no-progress"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "2 process(es)" in res.stdout
    model = load_model(out / "weights.safetensors")
    assert model.config.code_size == 8
    rows = list(csv.DictReader(open(out / "log.csv", newline="")))
    assert [r["step"] for r in rows] == ["2", "4"]
    assert all(torch.isfinite(torch.tensor(float(r["loss"]))) for r in rows)


def test_cli_user_errors(tmp_path, tiny_shards, tiny_yaml, capsys):
    assert main(["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "r")]) == 2
    assert "training data not found" in capsys.readouterr().err
    assert main(["train", "--data", str(tiny_shards), "--out", str(tmp_path / "r"), "--size", "100x96"]) == 2
    assert "multiple of 16" in capsys.readouterr().err
    assert main(["train", "--data", str(tiny_shards), "--out", str(tmp_path / "r"), "--size", "big"]) == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err


def test_train_library_call_with_two_sources(tmp_path, tiny_shards, tiny_config):
    """``--data A B``: several sources; the run folder holds config, logs, checkpoint and loadable weights."""
    from codeslam.network.train import train

    shards = sorted(tiny_shards.glob("shard_*.safetensors"))
    cfg = RunConfig(tiny_config(), TrainConfig(steps=3, batch_size=4, log_every=1, val_every=3))
    res = train(shards, tmp_path / "run", cfg, progress=False, log=None)
    assert res.finished and res.step == 3 and set(res.val) >= {"val_rmse_zero", "val_rmse_encode"}
    assert {p.name for p in (tmp_path / "run").iterdir()} >= {
        "config.yaml", "log.csv", "val.csv", "checkpoint.safetensors", "weights.safetensors"}
    assert main(["train", "--data", *map(str, shards), "--out", str(tmp_path / "cli"), "--steps", "1",
                 "--batch-size", "4", "--code-size", "8", "--size", "32x32", "--no-progress"]) == 0


def test_fine_tuning_starts_from_the_given_weights(tmp_path, tiny_shards, tiny_yaml, tiny_config):
    from codeslam.network.weights import save_weights

    torch.manual_seed(123)
    start = CodeNetwork(tiny_config())
    save_weights(tmp_path / "start.safetensors", start)
    assert _train_cli(tiny_shards, tmp_path / "ft", tiny_yaml, "--steps", "1", "--init",
                      str(tmp_path / "start.safetensors")) == 0
    assert _train_cli(tiny_shards, tmp_path / "scratch", tiny_yaml, "--steps", "1") == 0
    ref = start.state_dict()

    def dist(run: str) -> float:
        w = _weights(tmp_path / run / "weights.safetensors")
        return sum(float((w[k].float() - ref[k].float()).abs().sum()) for k in ref if ref[k].is_floating_point())

    assert dist("ft") < 0.05 * dist("scratch")  # one small Adam step away from the start, not from random weights
    cfg = (tmp_path / "ft" / "config.yaml").read_text()
    assert "init_weights: " + str(tmp_path / "start.safetensors") in cfg
    wrong = tiny_config(code_size=4)
    save_weights(tmp_path / "wrong.safetensors", CodeNetwork(wrong))
    assert _train_cli(tiny_shards, tmp_path / "bad", tiny_yaml, "--steps", "1", "--init",
                      str(tmp_path / "wrong.safetensors")) != 0


def test_code_scale_moves_only_the_code_paths_targets(tiny_config, synthetic_frames):
    """``train.code_scale``: the same step (weights, augmentation, code sample) gives the same zero-code NLL, a
    different reconstruction NLL, and with code_scale 0 the step of before to the bit."""
    from codeslam.network.data import DEPTH_UNITS_PER_M, FrameStore
    from codeslam.network.train import train_step

    images, depth = synthetic_frames(4, 32, 32)
    store = FrameStore(images, (depth * DEPTH_UNITS_PER_M).round().to(torch.uint16), [("s", 0, 4)])
    ncfg, idx = tiny_config(), torch.arange(4)

    def step(code_scale: float):
        torch.manual_seed(0)
        net = CodeNetwork(ncfg).train()
        cfg = RunConfig(ncfg, TrainConfig(code_scale=code_scale, exposure=0.5))
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        parts = train_step(net, opt, store, idx, 3, cfg, 1e-3, 1.0, 0, torch.device("cpu"))
        return parts._replace(**{k: v.detach() for k, v in parts._asdict().items() if torch.is_tensor(v)})

    plain, again, scaled = step(0.0), step(0.0), step(0.7)
    assert float(plain.total) == float(again.total)
    assert float(scaled.nll_zero) == pytest.approx(float(plain.nll_zero), rel=1e-6)
    assert abs(float(scaled.nll) - float(plain.nll)) > 1e-3
    with pytest.raises(ConfigError, match="code_scale"):
        TrainConfig(code_scale=-0.1)


def test_shape_weight_adds_the_zero_codes_shape_error(tiny_config, synthetic_frames):
    """``train.shape_weight``: the step's total gains exactly shape_weight times the zero code's shape error; at 0
    the term is neither computed nor added (logged as 0); without the zero code's NLL the zero code is still
    decoded for it."""
    from codeslam.network.data import DEPTH_UNITS_PER_M, FrameStore
    from codeslam.network.train import train_step

    images, depth = synthetic_frames(4, 32, 32)
    store = FrameStore(images, (depth * DEPTH_UNITS_PER_M).round().to(torch.uint16), [("s", 0, 4)])
    ncfg, idx = tiny_config(), torch.arange(4)

    def step(shape_weight: float, zero_code_weight: float = 1.0):
        torch.manual_seed(0)
        net = CodeNetwork(ncfg).train()
        cfg = RunConfig(ncfg, TrainConfig(shape_weight=shape_weight, zero_code_weight=zero_code_weight))
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        parts = train_step(net, opt, store, idx, 3, cfg, 1e-3, 1.0, 0, torch.device("cpu"))
        return parts._replace(**{k: v.detach() for k, v in parts._asdict().items() if torch.is_tensor(v)})

    plain, shaped = step(0.0), step(2.0)
    assert float(plain.shape) == 0.0 and float(shaped.shape) > 0
    assert float(shaped.total) == pytest.approx(float(plain.total) + 2.0 * float(shaped.shape), rel=1e-6)
    alone = step(2.0, zero_code_weight=0.0)  # the zero code is decoded for the shape term alone too
    assert float(alone.shape) == pytest.approx(float(shaped.shape), rel=1e-6)
    assert float(alone.total) == pytest.approx(float(shaped.total) - float(shaped.nll_zero), rel=1e-6)
    with pytest.raises(ConfigError, match="shape_weight"):
        TrainConfig(shape_weight=-1.0)
