"""Line-oriented reading of motion-capture text files, with errors that say where."""

import math

from jaxsim.files import read_text
from jaxsim.motion.deepmimic import MotionFileError


def fail(path, line, reason) -> MotionFileError:
    return MotionFileError(f"{path}:{line}: {reason}")


def read_lines(path):
    """[(line number, tokens)] for every line of a text file (any line ends)."""
    return [(number, line.split())
            for number, line in enumerate(read_text(path, MotionFileError).splitlines(), 1)]


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


def positive(path, name, value, meaning):
    """`value` as a float when it is a finite number > 0; otherwise a `MotionFileError` naming
    the file, the parameter `name` and what it gives (`meaning`, such as "frames per second")."""
    try:
        number = float(value) if not isinstance(value, str) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise MotionFileError(f"{path}: {name} must be a finite number > 0 ({meaning}), "
                              f"got {value!r}")
    return number
