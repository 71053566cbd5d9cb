"""Bad options and output paths of ``codeslam synth``: one error line, exit 2, nothing written (the options are
all checked before rendering, so these take milliseconds)."""

from __future__ import annotations

import pytest
from corpus import assert_clean_failure, listing, run_cli, temp_files

BAD_OPTIONS = {
    "size_not_WxH": (["--size", "big"], ["--size must look like"]),
    "size_one_number": (["--size", "64"], ["--size must look like"]),
    "size_three_numbers": (["--size", "16x16x3"], ["--size must look like"]),
    "size_float": (["--size", "16.5x16"], ["--size must look like"]),
    "size_zero": (["--size", "0x0"], ["between 8x8 and 4096x4096"]),
    "size_negative": (["--size", "-16x16"], ["between 8x8 and 4096x4096"]),
    "size_huge": (["--size", "100000x100000"], ["between 8x8 and 4096x4096"]),
    "frames_zero": (["--frames", "0"], ["--frames must be at least 1"]),
    "frames_negative": (["--frames", "-4"], ["--frames must be at least 1"]),
    "scenes_zero": (["--scenes", "0"], ["--scenes must be at least 1"]),
    "workers_zero": (["--workers", "0"], ["--workers must be at least 1"]),
    "supersample_zero": (["--supersample", "0"], ["supersample must be >= 1"]),
    "noise_negative": (["--noise", "-0.1"], ["must be non-negative"]),
    "noise_nan": (["--noise", "nan"], ["must be non-negative"]),
    "blur_inf": (["--blur", "inf"], ["must be finite"]),
    "train_views_zero": (["--train", "--views", "0"], ["--views must be at least 1"]),
    "train_views_per_scene_zero": (["--train", "--views-per-scene", "0"], ["--views-per-scene must be at least 1"]),
    "train_shard_size_negative": (["--train", "--shard-size", "-1"], ["--shard-size must be at least 1"]),
}


@pytest.mark.parametrize("name", sorted(BAD_OPTIONS))
def test_bad_option(tmp_path, capsys, name):
    opts, needles = BAD_OPTIONS[name]
    out = tmp_path / "out"
    defaults = [arg for key, value in {"--frames": "1", "--size": "16x16"}.items() if key not in opts
                for arg in (key, value)]  # small and fast should the option be accepted after all
    rc, _, err = run_cli(capsys, "synth", out, *opts, *defaults)
    assert_clean_failure(rc, err, *needles, out_dir=out)


@pytest.mark.parametrize("train", [False, True], ids=["sequences", "shards"])
@pytest.mark.parametrize("where", ["out_is_a_file", "parent_is_a_file", "json_is_a_folder", "json_parent_is_a_file"])
def test_unwritable_output_fails_before_rendering(tmp_path, capsys, train, where):
    (tmp_path / "blocker").write_text("a file")
    (tmp_path / "adir").mkdir()
    out, json_out = tmp_path / "out", tmp_path / "s.json"
    if where == "out_is_a_file":
        out = tmp_path / "blocker"
    elif where == "parent_is_a_file":
        out = tmp_path / "blocker" / "out"
    elif where == "json_is_a_folder":
        json_out = tmp_path / "adir"
    else:
        json_out = tmp_path / "blocker" / "s.json"
    before = listing(tmp_path)
    mode = ["--train", "--views", "2", "--views-per-scene", "2"] if train else ["--frames", "1"]
    rc, _, err = run_cli(capsys, "synth", out, *mode, "--size", "16x16", "--json", json_out)
    assert_clean_failure(rc, err, "cannot write")
    assert listing(tmp_path) == before and not temp_files(tmp_path)
