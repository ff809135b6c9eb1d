"""The search loop of Bayesian Diversity Search (thesis §3.5.1, Algorithm 1), batched BDS and a
random-search baseline behind one interface.

Algorithm 1: evaluate `initial` random points; then alternate `explore` picks that maximise the
posterior standard deviation (multi-start L-BFGS) and `diverse` picks that maximise the expected
distance to the nearest feature seen so far (DIRECT), refitting the GP before every pick.

Batched BDS (the thesis's future work, §3.8): each round picks `batch` points before any of them is
evaluated. After each pick, the pending point is added to the GP with its posterior mean as a
fantasised outcome ("kriging believer", hyperparameters kept): the posterior variance there drops,
so exploration moves elsewhere, and its believed feature joins the features the diversity
acquisition must differ from. With `batch = 1` this is Algorithm 1. A round's evaluations may run at
once, in worker processes or on Ray (`jaxsim.executor`; `workers` or `executor` of `search`).

Persistence: every event is appended to a JSONL log and synced to disk at once — a header with the
settings, each round's planned points before they are evaluated (with, for a model-based pick
weighted by the success model, its chance of success there), and each evaluation once it and
the round's evaluations before it have returned (so the log is in pick order however many run at
once). `search` on an existing log resumes: finished evaluations are read back, not repeated; a
round that was planned but not finished evaluates only its missing points; the next decisions are
computed from the same history. The log is read by the policy of `jaxsim.runlog`: a half-written
last line (a crash during a write) is set aside in `<log>.torn` with a warning, a bad line or an
evaluation whose x or feature is not finite numbers of the right size (or x lies outside the box)
is a `SearchError` naming the file and record, and a log cut off before its header was complete
holds nothing and starts afresh. A search that fails before its first evaluation is logged
removes the log it created.

Failures: a black box may return `Failure(reason)` for an x that produced no strategy (a jump
training that never cleared the lowest bar). It is logged with `"feature": null` and its reason,
and no feature is made up for it: the GP is fitted to the successful evaluations alone, and each
failed x is then added as a visited point whose outcome is the model's own prediction there (the
batched rounds' "kriging believer" device), which leaves the posterior mean unchanged and lowers
the posterior variance around it — so exploration does not go back to a failed x, while the
diversity acquisition compares only real features. Until a first evaluation succeeds there is no
model, and the model-based picks are random points (logged as kind "random"). With `feasibility`
on, failures also teach where not to go: a second GP, of the outcomes (success +1, failure −1),
weights both acquisitions by the probability that x succeeds (`bds.feasibility`). It is fitted once
per round from the evaluations that returned; a batched round's pending points do not change it.

Every random choice comes from the seed and the index of the pick, so the same settings give the
same search on the same machine.
"""

import contextlib
import dataclasses
import json
import math
import time
import warnings
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim.executor import Executor, InProcess, LocalProcesses
from bds import acquisition, feasibility, gp
from bds.optimize import direct, maximize_lbfgs
from jaxsim import runlog
from jaxsim.atomic import write_text_atomic

STRATEGIES = ("bds", "random")
CAPACITY_STEP = 16              # observation arrays are padded to a multiple of this
LBFGS_CANDIDATES = 1024         # uniform points the L-BFGS starts of an exploration pick come from
ROTATION_DIM = 3                # the feature size the "rotation" distance takes (a rotation vector)
SUCCESS_MODEL_KEY = 1 << 30     # the success model's random stream (the picks' are their indices)
SEARCH_LOG = "evaluations.jsonl"  # the file a search directory keeps its log in


class SearchError(ValueError):
    """A search log or a black-box output the search cannot use; the message names the file and
    line, or the evaluation."""


class Failure(NamedTuple):
    """What a black box returns for an x whose evaluation produced no strategy (e.g. a jump
    training that never cleared the lowest bar), with why. The search logs it (`"feature":
    null, "failure": reason`) and never gives the GP a feature for it; see `plan_round`."""
    reason: str


