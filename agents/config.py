"""TOML config files read into typed, frozen dataclasses.

A schema is a frozen dataclass whose fields are plain values (bool, int, float, str, tuples of
them) or further dataclasses (TOML tables). Every value is checked against its field's type; an
unknown key, a wrong type or a value the dataclass's own `__post_init__` rejects is a `ConfigError`
naming the file and the dotted key. Overrides `section.key=value` (the `--set` of the command line)
are applied before checking; the value is read as a TOML value, or as a string when it is not one
(so `--set search.strategy=random` needs no quotes).

`check_positive` is the number check the settings dataclasses share; `run_directory` is where a
new run from a config goes.
"""

import dataclasses
import json
import math
import tomllib
import types
import typing
from pathlib import Path

from jaxsim.files import read_text


MAX_INT = 2**31 - 1         # a config's whole numbers become 32-bit sizes, counts and seeds


class ConfigError(ValueError):
    """A config file or override that cannot be used; the message names the file and key."""


def check_positive(settings, names, allow_zero=False):
    """For a settings dataclass's `__post_init__`: a ValueError naming the first of the fields
    `names` whose value is not a finite number above zero (or at least zero, with `allow_zero`);
    NaN and ±inf are refused."""
    for name in names:
        value = getattr(settings, name)
        if not (math.isfinite(value) and (value >= 0 if allow_zero else value > 0)):
            raise ValueError(f"{name} must be a finite number {'≥ 0' if allow_zero else '> 0'}; "
                             f"got {value}")


def run_directory(config_path, out_dir, holds_run, advice) -> Path:
    """The directory of a new run from the config at `config_path`: `out_dir`, else
    runs/<config name>. When `holds_run(directory)` says a run is already there, a ConfigError
    refuses it, so no run is overwritten or mixed with another; its message ends with `advice`,
    in which "{run_dir}" stands for the directory."""
    run_dir = Path(out_dir or Path("runs") / Path(config_path).stem)
    if holds_run(run_dir):
        raise ConfigError(f"{run_dir} already holds a run; {advice.format(run_dir=run_dir)}")
    return run_dir


def read_stored(path) -> dict:
    """The config a run directory stored as JSON (its config.json); a ConfigError naming the file
    when it cannot be read as a JSON object (a torn write, another kind of file)."""
    path = Path(path)
    try:
        stored = json.loads(read_text(path, ConfigError))
    except json.JSONDecodeError as error:
        raise ConfigError(f"{path}: not a readable run config ({error})") from None
    if not isinstance(stored, dict):
        raise ConfigError(f"{path}: not a readable run config (not a JSON object)")
    return stored


def load(path, schema, overrides=()):
    """Read the TOML file at `path` into `schema`, after applying `overrides` ("a.b=value")."""
    return build(schema, read(path, overrides), str(path))


def read(path, overrides=()) -> dict:
    """The TOML file at `path` as nested dicts, with `overrides` ("a.b=value") applied; a file
    that holds no settings at all is refused (it would silently run on every default). A
    `.json` file is read as a stored config (a run's config.json, a sweep's base.json)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, not a config file (give a .toml file)")
    if path.suffix == ".json":
        return _with_overrides(read_stored(path), overrides, path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot be read ({error.strerror or error})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None
    return _with_overrides(data, overrides, path)


def _with_overrides(data, overrides, path):
    if not data:
        raise ConfigError(f"{path}: the file holds no settings")
    for override in overrides:
        apply_override(data, override, path)
    return data


def apply_override(data, override, source):
    """Set the dotted key of "a.b.c=value" in the nested dict `data`."""
    key, equals, text = override.partition("=")
    if not equals or not key.strip():
        raise ConfigError(f"{source}: override {override!r} is not of the form section.key=value")
    try:
        value = tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError:
        value = text
    *sections, name = key.strip().split(".")
    table = data
    for section in sections:
        table = table.setdefault(section, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: override {override!r}: {section!r} is not a table")
    table[name] = value


def build(schema, data, source, prefix=""):
    """Instantiate the dataclass `schema` from the dict `data`, checking keys and types."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {prefix.rstrip('.') or 'the file'} must be a table")
    fields = [f.name for f in dataclasses.fields(schema)]
    hints = typing.get_type_hints(schema)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{source}: unknown key {prefix + unknown[0]!r}; "
                          f"{prefix.rstrip('.') or 'the top level'} takes "
                          f"{', '.join(fields)}")
    values = {}
    for name, value in data.items():
        values[name] = _convert(hints[name], value, source, prefix + name)
    try:
        return schema(**values)
    except ValueError as error:
        where = f"[{prefix.rstrip('.')}]" if prefix else "config"
        raise ConfigError(f"{source}: {where}: {error}") from None


def _convert(kind, value, source, key):
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        options = [k for k in typing.get_args(kind) if k is not type(None)]
        if len(options) != 1 or type(None) not in typing.get_args(kind):
            raise TypeError(f"config key {key!r}: only `X | None` unions are supported")
        if value is None:                       # a stored config.json's null; TOML has none
            return None
        kind = options[0]
    if dataclasses.is_dataclass(kind):
        return build(kind, value, source, key + ".")
    if typing.get_origin(kind) is tuple:
        if not isinstance(value, list):
            raise _type_error(source, key, "a list", value)
        item = typing.get_args(kind)[0]
        return tuple(_convert(item, v, source, f"{key}[{i}]") for i, v in enumerate(value))
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if kind is int and isinstance(value, bool) or not isinstance(value, kind):
        raise _type_error(source, key, f"{'a' if kind is not int else 'an'} {kind.__name__}",
                          value)
    if kind is float and not math.isfinite(value):
        raise ConfigError(f"{source}: key {key!r} must be a finite number; got {value}")
    if kind is int and abs(value) > MAX_INT:
        raise ConfigError(f"{source}: key {key!r} is {value}, beyond the ±{MAX_INT:,} a whole "
                          "number in a config may be (it becomes a size, a step count or a seed "
                          "in compiled code, which counts in 32 bits)")
    return value


def _type_error(source, key, expected, value):
    return ConfigError(f"{source}: key {key!r} must be {expected}; got {value!r} "
                       f"({type(value).__name__})")

