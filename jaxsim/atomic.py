"""Writing files so that a reader never sees half of one: write a temporary file in the same
folder, flush it to disk, then rename it over the target (an atomic step on POSIX and Windows)."""

import contextlib
import os
import tempfile
from pathlib import Path


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