@dataclass(frozen=True)
class SearchSettings:
    strategy: str = "bds"           # "bds" or "random"
    budget: int = 20                # evaluations in all
    initial: int = 4                # random evaluations before the first model-based pick
    explore: int = 3                # N_exp: exploration picks per cycle
    diverse: int = 3                # N_opt: diversity picks per cycle
    batch: int = 1                  # q: points picked per round (1 = Algorithm 1)
    seed: int = 0
    distance: str = "euclidean"     # feature distance: euclidean, angle or rotation
    mc_samples: int = 128           # Monte-Carlo samples of the diversity acquisition
    gp_restarts: int = 8
    gp_steps: int = 200
    lbfgs_starts: int = 8
    direct_evaluations: int = 400
    # The range the feature can take, per component (both empty: unknown). When given, the GP's
    # prior mean is its middle and its standardising unit at least a quarter of its width (so
    # the prior's ±2σ spans it); otherwise both come from the features seen so far.
    feature_low: tuple[float, ...] = ()
    feature_high: tuple[float, ...] = ()
    # Weight every model-based pick's acquisition by the chance that x succeeds, from a GP of
    # the evaluations' successes and failures (`bds.feasibility`); off: Algorithm 1 as written.
    feasibility: bool = False
    # Fit the feature GP's hyperparameters under weak priors (`bds.gp`, `hyperprior`) instead of
    # by the marginal likelihood alone, which with a few evaluations is degenerate.
    hyperprior: bool = False

    def __post_init__(self):
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}; got "
                             f"{self.strategy!r}")
        acquisition.distance_function(self.distance)
        for name in ("budget", "initial", "batch", "mc_samples", "gp_restarts", "gp_steps",
                     "lbfgs_starts", "direct_evaluations"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1; got {getattr(self, name)}")
        if self.seed < 0:
            raise ValueError(f"seed must be non-negative; got {self.seed}")
        if self.lbfgs_starts > LBFGS_CANDIDATES:
            raise ValueError(f"lbfgs_starts must be at most {LBFGS_CANDIDATES} (the candidate "
                             f"points the starts are chosen from); got {self.lbfgs_starts}")
        if self.explore < 0 or self.diverse < 0 or self.explore + self.diverse == 0:
            raise ValueError("explore and diverse must be non-negative and not both zero")
        if self.strategy == "bds" and self.initial < self.batch:
            raise ValueError(f"initial ({self.initial}) must be at least batch ({self.batch}): "
                             "the first round has no observations to model")
        if self.feature_low or self.feature_high:
            try:
                check_bounds(self.feature_low, self.feature_high)
            except ValueError as error:
                raise ValueError(f"feature_low/feature_high: {error}") from None

    def check_feature_dim(self, feature_dim):
        """Raise a ValueError naming the setting when features of `feature_dim` numbers do not
        fit these settings: a feature range of another size, or the rotation distance with
        features that are not rotation vectors."""
        if self.feature_low and len(self.feature_low) != feature_dim:
            raise ValueError(f"feature_low/feature_high give {len(self.feature_low)} components, "
                             f"but the black box returns features of {feature_dim}")
        if self.distance == "rotation" and feature_dim != ROTATION_DIM:
            raise ValueError(f"distance 'rotation' compares rotation vectors of {ROTATION_DIM} "
                             f"numbers, but the black box returns features of {feature_dim}")

    def feature_prior(self, feature_dim):
        """The GP's prior mean and least standardising unit, each (feature_dim,), from the
        feature's range; (None, 0.0) when the range is not given."""
        self.check_feature_dim(feature_dim)
        if not self.feature_low:
            return None, 0.0
        low, high = np.asarray(self.feature_low), np.asarray(self.feature_high)
        return 0.5 * (low + high), 0.25 * (high - low)

    def kind(self, index):
        """What pick `index` is: 'initial', 'explore' or 'diverse' (BDS) or 'random'."""
        if self.strategy == "random":
            return "random"
        if index < self.initial:
            return "initial"
        cycle = (index - self.initial) % (self.explore + self.diverse)
        return "explore" if cycle < self.explore else "diverse"


class SearchResult(NamedTuple):
    x: np.ndarray              # (n, d) evaluated points, in the user's box
    features: np.ndarray       # (n, m); rows of NaN for failures
    kinds: list
    failures: list             # per evaluation: its Failure's reason, or None (a feature)


def check_bounds(lower, upper):
    """Bounds as float arrays, or a ValueError saying what is wrong with them."""
    try:
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    except (TypeError, ValueError):
        raise ValueError(f"bounds must be lists of numbers; got lower={lower!r}, "
                         f"upper={upper!r}") from None
    if lower.ndim != 1 or lower.size == 0 or lower.shape != upper.shape:
        raise ValueError(f"lower and upper bounds must be non-empty lists of the same length; "
                         f"got {lower.size} and {upper.size} numbers")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise ValueError("bounds must be finite numbers")
    bad = np.flatnonzero(upper <= lower)
    if bad.size:
        i = bad[0]
        raise ValueError(f"upper bound must exceed lower bound in every dimension; dimension {i} "
                         f"has lower {lower[i]} and upper {upper[i]}")
    return lower, upper


# ---------------------------------------------------------------------------------------------
# decisions (all in the unit box)


def _random_point(settings, index, dim):
    return np.random.default_rng([settings.seed, index]).uniform(size=dim)


def _padded(rows, capacity):
    out = np.zeros((capacity, rows.shape[1]))
    out[:len(rows)] = rows
    return out


@partial(jax.jit, static_argnames=("dim", "starts"))
def _explore(posterior, success_model, key, dim, starts):
    objective = feasibility.weighted(partial(acquisition.exploration, posterior), success_model)
    return maximize_lbfgs(objective, dim, key, starts=starts, candidates=LBFGS_CANDIDATES)


@partial(jax.jit, static_argnames=("distance",))
def _diversity(posterior, success_model, points, observed, observed_mask, base, distance):
    diversity = partial(acquisition.diversity, posterior, observed=observed,
                        observed_mask=observed_mask, base_samples=base, distance=distance)
    return feasibility.weighted(diversity, success_model)(points)


def _diversity_objective(posterior, success_model, observed, observed_mask, base, distance):
    """DIRECT's objective: −diversity at a batch of unit points, padded to a power of two so
    the jitted acquisition compiles for few shapes."""
    def objective(points):
        n = len(points)
        size = 1 << max(n - 1, 0).bit_length()
        padded = np.concatenate([points, np.repeat(points[:1], size - n, axis=0)])
        values = _diversity(posterior, success_model, jnp.asarray(padded), observed,
                            observed_mask, base, distance)
        return -np.asarray(values)[:n]
    return objective


def _pick(settings, kind, posterior, success_model, observed_f, observed_mask, dim, key):
    """A model-based pick; `success_model` (or None) weights its acquisition by the chance of
    success (`bds.feasibility`)."""
    if kind == "explore":
        point, _ = _explore(posterior, success_model, key, dim, settings.lbfgs_starts)
        return np.asarray(point)
    base = jax.random.normal(key, (settings.mc_samples, observed_f.shape[1]), observed_f.dtype)
    objective = _diversity_objective(posterior, success_model, observed_f, observed_mask, base,
                                     acquisition.distance_function(settings.distance))
    return direct(objective, np.zeros(dim), np.ones(dim),
                  max_evaluations=settings.direct_evaluations).x


def _capacity(observations):
    """The padded size of a round's observation arrays."""
    return CAPACITY_STEP * math.ceil(observations / CAPACITY_STEP)


def _round_key(settings, first_index):
    """The random stream of the round whose first pick is `first_index`."""
    return jax.random.fold_in(jax.random.PRNGKey(settings.seed), first_index)


def success_model(settings, first_index, x_unit, failed_unit, count=1):
    """The constraint GP of `bds.feasibility` that `plan_round` weights the picks of the round
    (first_index, `count` picks) by, over the successes x_unit and the failures failed_unit;
    None when `settings.feasibility` is off or nothing has failed yet (every pick is then taken
    to succeed)."""
    if not (settings.feasibility and len(failed_unit)):
        return None
    x = np.concatenate([x_unit, failed_unit])
    capacity = _capacity(len(x) + count)
    return feasibility.fit(_padded(x, capacity), np.arange(capacity) < len(x_unit),
                           np.arange(capacity) < len(x),
                           jax.random.fold_in(_round_key(settings, first_index),
                                              SUCCESS_MODEL_KEY),
                           settings.gp_restarts, settings.gp_steps)


class RoundModel:
    """The feature GP a round's picks are made with (see the module docstring): fitted to the
    successful evaluations x_unit (n, d) and their features (n, m), then each failed point of
    failed_unit added as visited (`believe`), in padded arrays with room for the round's
    `count` pending points."""

    def __init__(self, settings, first_index, x_unit, features, failed_unit, count):
        self.real_count, self.failed_count = len(x_unit), len(failed_unit)
        capacity = _capacity(self.real_count + self.failed_count + count)
        self.mask = np.arange(capacity) < self.real_count
        self.xs, self.fs = _padded(x_unit, capacity), _padded(features, capacity)
        self.key = _round_key(settings, first_index)
        prior_mean, min_scale = settings.feature_prior(self.fs.shape[1])
        self.posterior = gp.fit(self.xs, self.fs, self.mask, prior_mean=prior_mean, key=self.key,
                                restarts=settings.gp_restarts, steps=settings.gp_steps,
                                min_scale=min_scale, hyperprior=settings.hyperprior)
        self.visited = self.real_count
        for point in failed_unit:
            self.believe(point)

    def believe(self, point):
        """Add `point` as visited, its outcome the model's prediction there: the posterior mean
        stays, its variance there drops."""
        believed, _ = gp.predict(self.posterior, jnp.asarray(point)[None])
        row = self.visited
        self.xs[row], self.fs[row], self.mask[row] = point, np.asarray(believed)[0], True
        self.visited += 1
        self.posterior = gp.condition(self.posterior, jnp.asarray(self.xs),
                                      jnp.asarray(self.fs), jnp.asarray(self.mask))

    def compared(self):
        """The rows the diversity acquisition compares against: the real features and, in a
        batched round, the pending points' believed ones — never a failure's."""
        rows = np.arange(len(self.mask))
        return (rows < self.real_count) | (self.mask
                                           & (rows >= self.real_count + self.failed_count))


class Plan(NamedTuple):
    """A round's picks: their points (unit box), kinds, and each pick's chance of success under
    the success model that weighted it (None for a random pick, or when there is no model)."""
    points: list
    kinds: list
    success_probability: list


def plan_round(settings, first_index, count, x_unit, features, dim, failed_unit=None) -> Plan:
    """The next `count` points (unit box, d = dim) for picks first_index, first_index + 1, …,
    given the successful evaluations x_unit (n, d) with their features (n, m) and the failed
    ones' points failed_unit (k, d)."""
    kinds = [settings.kind(first_index + j) for j in range(count)]
    if not len(x_unit):                 # nothing to model yet: every pick is a random point
        kinds = [kind if kind == "initial" else "random" for kind in kinds]
    if all(kind in ("initial", "random") for kind in kinds):
        return Plan([_random_point(settings, first_index + j, dim) for j in range(count)], kinds,
                    [None] * count)
    failed_unit = np.zeros((0, dim)) if failed_unit is None else np.asarray(failed_unit)
    surrogate = RoundModel(settings, first_index, x_unit, features, failed_unit, count)
    model = success_model(settings, first_index, x_unit, failed_unit, count)
    picks = []
    for j, kind in enumerate(kinds):
        index = first_index + j
        if kind in ("initial", "random"):
            point = _random_point(settings, index, dim)
        else:
            point = _pick(settings, kind, surrogate.posterior, model, jnp.asarray(surrogate.fs),
                          jnp.asarray(surrogate.compared()), dim,
                          jax.random.fold_in(surrogate.key, index))
        picks.append(point)
        if j + 1 < count:                         # fantasise the pending point's outcome
            surrogate.believe(point)
    chances = ([None] * count if model is None else
               np.asarray(feasibility.success_probability(model, jnp.asarray(np.stack(picks))))
               .tolist())
    return Plan(picks, kinds, [None if kind in ("initial", "random") else chance
                               for kind, chance in zip(kinds, chances)])


# ---------------------------------------------------------------------------------------------
# the log


def _as_json(record):
    """`record` as JSON gives it back (tuples become lists), so a resumed log compares equal."""
    return json.loads(json.dumps(record))


_START = runlog.format_record({"event": "start"})[:-2]     # how every header begins


def _read_log(path) -> runlog.Log:
    """The log at `path` read by the policy of `jaxsim.runlog`, its errors as SearchErrors."""
    try:
        return runlog.read(path)
    except runlog.LogError as error:
        raise SearchError(str(error)) from None


def logged_evaluations(path):
    """The evaluation records in the search log at `path`, in the order they were written
    (none when there is no such file), checked as a resumed search checks them."""
    records = _read_log(path).records
    if not records:
        return []
    _check_start(path, records)
    return list(_contents(path, records)[1].values())


def _check_start(path, records):
    if not records or records[0].get("event") != "start":
        raise SearchError(f"{path}: not a search log (the first line must be the search's "
                          "'start' record)")


def _contents(path, records):
    """The plans {first_index: (points, kinds)} and evaluations {index: record} of a log's
    records after its header, each checked against the header's box; a SearchError naming the
    record for one that does not fit."""
    header = records[0]
    try:
        lower, upper = check_bounds(header.get("lower"), header.get("upper"))
    except ValueError as error:
        raise SearchError(f"{path}, record 1: {error}") from None
    plans, evaluations, feature_size = {}, {}, None
    for number, record in enumerate(records[1:], 2):
        event = record.get("event")
        if event == "plan":
            problem = _check_plan(record, len(lower))
        elif event == "evaluation":
            problem = _check_evaluation(record, lower, upper, feature_size)
        else:
            problem = f"event {event!r} is unknown"
        if problem:
            raise SearchError(f"{path}, record {number}: the {event or 'record'}'s {problem}")
        if event == "plan":
            plans[record["first_index"]] = (record["points"], record["kinds"])
        else:
            if record["feature"] is not None:
                feature_size = len(record["feature"])
            evaluations[record["index"]] = record
    return plans, evaluations


KINDS = ("initial", "explore", "diverse", "random")


def _check_plan(record, dim):
    """What is wrong with a logged plan ("" when nothing): its first index, its points (lists
    of `dim` numbers in the unit box), their kinds and their chances of success."""
    if not isinstance(record.get("first_index"), int) or record["first_index"] < 0:
        return f"first_index {record.get('first_index')!r} is not a whole number ≥ 0"
    points, kinds = record.get("points"), record.get("kinds")
    if not (isinstance(points, list) and points
            and all(_numbers(p, dim) and all(0 <= v <= 1 for v in p) for p in points)):
        return f"points are not a list of points of {dim} numbers in the unit box"
    if not (isinstance(kinds, list) and len(kinds) == len(points)
            and all(k in KINDS for k in kinds)):
        return f"kinds {kinds!r} are not one of {', '.join(KINDS)} per point"
    chances = record.get("success_probability", [None] * len(points))   # older logs lack it
    if not (isinstance(chances, list) and len(chances) == len(points)
            and all(p is None or (_numbers([p], 1) and 0 <= p <= 1) for p in chances)):
        return f"success_probability {chances!r} is not a chance in [0, 1] or null per point"
    return ""


def _numbers(value, size=None):
    """Whether `value` is a list of (`size`, if given) finite numbers."""
    return (isinstance(value, list) and (size is None or len(value) == size) and len(value) > 0
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    for v in value))


