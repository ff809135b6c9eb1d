"""`takeoff search CONFIG`: a strategy search (BDS or random) over a black box named in a config.

The config file (see configs/search_landscape.toml):

    black_box = "landscape"       # what g(x) is; for now the synthetic strategy landscapes
    [search]                      # bds.search.SearchSettings
    [landscape]                   # bds.landscapes.LandscapeSettings
    [box]                         # optional lower/upper bounds of x (default: the unit box)
    [executor]                    # optional: where a round's evaluations run
                                  # (jaxsim.executor.ExecutorSettings; --workers sets workers)

The run directory holds the resolved config (config.json) and the evaluation log
(evaluations.jsonl); running the same command again resumes the search from that log. A resumed
search may be given another search.budget and other [executor] settings; any other change to the
config is refused, since the log would then mix the results of two searches (or of two black
boxes).
"""

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agents import config as config_io
from jaxsim.executor import ExecutorSettings, executor_from
from jaxsim.atomic import check_writable, write_text_atomic
from bds.gp import to_unit
from bds.landscapes import LandscapeSettings, StrategyLandscape
from bds.search import SearchSettings, check_bounds, logged_evaluations, search

BLACK_BOXES = ("landscape",)
# The config keys a resumed search may change: its budget, and where it runs.
RESUMABLE = ("search.budget",
             *(f"executor.{field.name}" for field in dataclasses.fields(ExecutorSettings)))


@dataclass(frozen=True)
class Box:
    lower: tuple[float, ...] = ()     # empty: the unit box
    upper: tuple[float, ...] = ()


@dataclass(frozen=True)
class SearchConfig:
    black_box: str = "landscape"
    search: SearchSettings = field(default_factory=SearchSettings)
    landscape: LandscapeSettings = field(default_factory=LandscapeSettings)
    box: Box = field(default_factory=Box)
    executor: ExecutorSettings = field(default_factory=ExecutorSettings)

    def __post_init__(self):
        if self.black_box not in BLACK_BOXES:
            raise ValueError(f"black_box must be one of {', '.join(BLACK_BOXES)}; got "
                             f"{self.black_box!r}")
        if self.box.lower or self.box.upper:
            try:
                lower, _ = check_bounds(self.box.lower, self.box.upper)
            except ValueError as error:
                raise ValueError(f"[box]: {error}") from None
            if lower.size != self.landscape.dim:
                raise ValueError(f"[box] has {lower.size} dimensions but landscape.dim is "
                                 f"{self.landscape.dim}")
        try:
            self.search.check_feature_dim(self.landscape.feature_dim)
        except ValueError as error:
            raise ValueError(f"[search] does not fit landscape.feature_dim = "
                             f"{self.landscape.feature_dim}: {error}") from None

    def bounds(self):
        if self.box.lower:
            return np.array(self.box.lower), np.array(self.box.upper)
        return np.zeros(self.landscape.dim), np.ones(self.landscape.dim)


@dataclass(frozen=True, eq=False)
class LandscapeBlackBox:
    """The `landscape` black box: g(x) is the feature of the synthetic landscape at x of the
    box [lower, upper]; `label(x)` names the strategy there. An object, not a closure, so that
    worker processes can be sent it."""
    landscape: StrategyLandscape
    lower: np.ndarray
    upper: np.ndarray

    def __call__(self, x):
        return self.landscape(to_unit(np.asarray(x), self.lower, self.upper))

    def label(self, x):
        return int(self.landscape.label(to_unit(np.asarray(x), self.lower, self.upper)))


def black_box(config: SearchConfig) -> LandscapeBlackBox:
    """g(x) for the configured black box (with `label(x)`, the strategy of a point)."""
    return LandscapeBlackBox(StrategyLandscape(config.landscape), *config.bounds())


def _flat(tree, prefix=""):
    """The nested dict `tree` as {dotted key: value}."""
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[prefix + key] = value
    return flat


def _check_resumable(out_dir, resolved):
    """Raise a ConfigError naming the first key, other than those in RESUMABLE, in which the
    resolved config (as config.json holds it) differs from the run's config.json. A key the
    stored file lacks (written before that setting existed) is taken to have its default."""
    path = Path(out_dir) / "config.json"
    if not path.exists():
        raise config_io.ConfigError(f"{out_dir} holds a search log but no config.json, so this "
                                    "config cannot be checked against the search in it; use "
                                    "another --out")
    stored = config_io.read_stored(path)
    defaults = _flat(json.loads(json.dumps(dataclasses.asdict(SearchConfig()))))
    stored = {**defaults, **_flat(stored)}
    for key, value in _flat(resolved).items():
        if key not in RESUMABLE and stored.get(key) != value:
            raise config_io.ConfigError(
                f"{out_dir} holds a search with {key} = {stored.get(key)!r}, but the config gives "
                f"{value!r}; a resumed search may change only {', '.join(RESUMABLE)}: use the "
                "same config or another --out")


def run(config_path, out_dir=None, overrides=(), workers=None, echo=print):
    """Load the config, run or resume the search, print progress and a summary; returns the
    SearchResult. `workers`, when given, overrides the config's executor.workers."""
    if workers is not None:
        overrides = [*overrides, f"executor.workers={workers}"]
    config = config_io.load(config_path, SearchConfig, overrides)
    out_dir = Path(out_dir or Path("runs") / Path(config_path).stem)
    log = out_dir / "evaluations.jsonl"
    text = json.dumps(dataclasses.asdict(config), indent=2) + "\n"
    if log.exists():
        _check_resumable(out_dir, json.loads(text))
    check_writable(out_dir, what="the search's log")
    write_text_atomic(out_dir / "config.json", text)
    g = black_box(config)
    label = g.label
    settings = config.search
    # Strategies of the evaluations the log already holds, so progress says what is new.
    seen = {label(record["x"]) for record in logged_evaluations(log)
            if record["index"] < settings.budget}

    def progress(record):
        strategy = label(record["x"])
        new = strategy not in seen
        seen.add(strategy)
        feature = ", ".join(f"{v:.3f}" for v in record["feature"])
        echo(f"[{record['index'] + 1:3d}/{settings.budget}] {record['kind']:8s} "
             f"feature ({feature})  strategy {strategy}{' (new)' if new else ''}  "
             f"distinct {len(seen)}")

    if log.exists():
        echo(f"resuming from {log}")
    with executor_from(config.executor) as executor:
        result = search(g, *config.bounds(), settings, log=log, progress=progress,
                        executor=executor)
    labels = [label(x) for x in result.x]
    echo(f"\n{settings.strategy} search: {len(set(labels))} distinct strategies in "
         f"{len(labels)} evaluations (log: {log})")
    echo(f"{'strategy':>8} {'found at':>9} {'count':>6}  feature")
    for strategy in sorted(set(labels), key=labels.index):
        first = labels.index(strategy)
        feature = ", ".join(f"{v:.3f}" for v in result.features[first])
        echo(f"{strategy:>8} {first + 1:>9} {labels.count(strategy):>6}  ({feature})")
    return result
