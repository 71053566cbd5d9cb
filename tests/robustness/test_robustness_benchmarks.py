"""``benchmarks/bench_slam.py`` with bad input: one ``bench_slam:`` line and a non-zero exit, never a traceback and
never a hang. Each run is a child process; before, a child that failed left the parent waiting forever on its
result (a wrong ``--dataset`` path hung the bench)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from corpus import tum_folder

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_slam.py"


def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BENCH), "--preset", "", "--threads", "1", *args],
                          capture_output=True, text=True, timeout=300)


def _assert_one_line(p: subprocess.CompletedProcess, phrase: str) -> None:
    assert p.returncode != 0
    assert "Traceback" not in p.stderr
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("bench_slam:") and phrase in lines[0], p.stderr


def test_a_missing_dataset_stops_the_bench_before_any_run(tmp_path):
    _assert_one_line(_bench("--dataset", str(tmp_path / "missing")), "not found")


def test_a_run_that_fails_in_its_process_stops_the_bench_with_its_error(tmp_path):
    seq = tum_folder(tmp_path / "seq", n=3)
    p = _bench("--dataset", str(seq), "--weights", str(tmp_path / "missing.safetensors"), "--modes", "sequential")
    _assert_one_line(p, "the sequential run failed")
