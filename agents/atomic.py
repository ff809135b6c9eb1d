"""Writing files so that a reader never sees half of one: a temporary file in the same folder,
then an atomic rename over the target."""

import os
import tempfile
from pathlib import Path


def write_text_atomic(path, text):
    """Write `text` to `path` (creating its folder), flushed to disk before the rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
