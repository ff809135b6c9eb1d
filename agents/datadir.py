"""Where the reference data lives: the directory the user names (data never ships with takeoff)."""

import os
from pathlib import Path


class DataDirError(ValueError):
    """No usable data directory; the message says how to name one."""


def data_dir_from(argument=None) -> Path:
    """--data-dir, else $TAKEOFF_DATA."""
    path = argument or os.environ.get("TAKEOFF_DATA")
    if not path:
        raise DataDirError("name the data directory with --data-dir or TAKEOFF_DATA "
                           "(e.g. ../shared/data)")
    return Path(path)
