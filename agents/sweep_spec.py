"""A config's `[sweep]` table, expanded into the sweep's members (DESIGN.md "Configs and CLI").

The table names config keys (dotted, as `--set` does; TOML nests `ppo.clip = …` inside
`[sweep]` as a table, and either spelling works) and what each takes:

    [sweep]
    ppo.clip = [0.1, 0.2, 0.3]                  # a grid: these values
    "world.gravity" = [-9.81, -3.7]
    physics.leg_length_scale = {linspace = [0.8, 1.2, 64]}   # a grid of 64 values
    ppo.policy_lr = {log_uniform = [1e-5, 1e-3]}  # random draws
    run.seed = {choice = [0, 1, 2]}
    highjump.z_min = {uniform = [0.4, 0.6]}
    samples = 8                                 # how many draws (with any distribution)
    seed = 0                                    # the draws' seed

Lists, `{linspace = [low, high, n]}` and `{logspace = [low, high, n]}` (n values evenly spaced,
on a log scale for the latter) make a grid: every combination of their values, the first key
varying slowest. Each
distribution (`uniform`, `log_uniform`, `choice`) is drawn `samples` times; with a grid as well,
every grid point is crossed with the same `samples` draws, so its members differ only in the grid's
keys. The draws come from `numpy.random.default_rng(seed)`, key by key in sorted order, so the
same table gives the same members on any machine, and adding a grid key does not change the
draws.

A member is a dict {dotted key: value}; `overrides(member)` gives it as `--set` strings, which
`agents.config` applies and checks against the config's schema (an unknown key or a wrong type
is then a ConfigError naming the key). This module checks the table itself: an empty list, a
value that is neither a list nor a distribution, two distributions in one key, a range backwards
or (log-uniform) not positive, `samples` missing or given without a distribution, each named by
its key. A table whose key is not a distribution's name (`{normal = […]}`) reads as a deeper
config key (`….normal`), which the config's schema then refuses.
"""

import itertools
import json
import math

import numpy as np

from agents.config import ConfigError

DISTRIBUTIONS = ("uniform", "log_uniform", "choice")
RANGES = ("linspace", "logspace")
# The table's own keys, not config keys: the draws', and how the sweep runs (`agents.sweep`).
SETTINGS = ("samples", "seed", "evaluate", "episodes", "difficulty", "workers", "vmap")
MAX_MEMBERS = 100_000


def expand(table: dict, source) -> list[dict]:
    """The members of the sweep that `table` (the config's [sweep] as read from TOML)
    describes; a ConfigError naming `source` and the key for a table that does not make one."""
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{source}: [sweep] must be a table naming at least one key to sweep")
    settings = {k: table[k] for k in SETTINGS if k in table}
    grid, drawn = {}, {}
    for key, spec in _leaves({k: v for k, v in table.items() if k not in SETTINGS}):
        where = f"sweep.{key}"
        if isinstance(spec, list):
            if not spec:
                raise ConfigError(f"{source}: {where} is an empty list: give the values to sweep")
            grid[key] = spec
        elif isinstance(spec, dict) and len(spec) == 1 and set(spec) <= set(RANGES):
            grid[key] = _range(spec, source, where)
        elif isinstance(spec, dict):
            drawn[key] = _distribution(spec, source, where)
        else:
            raise ConfigError(f"{source}: {where} must be a list of values or a distribution "
                              f"({', '.join(f'{{{d} = …}}' for d in DISTRIBUTIONS)}); got "
                              f"{spec!r}")
    if not grid and not drawn:
        raise ConfigError(f"{source}: [sweep] names no key to sweep")
    samples = _whole(settings, "samples", source, default=None)
    seed = _whole(settings, "seed", source, default=0)
    if drawn and samples is None:
        raise ConfigError(f"{source}: sweep.samples must say how many draws to make of "
                          f"{', '.join(f'sweep.{k}' for k in drawn)}")
    if samples is not None and not drawn:
        raise ConfigError(f"{source}: sweep.samples = {samples} is given, but no key is drawn "
                          f"from a distribution (a list is a grid; use {{choice = […]}} to draw)")
    if samples is not None and samples < 1:
        raise ConfigError(f"{source}: sweep.samples must be at least 1; got {samples}")
    points = math.prod(len(v) for v in grid.values()) * (samples or 1)
    if points > MAX_MEMBERS:
        raise ConfigError(f"{source}: [sweep] makes {points:,} members, more than "
                          f"{MAX_MEMBERS:,}; sweep fewer values")
    draws = _draw(drawn, samples, seed) if drawn else [{}]
    return [{**dict(zip(grid, values)), **draw}
            for values in itertools.product(*grid.values()) for draw in draws]


