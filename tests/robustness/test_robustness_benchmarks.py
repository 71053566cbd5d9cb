"""``benchmarks/bench_slam.py`` and ``bench_cli.py`` with bad input: one ``bench_slam:`` (``bench_cli:``) line and a
non-zero exit, never a traceback and never a hang. Each run is a child process; before, a child that failed left
the parent waiting forever on its result (a wrong ``--dataset`` path hung the bench)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from corpus import tum_folder

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _bench(*args: str, script: str = "bench_slam") -> subprocess.CompletedProcess:
    extra = ["--preset", ""] if script == "bench_slam" else []
    return subprocess.run([sys.executable, str(BENCHMARKS / f"{script}.py"), *extra, "--threads", "1", *args],
                          capture_output=True, text=True, timeout=300)


def _assert_one_line(p: subprocess.CompletedProcess, phrase: str, script: str = "bench_slam") -> None:
    assert p.returncode != 0
    assert "Traceback" not in p.stderr
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{script}:") and phrase in lines[0], p.stderr


def test_a_missing_dataset_stops_the_bench_before_any_run(tmp_path):
    _assert_one_line(_bench("--dataset", str(tmp_path / "missing")), "not found")


def test_a_run_that_fails_in_its_process_stops_the_bench_with_its_error(tmp_path):
    seq = tum_folder(tmp_path / "seq", n=3)
    p = _bench("--dataset", str(seq), "--weights", str(tmp_path / "missing.safetensors"), "--modes", "sequential")
    _assert_one_line(p, "the sequential run failed")


def test_the_whole_process_bench_refuses_a_missing_dataset_or_configuration_before_any_run(tmp_path):
    seq = tum_folder(tmp_path / "seq", n=3)
    _assert_one_line(_bench(str(tmp_path / "missing"), script="bench_cli"), "dataset not found", "bench_cli")
    _assert_one_line(_bench(str(seq), "--config", str(tmp_path / "none.yaml"), script="bench_cli"),
                     "configuration file not found", "bench_cli")


def test_the_whole_process_bench_stops_with_the_failed_runs_own_error(tmp_path):
    seq = tum_folder(tmp_path / "seq", n=3)
    p = _bench(str(seq), "--weights", str(tmp_path / "missing.safetensors"), "--modes", "sequential", "--rounds", "1",
               script="bench_cli")
    _assert_one_line(p, "weights file not found", "bench_cli")


def test_the_whole_process_bench_prints_each_cells_medians_and_the_ratio(tmp_path):
    seq = tum_folder(tmp_path / "seq", n=4)
    cfg = tmp_path / "f32.yaml"
    cfg.write_text("jacobian_dtype: float32\n")
    out = tmp_path / "runs.json"
    p = _bench(str(seq), "--modes", "sequential", "--rounds", "1", "--config", "default", str(cfg), "--json", str(out),
               script="bench_cli")
    assert p.returncode == 0, p.stderr
    for row in ("wall s", "frames/s, whole process", "frames/s, its summary", "CPU s", "peak memory MB",
                "failed frames", "ATE Sim(3) m"):
        assert any(line.startswith(row) for line in p.stdout.splitlines()), (row, p.stdout)
    assert "seq sequential: f32 / default whole-process frames/s = " in p.stdout
    runs = json.loads(out.read_text())
    assert sorted(runs) == sorted(f"{seq} sequential {c}" for c in ("default", str(cfg)))
    for cell in runs.values():
        assert len(cell) == 1 and cell[0]["frames"] == 4 and cell[0]["wall_s"] > 0 and cell[0]["cpu_s"] > 0
