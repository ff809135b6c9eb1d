"""Atomic writes: a reader sees the old file or the new one, never half of one."""

import os
import stat

import pytest

from jaxsim.atomic import atomic_path, write_text_atomic


def test_written_file_has_a_normal_mode_and_no_leftovers(tmp_path):
    umask = os.umask(0)
    os.umask(umask)
    write_text_atomic(tmp_path / "sub" / "a.txt", "hello")
    path = tmp_path / "sub" / "a.txt"
    assert path.read_text() == "hello"
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask     # as open() would make it
    assert os.listdir(tmp_path / "sub") == ["a.txt"]


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "a.json"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            with open(tmp, "w") as f:
                f.write("half of the ne")
            raise RuntimeError("writer died")
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["a.json"]
