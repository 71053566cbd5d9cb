import pytest

from codeslam.io import atomic_path, atomic_write, write_json


def test_atomic_write_keeps_previous_file_on_failure(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old complete content")
    with pytest.raises(RuntimeError):
        with atomic_write(p) as f:
            f.write("half of the new")
            raise RuntimeError("killed mid-write")
    assert p.read_text() == "old complete content"
    assert [x.name for x in tmp_path.iterdir()] == ["out.txt"]  # no temporary left behind


def test_atomic_write_creates_file_and_parents(tmp_path):
    p = tmp_path / "a" / "b" / "out.json"
    write_json(p, {"x": 1})
    assert p.read_text().strip().startswith("{")


def test_atomic_path_failure_leaves_nothing(tmp_path):
    p = tmp_path / "img.png"
    with pytest.raises(ValueError):
        with atomic_path(p) as tmp:
            tmp.write_bytes(b"partial")
            raise ValueError
    assert not any(tmp_path.iterdir())


def test_results_get_the_permissions_of_a_newly_created_file(tmp_path):
    """mkstemp makes 0600 temporaries; the renamed result must be readable like any file the user creates."""
    import os

    from codeslam.io import _umask

    atomic = tmp_path / "atomic.txt"
    with atomic_write(atomic) as f:
        f.write("x")
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert (atomic.stat().st_mode & 0o777) == (plain.stat().st_mode & 0o777) == 0o666 & ~_umask()
    assert os.access(atomic, os.R_OK)
