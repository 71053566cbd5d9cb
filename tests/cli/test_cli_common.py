"""The command-line toolkit every command shares: one ``--frames`` grammar with one error message, the device
check, the thread setting, the size parser and the progress helper."""

from __future__ import annotations

import pytest
import torch

from codeslam.cli import main
from codeslam.cli.common import check_device, parse_frames, parse_size, progress_bar, set_threads
from codeslam.errors import ConfigError


@pytest.mark.parametrize(
    ("spec", "n", "expected"),
    [
        (None, 5, [0, 1, 2, 3, 4]),
        ("3", 9, [3]),
        ("40,44,48", 50, [40, 44, 48]),
        ("18,16,20", 50, [18, 16, 20]),  # the order given (the first listed is SfM's master)
        ("1:4", 5, [1, 2, 3]),
        ("0:10:3", 10, [0, 3, 6, 9]),
        (":3", 9, [0, 1, 2]),
        ("6:", 9, [6, 7, 8]),
        ("::2", 5, [0, 2, 4]),
        ("0:10:", 10, list(range(10))),
        ("2:,0", 5, [2, 3, 4, 0]),
        (" 0:3 , 7 ", 9, [0, 1, 2, 7]),
    ],
)
def test_frames_grammar(spec, n, expected):
    assert parse_frames(spec, n) == expected


@pytest.mark.parametrize(
    ("spec", "n", "message"),
    [
        ("a", 10, "must look like"), ("x:y", 9, "must look like"), ("1:2:3:4", 9, "must look like"),
        ("", 10, "must look like"), (",", 10, "must look like"), ("1,,x", 10, "must look like"),
        ("-1", 10, ">= 0"), ("-1:3", 9, ">= 0"), ("1:2:0", 10, "step >= 1"),
        ("10", 10, "outside"), ("0:11", 10, "outside"), ("9:", 9, "outside"),
        ("4:4", 9, "selects no frame"), ("5:3,7", 9, "selects no frame"),
        ("1,1", 10, "twice"), ("0:3,2", 10, "twice"),
    ],
)
def test_bad_frames_are_one_config_error(spec, n, message):
    with pytest.raises(ConfigError, match=message):
        parse_frames(spec, n)


def test_frames_minimum_and_order():
    assert parse_frames("3,5", 9, min_frames=2, what="SfM") == [3, 5]
    with pytest.raises(ConfigError, match="selects 1 frame.*SfM needs at least 2"):
        parse_frames("3", 9, min_frames=2, what="SfM")
    with pytest.raises(ConfigError, match="SLAM needs at least 2 frames; the sequence has 1"):
        parse_frames(None, 1, min_frames=2, what="SLAM")
    with pytest.raises(ConfigError, match="must increase"):
        parse_frames("5,3", 9, what="SLAM", increasing=True)
    assert parse_frames("5,3", 9) == [5, 3]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("common")
    assert main(["synth", str(root), "--scenes", "1", "--frames", "4", "--size", "32x24", "--seed", "1"]) == 0
    return root / "scene_000"


@pytest.mark.parametrize("spec", ["0:x", "9", "1,1"])
def test_every_dataset_command_gives_the_same_frames_error(sequence, tmp_path, capsys, spec):
    """depth, sfm and slam read --frames with one parser, so a bad one gets the same line from each."""
    lines = []
    for cmd in (["depth"], ["sfm"], ["slam", "--depth-model", "standin", "--out", str(tmp_path / "o")]):
        rc = main([cmd[0], str(sequence), "--frames", spec, *cmd[1:]])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.startswith("codeslam: error: --frames") and "\n" not in err, (cmd, err)
        lines.append(err)
    assert lines[0] == lines[1] == lines[2]
    assert not (tmp_path / "o").exists()


def test_device_check():
    assert check_device(None) == "cpu"
    assert check_device(None, default="cpu:0") == "cpu:0"
    assert check_device("cpu") == "cpu"
    for bad, message in (("meta", "must be cpu or cuda"), ("tpu", "must look like"), ("cuda:99", "no such CUDA")):
        with pytest.raises(ConfigError, match=message):
            check_device(bad)


def test_threads():
    before = torch.get_num_threads()
    try:
        set_threads(1)
        assert torch.get_num_threads() == 1
        set_threads(None)
        assert torch.get_num_threads() == 1
        with pytest.raises(ConfigError, match=">= 1"):
            set_threads(0)
    finally:
        torch.set_num_threads(before)


def test_size():
    assert parse_size("128x96") == (128, 96)
    assert parse_size("64X48") == (64, 48)
    for bad in ("128", "axb", "4x4", "8x5000"):
        with pytest.raises(ConfigError, match="--size"):
            parse_size(bad)


@pytest.mark.parametrize("quiet", [False, True])
def test_progress_bar_takes_updates(quiet, capsys):
    with progress_bar("test", 3, quiet) as update:
        for k in range(3):
            update(k + 1, f"step {k}")
        update(3)
    assert capsys.readouterr().out == ""  # never on stdout, where the results go


@pytest.mark.parametrize(("argv", "code"), [(["--help"], 0), (["info", "/nonexistent/dataset"], 2)])
def test_the_console_entry_returns_the_commands_exit_code_and_freezes_the_heap_last(monkeypatch, capsys, argv,
                                                                                    code):
    """The console script (``codeslam``, ``python -m codeslam``) runs :func:`main` and only then freezes the
    garbage collector's heap for the interpreter's shutdown; a failing command keeps its exit code."""
    import codeslam.cli as cli

    calls = []
    monkeypatch.setattr(cli.sys, "argv", ["codeslam", *argv])
    command = cli.main
    monkeypatch.setattr(cli, "main", lambda: calls.append("main") or command())
    monkeypatch.setattr(cli.gc, "freeze", lambda: calls.append("freeze"))
    assert cli.entry() == code
    assert calls == ["main", "freeze"]
    capsys.readouterr()
