"""No half-written output after SIGKILL (issue 6, item 3), for the generator's training shards: every shard on
disk is complete, temporaries are hidden names that no reader picks up, and running the same command again
finishes the set, skipping the complete shards, with the bytes an uninterrupted run writes.

(Training killed with SIGKILL and resumed: tests/network/test_network_train.py::test_resume_after_sigkill.)
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from codeslam.cli import main
from codeslam.network.data import shard_files
from codeslam.synth.shards import read_shard

REPO = Path(__file__).resolve().parents[2]
ARGS = ["--train", "--views", "48", "--views-per-scene", "2", "--shard-size", "2", "--size", "16x16", "--seed", "3"]


def test_sigkilled_shard_generation_leaves_only_complete_shards_and_resumes(tmp_path, capsys):
    out = tmp_path / "killed"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "codeslam", "synth", str(out), *ARGS], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(shard_files(out) if out.is_dir() else []) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()
    done = shard_files(out)
    assert 2 <= len(done) < 24, "the run was not interrupted mid-way"
    for path in done:  # every shard a reader sees is complete
        image, depth, cam = read_shard(path)
        assert image.shape == (2, 3, 16, 16) and depth.shape == (2, 16, 16)
    assert all(p.name.startswith(".") for p in out.iterdir() if p not in done)  # only hidden temporaries

    assert main(["synth", str(out), *ARGS]) == 0
    summary = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert f"{24 - len(done)} written, {len(done)} already there" in summary
    assert main(["synth", str(tmp_path / "straight"), *ARGS]) == 0
    straight = shard_files(tmp_path / "straight")
    assert [p.name for p in shard_files(out)] == [p.name for p in straight]
    for a, b in zip(shard_files(out), straight):
        assert a.read_bytes() == b.read_bytes(), a.name
