"""`takeoff search CONFIG`: a strategy search (BDS or random) over a black box named in a config.

The config file (see configs/search_landscape.toml, configs/highjump_bds.toml):

    black_box = "jump"            # what g(x) is: "jump" (train a jump policy from x,
                                  # agents.discovery.jump_black_box), "ballistic" (the take-off
                                  # state's held-pose flight, agents.tasks.ballistic: no
                                  # learning, milliseconds) or "landscape" (a synthetic
                                  # strategy landscape); the last two for tests and benchmarks
    same_strategy = 0.5236        # features this close are one strategy (bds.strategies);
                                  # 0: the feature's default (π/6 for the jumps' up angle)
    [search]                      # bds.search.SearchSettings
    [jump]                        # agents.discovery.jump_black_box.JumpBlackBoxSettings
    [ballistic]                   # task = "highjump" or "obstacle"
    [landscape]                   # bds.landscapes.LandscapeSettings
    [box]                         # optional lower/upper bounds of x (default: the unit box for a
                                  # landscape, the task's take-off-state bounds for a jump)
    [executor]                    # optional: where a round's evaluations run
                                  # (jaxsim.executor.ExecutorSettings; --workers sets workers)

The run directory holds the resolved config (config.json), the evaluation log
(evaluations.jsonl) and, for a jump, one directory per evaluation (evaluations/NNN/); running the
same command again resumes the search from the log, and an evaluation that was training resumes
its training from its checkpoint. A resumed search may be given another search.budget, other
[executor] settings and another same_strategy; any other change to the config is refused, since
the log would then mix the results of two searches (or of two black boxes).
"""

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agents import config as config_io
from agents.discovery.jump_black_box import EVALUATIONS, JumpBlackBox, JumpBlackBoxSettings
from agents.tasks import takeoff_state
from bds import strategies
from bds.gp import to_unit
from bds.landscapes import LandscapeSettings, StrategyLandscape
from bds.search import SEARCH_LOG, SearchSettings, check_bounds, logged_evaluations, search
from jaxsim.atomic import check_writable, hold_directory, write_text_atomic
from jaxsim.executor import ExecutorSettings, executor_from

BLACK_BOXES = ("landscape", "ballistic", "jump")
# The config keys a resumed search may change: its budget, where it runs, how its summary
# groups strategies.
RESUMABLE = ("search.budget", "same_strategy",
             *(f"executor.{field.name}" for field in dataclasses.fields(ExecutorSettings)))


@dataclass(frozen=True)
class Box:
    lower: tuple[float, ...] = ()     # empty: the black box's own (`bounds`)
    upper: tuple[float, ...] = ()


@dataclass(frozen=True)
class BallisticSettings:
    task: str = "highjump"            # whose take-off states fly


@dataclass(frozen=True)
class SearchConfig:
    black_box: str = "landscape"
    same_strategy: float = 0.0
    search: SearchSettings = field(default_factory=SearchSettings)
    landscape: LandscapeSettings = field(default_factory=LandscapeSettings)
    jump: JumpBlackBoxSettings = field(default_factory=JumpBlackBoxSettings)
    ballistic: BallisticSettings = field(default_factory=BallisticSettings)
    box: Box = field(default_factory=Box)
    executor: ExecutorSettings = field(default_factory=ExecutorSettings)

    def __post_init__(self):
        if self.black_box not in BLACK_BOXES:
            raise ValueError(f"black_box must be one of {', '.join(BLACK_BOXES)}; got "
                             f"{self.black_box!r}")
        if not self.same_strategy >= 0:
            raise ValueError(f"same_strategy must be ≥ 0; got {self.same_strategy}")
        dim, what = self._dim()
        if self.box.lower or self.box.upper:
            try:
                lower, _ = check_bounds(self.box.lower, self.box.upper)
            except ValueError as error:
                raise ValueError(f"[box]: {error}") from None
            if lower.size != dim:
                raise ValueError(f"[box] has {lower.size} dimensions but {what} has {dim}")
        if self.black_box == "landscape":
            feature_dim = self.landscape.feature_dim
            what = f"landscape.feature_dim = {feature_dim}"
        else:
            feature_dim, what = 1, f"the {self.black_box} black box's feature (1 number)"
        try:
            self.search.check_feature_dim(feature_dim)
        except ValueError as error:
            raise ValueError(f"[search] does not fit {what}: {error}") from None

    def task(self) -> str:
        """The jump task of a `jump` black box (the one its training config trains) or of a
        `ballistic` one: "highjump" or "obstacle"."""
        if self.black_box == "ballistic":
            return self.ballistic.task
        from agents.commands import train_commands
        return train_commands.load_config(self.jump.train, self.jump.set).run.task

    def _dim(self):
        if self.black_box == "landscape":
            return self.landscape.dim, "landscape.dim"
        return len(self._task_bounds()[0]), f"the {self.task()} take-off state x"

    def _task_bounds(self):
        task = self.task()
        if task not in takeoff_state.BOUNDS:
            key = "ballistic.task is" if self.black_box == "ballistic" else "jump.train trains"
            raise ValueError(f"{key} the task {task!r}, which has no take-off states to "
                             f"search; use one of {', '.join(takeoff_state.BOUNDS)}")
        return takeoff_state.BOUNDS[task]

    def bounds(self):
        if self.box.lower:
            return np.array(self.box.lower), np.array(self.box.upper)
        if self.black_box == "landscape":
            return np.zeros(self.landscape.dim), np.ones(self.landscape.dim)
        lower, upper = self._task_bounds()
        return np.array(lower, float), np.array(upper, float)

    def strategy_threshold(self) -> float:
        return self.same_strategy or strategies.UP_ANGLE_THRESHOLD


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


