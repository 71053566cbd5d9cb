"""``benchmarks/bench_decode.py``: it runs and prints both types of the code Jacobian, and bad input is one
``bench_decode:`` line and a non-zero exit, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_decode.py"


def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BENCH), "--threads", "1", "--repeats", "1", *args],
                          capture_output=True, text=True, timeout=300)


def test_it_times_both_types_against_float32():
    p = _bench()
    assert p.returncode == 0, p.stderr
    rows = [line.split() for line in p.stdout.splitlines() if line.startswith("  ")]
    assert [r[0] for r in rows] == ["float32", "bfloat16"]
    assert rows[0][rows[0].index("float32", 1) + 1] == "1.000"  # the ratio of float32 to itself


def test_a_missing_weights_file_or_image_is_one_line(tmp_path):
    for args, phrase in ((("--weights", str(tmp_path / "missing.safetensors")), "missing.safetensors"),
                         (("--image", str(tmp_path / "missing.png")), "not found")):
        p = _bench(*args)
        assert p.returncode != 0 and "Traceback" not in p.stderr
        lines = [line for line in p.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("bench_decode:") and phrase in lines[0], p.stderr