def _check_evaluation(record, lower, upper, feature_size):
    """What is wrong with a logged evaluation ("" when nothing): its index, its x (inside the
    search's box) and its feature (finite numbers, as many as the others')."""
    if not isinstance(record.get("index"), int) or record["index"] < 0:
        return f"index {record.get('index')!r} is not a whole number ≥ 0"
    if not _numbers(record.get("x"), len(lower)):
        return f"x {record.get('x')!r} is not {len(lower)} finite numbers"
    x = np.asarray(record["x"])
    if np.any(x < lower - 1e-9 * (upper - lower)) or np.any(x > upper + 1e-9 * (upper - lower)):
        return f"x {record['x']} lies outside the search's box"
    failure = record.get("failure")
    if failure is not None:
        if not (isinstance(failure, str) and failure):
            return f"failure {failure!r} is not a reason (a non-empty string) or null"
        if record.get("feature") is not None:
            return f"feature {record['feature']!r} is given for a failure (it must be null)"
        return ""
    if not _numbers(record.get("feature"), feature_size):
        return (f"feature {record.get('feature')!r} is not "
                f"{feature_size or 'a list of'} finite numbers")
    return ""


class SearchLog:
    """Append-only JSONL record of a search; see the module docstring."""

    def __init__(self, path, header):
        self.path = Path(path) if path is not None else None
        self.header = header
        self.plans = {}            # first_index -> (points, kinds)
        self.evaluations = {}      # index -> record
        self.started = False       # whether the file holds the header
        self.created = False       # whether this search wrote it
        if self.path is not None and self.path.exists():
            self._read()

    def _read(self):
        log = _read_log(self.path)
        if not log.records and (_START.startswith(log.torn) or log.torn.startswith(_START)):
            # Empty, or a crash while the header was written: no evaluation to keep, and the
            # header is written again with the first record.
            self._set_aside(log, [])
            self.path.unlink()
            return
        records = log.records
        _check_start(self.path, records)
        # A setting added after the log was written is taken to have had its default value.
        stored = {**_as_json(dataclasses.asdict(SearchSettings())),
                  **{key: value for key, value in records[0].items() if key != "event"}}
        for key, value in self.header.items():
            if stored.get(key) != value:
                raise SearchError(f"{self.path}: this log belongs to a different search: its "
                                  f"{key} is {stored.get(key)!r}, the settings give {value!r}; "
                                  "use another log file or the same settings")
        self.plans, self.evaluations = _contents(self.path, records)
        self.started = True
        self._set_aside(log, records)

    def _set_aside(self, log, records):
        """Rewrite a log that is not intact as `records`, its torn last line set aside."""
        if log.intact:
            return
        note = runlog.repair(log, records)
        if note:
            warnings.warn(note, runlog.LogWarning, stacklevel=4)

    def _append(self, record):
        """Append `record` (after the header, when the file has none yet), synced to disk."""
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not self.started:
            write_text_atomic(self.path, runlog.format_record({"event": "start", **self.header}))
            self.started = self.created = True
        try:
            runlog.append(self.path, record, sync=True)
        except ValueError as error:         # a NaN point, which JSON cannot hold
            raise SearchError(f"{self.path}: cannot log the {record['event']} ({error}): "
                              f"{record}") from None

    def discard_if_empty(self):
        """Remove the log this search created when it holds no evaluation (only its header and
        plans), so a search that failed at once leaves no file behind."""
        if self.path is not None and self.created and not self.evaluations:
            self.path.unlink(missing_ok=True)
            self.started = self.created = False

    def add_plan(self, first_index, points, kinds, success_probability):
        self.plans[first_index] = (points, kinds)
        self._append({"event": "plan", "first_index": first_index, "points": points,
                      "kinds": kinds, "success_probability": success_probability})

    def add_evaluation(self, record):
        self.evaluations[record["index"]] = record
        self._append({"event": "evaluation", **record})