def overrides(member: dict) -> list[str]:
    """The member as `--set` strings, "key=value" with the value written as TOML reads it."""
    return [f"{key}={json.dumps(value)}" for key, value in member.items()]


def _leaves(table, prefix=""):
    """(dotted key, spec) for each swept key of the nested table: a dict whose keys are all
    distribution names is a spec, any other dict a namespace."""
    for key, value in table.items():
        if isinstance(value, dict) and not set(value) <= {*DISTRIBUTIONS, *RANGES}:
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield prefix + key, value


def _distribution(spec, source, where):
    """(name, argument) of the one-key table `spec`, its argument checked."""
    if len(spec) != 1:
        raise ConfigError(f"{source}: {where} must name one distribution, one of "
                          f"{', '.join(DISTRIBUTIONS)}; got {', '.join(spec) or 'none'}")
    [(name, argument)] = spec.items()
    if name == "choice":
        if not isinstance(argument, list) or not argument:
            raise ConfigError(f"{source}: {where}.choice must be a non-empty list of values")
        return name, argument
    if (not isinstance(argument, list) or len(argument) != 2
            or not all(_is_number(a) for a in argument)):
        raise ConfigError(f"{source}: {where}.{name} must be [low, high], two numbers; got "
                          f"{argument!r}")
    low, high = (float(a) for a in argument)
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ConfigError(f"{source}: {where}.{name} must be [low, high] with low ≤ high, both "
                          f"finite; got {argument!r}")
    if name == "log_uniform" and low <= 0:
        raise ConfigError(f"{source}: {where}.log_uniform needs low > 0; got {argument!r}")
    return name, (low, high)


def _range(spec, source, where):
    """The values of a `{linspace = [low, high, n]}` or `{logspace = …}` grid key."""
    [(name, argument)] = spec.items()
    if (not isinstance(argument, list) or len(argument) != 3
            or not all(_is_number(a) for a in argument)
            or isinstance(argument[2], float) or argument[2] < 1):
        raise ConfigError(f"{source}: {where}.{name} must be [low, high, n], two numbers and a "
                          f"whole number of values n ≥ 1; got {argument!r}")
    low, high, count = float(argument[0]), float(argument[1]), argument[2]
    if count > MAX_MEMBERS:
        raise ConfigError(f"{source}: {where}.{name} asks for {count:,} values, more than "
                          f"{MAX_MEMBERS:,}; sweep fewer values")
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ConfigError(f"{source}: {where}.{name} must have finite ends; got {argument!r}")
    if name == "logspace":
        if low <= 0 or high <= 0:
            raise ConfigError(f"{source}: {where}.logspace needs ends > 0; got {argument!r}")
        return np.geomspace(low, high, count).tolist()
    return np.linspace(low, high, count).tolist()


def _draw(drawn, samples, seed):
    """`samples` dicts {key: value}, the keys drawn in sorted order from one generator."""
    rng = np.random.default_rng(seed)
    columns = {}
    for key in sorted(drawn):
        name, argument = drawn[key]
        if name == "choice":
            columns[key] = [argument[i] for i in rng.integers(len(argument), size=samples)]
        elif name == "uniform":
            columns[key] = rng.uniform(*argument, size=samples).tolist()
        else:
            low, high = np.log(argument)
            columns[key] = np.exp(rng.uniform(low, high, size=samples)).tolist()
    return [{key: columns[key][i] for key in drawn} for i in range(samples)]


def _whole(settings, name, source, default):
    if name not in settings:
        return default
    value = settings[name]
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{source}: sweep.{name} must be a whole number ≥ 0; got {value!r}")
    return value


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)
