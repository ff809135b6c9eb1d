"""Append-only JSON-lines logs (a training run's `metrics.jsonl`, a search's
`evaluations.jsonl`) and the one policy every reader of them follows.

A writer appends one JSON object per line and flushes it; a record is *accepted* once its line,
newline included, is in the file. Reading (`read`):

- every line that ends in a newline must be a JSON object of finite numbers (NaN and ±Infinity,
  which Python's `json` would accept, are refused): anything else is a `LogError` naming the
  file and line, since a bad line in the middle is damage no reader can repair by guessing;
- a last line without its newline that parses is a whole record whose newline was not written
  yet: it is kept (`Log.needs_newline`);
- a last line without its newline that does not parse is *torn*: a write interrupted by a
  crash. It is not a record, but it is never dropped unseen: `Log.torn` holds its text, and
  `repair` moves it to `<log>.torn` (appending, so nothing earlier there is lost) and returns a
  message for the user, before anything more is appended.

The writers redo what a torn line would have recorded (a training resumes from its checkpoint,
a search evaluates the point again), so a torn line loses no accepted record; a line damaged by
hand that way is kept in `<log>.torn` for the user to look at.
"""

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from jaxsim.atomic import write_text_atomic
from jaxsim.files import read_text

TORN_SUFFIX = ".torn"


class LogError(ValueError):
    """A log line that is not a record: the message names the file and the line."""


class LogWarning(UserWarning):
    """A log that was not intact and has been set right; the message says what was done."""


def _refuse_constant(name):
    raise ValueError(f"{name} is not a finite number")


def _finite(text):
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text} is not a finite number")
    return value


def parse_record(line: str) -> dict:
    """One log line as a dict; a ValueError when it is not a JSON object of finite numbers."""
    record = json.loads(line, parse_constant=_refuse_constant, parse_float=_finite)
    if not isinstance(record, dict):
        raise ValueError("not a JSON object")
    return record


def format_record(record: dict) -> str:
    """`record` as one log line (with its newline); a ValueError for a non-finite number."""
    return json.dumps(record, allow_nan=False) + "\n"


@dataclass
class Log:
    """What `read` found in a log file."""

    path: Path
    records: list = field(default_factory=list)
    torn: str = ""                  # the text of a torn last line ("" when there is none)
    needs_newline: bool = False     # the last record is whole but its newline is missing

    @property
    def intact(self) -> bool:
        return not self.torn and not self.needs_newline


def read(path) -> Log:
    """The records of the log at `path` (none when the file does not exist); see the module
    docstring for what is refused and what is set aside."""
    path = Path(path)
    if not path.exists():
        return Log(path)
    text = read_text(path, LogError)
    lines = text.split("\n")
    tail = lines.pop()              # "" when the text ends with a newline
    log = Log(path)
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            log.records.append(parse_record(line))
        except ValueError as error:
            raise LogError(f"{path}, line {number}: not a log record ({error})") from None
    if tail.strip():
        try:
            log.records.append(parse_record(tail))
            log.needs_newline = True
        except ValueError:
            log.torn = tail
    return log


def repair(log: Log, records=None) -> str:
    """Rewrite the log as `records` (default: the records read) with a newline after each,
    moving a torn last line to `<log>.torn`. Returns what was done, for the user ("" when the
    file needed nothing)."""
    records = log.records if records is None else records
    note = ""
    if log.torn:
        torn_path = log.path.with_name(log.path.name + TORN_SUFFIX)
        with open(torn_path, "a", encoding="utf-8") as f:
            f.write(log.torn + "\n")
        note = (f"{log.path}: its last line was cut off (a write interrupted by a crash) and is "
                f"not a record; its text is kept in {torn_path}")
    if log.torn or log.needs_newline or records is not log.records or not log.path.exists():
        write_text_atomic(log.path, "".join(format_record(r) for r in records))
    return note


def append(path, record: dict, sync: bool = False):
    """Append `record` as one line and flush it (and, with `sync`, fsync it to disk)."""
    line = format_record(record)
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        if sync:
            os.fsync(f.fileno())