def load_search_config(search_dir) -> SearchConfig:
    """The config a search directory stored (its config.json), checked as `run` checks one."""
    path = Path(search_dir) / "config.json"
    if not path.exists():
        raise config_io.ConfigError(f"{path}: missing; is {search_dir} a search directory?")
    return config_io.build(SearchConfig, config_io.read_stored(path), str(path))


def black_box(config: SearchConfig, out_dir=None, data_dir=None):
    """g(x) for the configured black box; a landscape's also has `label(x)`, the strategy of a
    point."""
    if config.black_box == "landscape":
        return LandscapeBlackBox(StrategyLandscape(config.landscape), *config.bounds())
    from agents.datadir import data_dir_from
    if config.black_box == "ballistic":
        from agents.tasks.ballistic import BallisticBlackBox
        return BallisticBlackBox(config.task(), data_dir_from(data_dir))
    return JumpBlackBox(config.jump, Path(out_dir), data_dir_from(data_dir))


def _flat(tree, prefix=""):
    """The nested dict `tree` as {dotted key: value}."""
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[prefix + key] = value
    return flat


def config_text(config: SearchConfig) -> str:
    """The config as a search directory stores it (its config.json)."""
    return json.dumps(dataclasses.asdict(config), indent=2) + "\n"


def started(out_dir) -> bool:
    """Whether `out_dir` holds a search's work that another config would misread: its log, or
    an evaluation's directory (a first evaluation killed before it was logged leaves its
    training's checkpoint and no log)."""
    out_dir = Path(out_dir)
    evaluations = out_dir / EVALUATIONS
    return ((out_dir / SEARCH_LOG).exists()
            or (evaluations.is_dir() and any(evaluations.iterdir())))


def check_resumable(out_dir, resolved):
    """Raise a ConfigError naming the first key, other than those in RESUMABLE, in which the
    resolved config (as config.json holds it) differs from the run's config.json. A key the
    stored file lacks (written before that setting existed) is taken to have its default."""
    path = Path(out_dir) / "config.json"
    if not path.exists():
        raise config_io.ConfigError(f"{out_dir} holds a search's log or evaluations but no "
                                    "config.json, so this config cannot be checked against the "
                                    "search in it; use another --out")
    stored = config_io.read_stored(path)
    defaults = _flat(json.loads(json.dumps(dataclasses.asdict(SearchConfig()))))
    stored = {**defaults, **_flat(stored)}
    for key, value in _flat(resolved).items():
        if key not in RESUMABLE and stored.get(key) != value:
            raise config_io.ConfigError(
                f"{out_dir} holds a search with {key} = {stored.get(key)!r}, but the config gives "
                f"{value!r}; a resumed search may change only {', '.join(RESUMABLE)}: use the "
                "same config or another --out")