# ---------------------------------------------------------------------------------------------
# the loop


def _feature(value, index, x):
    feature = np.atleast_1d(np.asarray(value, float))
    if feature.ndim != 1 or not np.all(np.isfinite(feature)):
        raise SearchError(f"evaluation {index} at x = {list(x)} returned {value!r}; the black box "
                          "must return a finite number or a 1-D list of finite numbers")
    return feature


@dataclass(frozen=True, eq=False)
class _Evaluation:
    """One evaluation of the black box g at a point of the unit box, as a job for an executor:
    its log record (index, kind, x in the box [lower, upper], feature, seconds). `seconds` is the
    wall time of the call that finished it: an evaluation resumed after a kill counts only its
    last leg (a black box's own records, such as a training's metrics, hold the total).
    Picklable when g is, so worker processes can run it."""
    g: Callable
    lower: np.ndarray
    upper: np.ndarray

    def __call__(self, index, point_unit, kind):
        x = gp.from_unit(np.asarray(point_unit), self.lower, self.upper)
        start = time.perf_counter()
        evaluate = getattr(self.g, "evaluate", None)
        outcome = self.g(x) if evaluate is None else evaluate(index, x)
        if isinstance(outcome, Failure):
            feature, failure = None, str(outcome.reason) or "failed (no reason given)"
        else:
            feature, failure = _feature(outcome, index, x).tolist(), None
        return {"index": index, "kind": kind, "x": x.tolist(), "feature": feature,
                "failure": failure, "seconds": time.perf_counter() - start}


