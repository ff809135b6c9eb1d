"""Writing files so that a reader never sees half of one: write a temporary file in the same
folder, flush it to disk, then rename it over the target (an atomic step on POSIX and Windows).
And `check_writable`, asked before any long work, so that an output folder that cannot take the
results fails at once with its name, not after minutes of work with a traceback; and
`hold_directory`, so that two processes never write one run or search directory at once."""

import contextlib
import fcntl
import os
import shutil
import socket
import tempfile
from pathlib import Path


class OutputError(ValueError):
    """An output folder that cannot be written, or has too little room; the message names it."""


def check_writable(directory, need_bytes: int = 0, what: str = "the output") -> Path:
    """Make sure `directory` exists (creating it) and a file can be written in it, with at
    least `need_bytes` free on its disk for `what`; an `OutputError` naming it otherwise.
    Returns it as a Path."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=directory, prefix=".write-check.")
        os.close(fd)
        os.remove(probe)
    except OSError as error:
        raise OutputError(f"{directory}: cannot write {what} there "
                          f"({error.strerror or error})") from None
    free = shutil.disk_usage(directory).free
    if free < need_bytes:
        raise OutputError(f"{directory}: {what} needs {_megabytes(need_bytes)} on disk, and "
                          f"only {_megabytes(free)} is free there")
    return directory


def _megabytes(count: int) -> str:
    return f"{count / 1e6:,.1f} MB"


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()     # read once, at import: os.umask is process-wide, not thread-safe


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary file name beside `path` (creating the folder; the name keeps `path`'s
    extension, for writers that infer the format from it); when the block succeeds
    the file is fsync'd and renamed to `path`, otherwise it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".",
                               suffix=".tmp" + path.suffix)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)    # mkstemp makes it private; give it a normal file's mode
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def write_text_atomic(path, text):
    """Write `text` (UTF-8) to `path` atomically."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")


LOCK_FILE = ".lock"


@contextlib.contextmanager
def hold_directory(directory, what: str = "the directory"):
    """Hold `directory` (creating it) for this process while the block runs: an advisory lock
    (flock) on its `LOCK_FILE`, which records who holds it. A directory another process holds
    is an `OutputError` naming it and that process, raised before anything in it is touched.
    The kernel drops the lock when its holder dies, however it dies (kill -9 too), so a killed
    run never leaves a stale lock behind to clear by hand; the file itself stays, harmless."""
    directory = Path(directory)
    path = directory / LOCK_FILE
    try:
        directory.mkdir(parents=True, exist_ok=True)
        f = open(path, "a+", encoding="utf-8")
    except OSError as error:
        raise OutputError(f"{path}: cannot open the lock that keeps {what} to one process "
                          f"({error.strerror or error})") from None
    with f:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            raise OutputError(f"{directory}: {what} is in use by {holder}; wait for it to end, "
                              f"or stop it, before starting another process on it") from None
        except OSError as error:    # a filesystem without flock (ENOLCK, EOPNOTSUPP)
            raise OutputError(f"{path}: cannot lock it to keep {what} to one process "
                              f"({error.strerror or error}); use a local folder") from None
        f.seek(0)
        f.truncate()
        f.write(f"process {os.getpid()} on {socket.gethostname()}\n")
        f.flush()
        try:
            yield directory
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)