def run(config_path, out_dir=None, overrides=(), workers=None, echo=print, data_dir=None):
    """Load the config, run or resume the search, print progress and a summary; returns the
    SearchResult. `workers`, when given, overrides the config's executor.workers; `data_dir` is
    the reference data a jump black box trains with (default: `agents.datadir`)."""
    if workers is not None:
        overrides = [*overrides, f"executor.workers={workers}"]
    config = config_io.load(config_path, SearchConfig, overrides)
    out_dir = Path(out_dir or Path("runs") / Path(config_path).stem)
    text = config_text(config)
    if started(out_dir):
        check_resumable(out_dir, json.loads(text))
    check_writable(out_dir, what="the search's log")
    with hold_directory(out_dir, "the search"):
        return _run_held(config, out_dir, text, echo, data_dir)


def _run_held(config: SearchConfig, out_dir: Path, text: str, echo, data_dir):
    """`run`'s work in the search directory, which this process holds: the search, resumed
    from its log, with progress and the summary."""
    log = out_dir / SEARCH_LOG
    if config.black_box == "jump":     # trainings in this process use a device per core
        from agents.commands import train_commands
        from agents.rl import parallel
        parallel.start(train_commands.load_config(config.jump.train, config.jump.set).run.devices)
    write_text_atomic(out_dir / "config.json", text)
    g = black_box(config, out_dir, data_dir)
    settings = config.search
    tally = Tally(config, g)
    for record in logged_evaluations(log):
        if record["index"] < settings.budget:
            tally.add(record)

    def progress(record):
        strategy, new = tally.add(record)
        if record["feature"] is None:
            outcome = f"FAILED: {record['failure']}"
        else:
            feature = ", ".join(f"{v:.3f}" for v in record["feature"])
            outcome = (f"feature ({feature})  strategy {strategy}{' (new)' if new else ''}  "
                       f"distinct {tally.distinct()}")
        echo(f"[{record['index'] + 1:3d}/{settings.budget}] {record['kind']:8s} "
             f"x ({', '.join(f'{v:.2f}' for v in record['x'])})  {outcome}  "
             f"({record['seconds'] / 60:.1f} min)")

    if log.exists():
        echo(f"resuming from {log}")
    with executor_from(config.executor) as executor:
        result = search(g, *config.bounds(), settings, log=log, progress=progress,
                        executor=executor)
    tally = Tally(config, g)
    for record in logged_evaluations(log)[:settings.budget]:
        tally.add(record)
    echo(f"\n{settings.strategy} search: {tally.distinct()} distinct strategies in "
         f"{len(result.x)} evaluations, {sum(f is not None for f in result.failures)} failed "
         f"(log: {log})")
    echo(tally.table())
    return result


class Tally:
    """The strategies of a search's evaluations as they come: the landscape's own labels, or
    the features grouped by `bds.strategies` (failures are no strategy)."""

    def __init__(self, config: SearchConfig, g):
        self.label = getattr(g, "label", None)
        self.threshold, self.distance = config.strategy_threshold(), config.search.distance
        self.records = []

    def labels(self):
        if self.label is not None:
            return [self.label(r["x"]) if r["feature"] is not None else -1 for r in self.records]
        return list(strategies.group([r["feature"] for r in self.records], self.threshold,
                                     self.distance))

    def add(self, record):
        """Add an evaluation record; (its strategy, whether it is new)."""
        before = set(self.labels())
        self.records.append(record)
        strategy = self.labels()[-1]
        return strategy, strategy >= 0 and strategy not in before

    def distinct(self) -> int:
        return len({label for label in self.labels() if label >= 0})

    def table(self) -> str:
        labels = self.labels()
        lines = [f"{'strategy':>8} {'found at':>9} {'count':>6}  feature"]
        for strategy in sorted({l for l in labels if l >= 0}, key=labels.index):
            first = labels.index(strategy)
            feature = ", ".join(f"{v:.3f}" for v in self.records[first]["feature"])
            lines.append(f"{strategy:>8} {first + 1:>9} {labels.count(strategy):>6}  "
                         f"({feature})")
        for index, record in enumerate(self.records):
            if record["feature"] is None:
                lines.append(f"{'failed':>8} {index + 1:>9} {'':>6}  {record['failure']}")
        return "\n".join(lines)