def search(g: Callable, lower, upper, settings: SearchSettings = SearchSettings(), log=None,
           workers=1, progress=None, executor: Executor | None = None) -> SearchResult:
    """Run (or resume) a search for diverse features of the black box g over [lower, upper].

    g(x) takes a point (d,) of the box and returns its feature (a number or (m,) numbers), or
    a `Failure` when x produced no strategy (see the module docstring). A black box that keeps
    something per evaluation (a training's run directory, which a resumed search must find
    again) has instead a method `evaluate(index, x)`, given the evaluation's index.
    `log` is the JSONL file to append to (None: keep nothing). A round's points are evaluated
    by `executor` (an `jaxsim.executor.Executor`, which the caller closes), else, with
    `workers` > 1, in that many local worker processes (`LocalProcesses`: g must then be
    picklable, a module-level function or object rather than a lambda or closure, and it runs
    in another process, so it cannot change this one's state), else one after another in this
    process. The log is the same however they run. `progress(record)` is called after every
    evaluation is logged, with its log record (index, kind, x, feature, failure, seconds).

    When g (or a check of its output) raises, or the search is interrupted, the evaluations of
    the round that did finish are logged, those not finished are dropped, and the error
    propagates: a resumed search neither repeats nor loses an evaluation.
    """
    if executor is not None and workers != 1:
        raise ValueError(f"give workers ({workers}) or an executor, not both")
    lower, upper = check_bounds(lower, upper)
    dim = lower.size
    header = _as_json({"lower": lower.tolist(), "upper": upper.tolist(),
                       **{k: v for k, v in dataclasses.asdict(settings).items() if k != "budget"}})
    record_log = SearchLog(log, header)

    def history():
        """(x_unit, features) of the successful evaluations and x_unit of the failed ones."""
        done = [record_log.evaluations[i] for i in sorted(record_log.evaluations)]
        unit = lambda records: gp.to_unit(np.array([r["x"] for r in records]).reshape(-1, dim),
                                          lower, upper)
        good = [r for r in done if r["feature"] is not None]
        return (unit(good), np.array([r["feature"] for r in good]),
                unit([r for r in done if r["feature"] is None]))

    def finish(record):
        if record["feature"] is not None:
            _check_feature_size(record, record_log, settings)
        record_log.add_evaluation(record)
        if progress is not None:
            progress(record)

    owned = executor is None
    if owned:
        executor = InProcess() if workers == 1 else LocalProcesses(workers)
    try:
        _run_rounds(settings, record_log, history, _Evaluation(g, lower, upper), finish, dim,
                    executor)
    except BaseException:
        record_log.discard_if_empty()
        raise
    finally:
        if owned:
            executor.close()
    done = [record_log.evaluations[i] for i in range(settings.budget)]
    size = next((len(r["feature"]) for r in done if r["feature"] is not None), 1)
    features = np.array([r["feature"] if r["feature"] is not None else [np.nan] * size
                         for r in done])
    return SearchResult(np.array([r["x"] for r in done]), features, [r["kind"] for r in done],
                        [r.get("failure") for r in done])


