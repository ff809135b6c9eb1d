"""Atomic writes: a reader sees the old file or the new one, never half of one. Held
directories: one process at a time writes a run or a search."""

import os
import signal
import stat
import subprocess
import sys

import pytest

from jaxsim.atomic import OutputError, atomic_path, hold_directory, write_text_atomic


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


def test_a_held_directory_is_refused_to_another_holder_until_released(tmp_path):
    run_dir = tmp_path / "run"
    with hold_directory(run_dir, "the run"):
        with pytest.raises(OutputError, match=rf"run: the run is in use by process "
                                              rf"{os.getpid()} on "):
            with hold_directory(run_dir, "the run"):
                pass
    with hold_directory(run_dir, "the run"):        # released: held again at once
        pass


HOLDER = """
import sys, time
from jaxsim.atomic import hold_directory
with hold_directory(sys.argv[1]):
    print("held", flush=True)
    time.sleep(600)
"""


def test_a_holder_killed_with_sigkill_leaves_no_lock_behind(tmp_path):
    run_dir = tmp_path / "run"
    child = subprocess.Popen([sys.executable, "-c", HOLDER, str(run_dir)],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline() == "held\n"
        with pytest.raises(OutputError, match=rf"in use by process {child.pid} on "):
            with hold_directory(run_dir):
                pass
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    with hold_directory(run_dir):                    # nothing to clear by hand
        pass


def test_a_lock_that_cannot_be_opened_is_named(tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / ".lock").mkdir(parents=True)             # not a file: open() fails
    with pytest.raises(OutputError, match=r"run/\.lock: cannot open the lock that keeps the "
                                          r"run to one process"):
        with hold_directory(run_dir, "the run"):
            pass
