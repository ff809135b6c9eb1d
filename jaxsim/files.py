"""Reading a text file the user names (a character, a motion, a motion-capture file, a run's
config): its text, or the caller's own error naming the file when it is missing, a directory,
unreadable or not text, instead of Python's OSError or UnicodeDecodeError."""

from pathlib import Path


def read_text(path, error: type[Exception]) -> str:
    """The UTF-8 text of the file at `path`; an `error(message)` naming it when it cannot be."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except IsADirectoryError:
        raise error(f"{path}: is a directory, not a file") from None
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except UnicodeDecodeError as decode:
        raise error(f"{path}: not a text file (byte {decode.start} is not UTF-8)") from None
    except OSError as other:
        raise error(f"{path}: cannot be read ({other.strerror or other})") from None