def _check_feature_size(record, record_log, settings):
    """A SearchError when a successful evaluation's feature has another size than the earlier
    ones', or one the settings cannot use."""
    earlier = next((r for r in record_log.evaluations.values() if r["feature"] is not None),
                   None)
    if earlier is not None and len(earlier["feature"]) != len(record["feature"]):
        raise SearchError(f"evaluation {record['index']} at x = {record['x']} returned "
                          f"{len(record['feature'])} numbers; earlier evaluations returned "
                          f"{len(earlier['feature'])}")
    try:
        settings.check_feature_dim(len(record["feature"]))
    except ValueError as error:
        raise SearchError(f"evaluation {record['index']} at x = {record['x']}: {error}") from None


def _run_rounds(settings, record_log, history, evaluate, finish, dim, executor):
    """Plan (or read back) each round's points and evaluate those the log does not hold."""
    first = 0
    while first < settings.budget:
        count = min(settings.batch, settings.budget - first)
        if first in record_log.plans:       # perhaps planned under a larger budget
            points, kinds = record_log.plans[first]
            points, kinds = points[:count], kinds[:count]
        else:
            x_unit, features, failed_unit = history()
            points, kinds, chances = plan_round(settings, first, count, x_unit, features, dim,
                                                failed_unit)
            points = [np.asarray(p).tolist() for p in points]
            record_log.add_plan(first, points, kinds, chances)
        todo = [first + j for j in range(len(points))
                if first + j not in record_log.evaluations]
        _evaluate_round(executor, evaluate, finish,
                        [(i, points[i - first], kinds[i - first]) for i in todo])
        first += len(points)


def _evaluate_round(executor, evaluate, finish, jobs):
    """Evaluate the jobs (index, point, kind) of a round through the executor and pass each
    record to `finish` in index order: each as soon as those before it are finished; on an
    error, the records that did come back (still in index order) before the error propagates.
    The first error is the one raised; a record that fails too is left for the resumed search
    to evaluate again."""
    waiting = [index for index, _, _ in jobs]          # indices not yet finished, in order
    returned = {}
    results = executor.map_unordered(evaluate, jobs)
    try:
        for j, record in results:
            returned[jobs[j][0]] = record
            while waiting and waiting[0] in returned:
                finish(returned.pop(waiting.pop(0)))
    except BaseException:
        results.close()                                 # stops the evaluations still running
        for index in sorted(returned):
            with contextlib.suppress(Exception):
                finish(returned[index])
        raise
