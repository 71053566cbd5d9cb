"""The same bad inputs through every command that reads a dataset and weights (``depth``, ``sfm``, ``slam``): one
``codeslam: error:`` line, exit 2, no traceback, nothing left in ``--out``, nothing unpickled or executed.

Only the contract and a key phrase of each message are checked, so that the commands' own tests stay the place
for their exact wording. A command that is missing fails (it is never skipped).
"""

from __future__ import annotations

import os

import pytest
from corpus import (
    assert_clean_failure,
    pickle_payload,
    run_cli,
    tiny_weights,
    torch_save_payload,
    tum_folder,
    yaml_payload,
)

from codeslam.cli.app import app

COMMANDS = {c.name or c.callback.__name__ for c in app.registered_commands}
#: the arguments each command needs besides DATASET, --weights and --out
EXTRA = {"depth": ["--frames", "0"], "sfm": ["--frames", "0,1"], "slam": ["-q"]}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    base = tmp_path_factory.mktemp("commands")
    return {"seq": tum_folder(base / "seq", n=3), "one": tum_folder(base / "one", n=1),
            "weights": tiny_weights(base / "w.safetensors")}


def _run(capsys, command, dataset, weights, out, *extra):
    return run_cli(capsys, command, dataset, "--weights", weights, "--out", out, *EXTRA[command], *extra)


def test_the_commands_under_test_are_registered():
    """A command that disappeared (or was renamed) is a failure here, not a silently skipped corpus."""
    assert {"depth", "sfm", "slam"} <= COMMANDS, sorted(COMMANDS)


@pytest.mark.parametrize("command", ["depth", "sfm", "slam"])
@pytest.mark.parametrize("case", ["truncated", "random_bytes", "pickle", "torch_zip", "missing"])
def test_bad_weights(tmp_path, capsys, files, command, case):
    marker = tmp_path / "PWNED"
    path = tmp_path / "w.safetensors"
    if case == "truncated":
        path.write_bytes(files["weights"].read_bytes()[:3000])
    elif case == "random_bytes":
        path.write_bytes(b"\x07" + os.urandom(2047))
    elif case == "pickle":
        pickle_payload(path, marker)
    elif case == "torch_zip":
        torch_save_payload(path, marker)
    out = tmp_path / "out"
    rc, _, err = _run(capsys, command, files["seq"], path, out)
    assert_clean_failure(rc, err, "w.safetensors", out_dir=out)
    assert not marker.exists()


@pytest.mark.parametrize("command", ["depth", "sfm", "slam"])
def test_weights_of_another_code_size_run(tmp_path, capsys, files, command):
    """Weights of another code size carry their architecture in their metadata: a command runs the network they
    hold (nothing assumes the default code size)."""
    weights = tiny_weights(tmp_path / "w16.safetensors", code_size=16)
    out = tmp_path / "out"
    rc, _, err = _run(capsys, command, files["seq"], weights, out)
    assert rc == 0 and "Traceback" not in err, err


@pytest.mark.parametrize("command", ["depth", "sfm", "slam"])
@pytest.mark.parametrize("case", ["missing", "unknown_layout", "a_file"])
def test_bad_dataset(tmp_path, capsys, files, command, case):
    dataset = tmp_path / "data"
    needle = {"missing": "not found", "unknown_layout": "no known dataset format", "a_file": "not a folder"}[case]
    if case == "unknown_layout":
        dataset.mkdir()
        (dataset / "notes.txt").write_text("hello")
    elif case == "a_file":
        dataset.write_text("hello")
    out = tmp_path / "out"
    rc, _, err = _run(capsys, command, dataset, files["weights"], out)
    assert_clean_failure(rc, err, needle, out_dir=out)


@pytest.mark.parametrize("command", ["sfm", "slam"])
def test_single_frame_sequence_needs_two_frames(tmp_path, capsys, files, command):
    out = tmp_path / "out"
    extra = ["--frames", "0"] if command == "sfm" else []
    rc, _, err = run_cli(capsys, command, files["one"], "--weights", files["weights"], "--out", out, *extra,
                         *(["-q"] if command == "slam" else []))
    assert_clean_failure(rc, err, "2 frames", out_dir=out)


@pytest.mark.parametrize("command", ["sfm", "slam"])
@pytest.mark.parametrize("case", ["python_tags", "malformed", "unknown_key", "not_a_mapping"])
def test_bad_config(tmp_path, capsys, files, command, case):
    marker = tmp_path / "PWNED"
    cfg = tmp_path / "bad.yaml"
    cfg.write_text({"python_tags": yaml_payload(marker), "malformed": "a: [1, 2\n", "unknown_key": "nonsense: 1\n",
                    "not_a_mapping": "- 1\n- 2\n"}[case])
    out = tmp_path / "out"
    rc, _, err = _run(capsys, command, files["seq"], files["weights"], out, "--config", cfg)
    assert_clean_failure(rc, err, out_dir=out)
    assert not marker.exists()


@pytest.mark.parametrize("command", ["depth", "sfm", "slam"])
def test_out_is_a_file(tmp_path, capsys, files, command):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    rc, _, err = _run(capsys, command, files["seq"], files["weights"], blocker)
    assert_clean_failure(rc, err, "blocker is a file")
    assert blocker.read_text() == "a file"
