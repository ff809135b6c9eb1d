"""Line-oriented reading of motion-capture text files, with errors that say where."""

import math

from jaxsim.motion.deepmimic import MotionFileError


def fail(path, line, reason) -> MotionFileError:
    return MotionFileError(f"{path}:{line}: {reason}")


def read_lines(path):
    """[(line number, tokens)] for every line of a text file (any line ends)."""
    with open(path) as f:
        return [(number, line.split()) for number, line in enumerate(f, 1)]


def floats(path, line, tokens, count=None):
    """The finite numbers in `tokens` (exactly `count` of them unless count is None); "nan" and
    "inf", which Python would read, are refused."""
    if count is not None and len(tokens) != count:
        raise fail(path, line, f"expected {count} values, got {len(tokens)}")
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise fail(path, line, f"not a number in {' '.join(tokens)!r}") from None
    bad = [t for t, v in zip(tokens, values) if not math.isfinite(v)]
    if bad:
        raise fail(path, line, f"not a finite number: {bad[0]!r}")
    return values
