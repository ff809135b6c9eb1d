"""Where the reference data lives: the directory the user names (data never ships with takeoff).

The one rule, for every command and the tests alike: `--data-dir`, else `$TAKEOFF_DATA`, else
`shared/data` beside the checkout (`../shared/data` seen from the repository's root), the
layout of a development checkout. The checkout is the one the package runs from (`pip install
-e`), or else the current directory (a package installed by copy, run from its checkout).
"""

import os
from pathlib import Path

_PACKAGE_CHECKOUT = Path(__file__).resolve().parents[1]


def checkout_default() -> Path:
    """`../shared/data` beside the checkout the package runs from, or else beside the current
    directory."""
    if (_PACKAGE_CHECKOUT / "pyproject.toml").is_file():
        return _PACKAGE_CHECKOUT.parent / "shared" / "data"
    return Path.cwd().parent / "shared" / "data"


class DataDirError(ValueError):
    """No usable data directory; the message says how to name one."""


def data_dir_from(argument=None) -> Path:
    """--data-dir, else $TAKEOFF_DATA, else `checkout_default()`; a DataDirError saying which
    was tried when it is not a directory."""
    if argument:
        path, source = Path(argument), "--data-dir"
    elif os.environ.get("TAKEOFF_DATA"):
        path, source = Path(os.environ["TAKEOFF_DATA"]), "TAKEOFF_DATA"
    else:
        path, source = checkout_default(), "the default beside the checkout"
    if not path.is_dir():
        raise DataDirError(f"no data directory at {path} ({source}); name it with --data-dir "
                           "or TAKEOFF_DATA (e.g. ../shared/data)")
    return path
