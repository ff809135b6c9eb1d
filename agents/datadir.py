"""Where the reference data lives: the directory the user names (data never ships with takeoff).

The one rule, for every command and the tests alike: `--data-dir`, else `$TAKEOFF_DATA`, else
`shared/data` beside the checkout (`../shared/data` seen from the repository's root), the
layout of a development checkout.
"""

import os
from pathlib import Path

CHECKOUT_DEFAULT = Path(__file__).resolve().parents[1].parent / "shared" / "data"


class DataDirError(ValueError):
    """No usable data directory; the message says how to name one."""


def data_dir_from(argument=None) -> Path:
    """--data-dir, else $TAKEOFF_DATA, else `CHECKOUT_DEFAULT`; a DataDirError saying which
    was tried when it is not a directory."""
    if argument:
        path, source = Path(argument), "--data-dir"
    elif os.environ.get("TAKEOFF_DATA"):
        path, source = Path(os.environ["TAKEOFF_DATA"]), "TAKEOFF_DATA"
    else:
        path, source = CHECKOUT_DEFAULT, "the default beside the checkout"
    if not path.is_dir():
        raise DataDirError(f"no data directory at {path} ({source}); name it with --data-dir "
                           "or TAKEOFF_DATA (e.g. ../shared/data)")
    return path
