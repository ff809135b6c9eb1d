"""Stage 2 of strategy discovery: novel policy seeking (thesis §3.5.2, §3.7.1).

From the take-off state of a Stage-1 strategy a new policy is trained, warm-started from that
strategy's Stage-1 policy, with the reward r = r_task · r_naturalness · r_novelty (eq. 3.15),
where r_novelty = clip(min_i d(f, f_i) / d_threshold, 0.01, 1) (eq. 3.12): f is the 3-D root
orientation where the centre of mass crosses the bar plane (a rotation vector, relative to the
facing frame at take-off; §3.6.1, `agents.tasks.jump`), the f_i are those of the policies found
so far, d is the geodesic angle between two rotations and d_threshold = π/2 (§3.6.2).

A training config's optional `[novelty]` section makes its run a Stage-2 run:

    [novelty]
    warm_start = "runs/search/evaluations/002/train"   # the Stage-1 run to start from
    known = [[0.1, -0.2, 1.4]]      # the f_i: rotation vectors of the policies found so far
    search = "runs/search"          # and/or: every policy that strategy search has found
    threshold = 1.5707963           # d_threshold (default π/2)
    distance = "rotation"           # d, a feature distance of bds.acquisition

The warm start. The run's first state takes from the Stage-1 checkpoint the policy and value
networks, their optimiser states, the observation statistics, the sample count (so the policy's
exploration noise σ goes on from where Stage 1 left it rather than jumping back to its start)
and the curriculum's state (so Stage 2 goes on at the Stage-1 policy's bar height, not from
z_min). Its environments start afresh at that height from the run's own seed, and its iteration
count starts at 0, so `[run].iterations` counts Stage 2's iterations. The networks must match:
the same task, `ppo.hidden` and the task's settings that size them (its `fixed_on_resume`:
character, actions, pvae). A resumed Stage-2 run (`takeoff train --resume`) continues from its
own checkpoint like any run; its warm_start cannot change.

`search` is read once, when the run starts: the run's config.json then holds in `known` the
features given and those read, so a resumed run keeps the reward it started with. What a search
has found (`found_policies`): its Stage-1 evaluations that succeeded (those of its log, within
its budget) and its Stage-2 runs that succeeded (SEARCH/stage2/NNN/result.json), each with the
3-D crossing feature of its result.json.

The Stage-1 strategies of a search (`stage1_strategies`) are its successful evaluations grouped
by `bds.strategies` with the threshold and distance its own summary uses; each strategy's
representative is the evaluation that cleared the highest bar.
"""

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents import config as config_io
from agents.checkpoint import CheckpointError, previous_path
from agents.config import ConfigError
from agents.discovery import jump_black_box
from agents.rl import trainer as trainer_lib
from bds import strategies
from bds.acquisition import distance_function
from bds.novelty import novelty_reward
from bds.search import SEARCH_LOG, SearchError, logged_evaluations

RETRAINED = "retrained"     # evaluations/NNN/retrained: a lost Stage-1 policy, trained again
FEATURE_SIZE = 3            # the root orientation at the bar crossing, as a rotation vector
STAGE2 = "stage2"           # SEARCH/stage2: the Stage-2 runs of a search
PLAN = "plan.json"          # a Stage-2 directory's rounds (`takeoff stage2`)
KNOWN = "known.json"        # a round's known features, with which policy each is
RUN_CONFIG = "stage2.toml"  # a round's training config


@dataclass(frozen=True)
class NoveltySettings:
    """The `[novelty]` section of a training config (see the module docstring)."""

    warm_start: str = ""                         # a Stage-1 run directory
    known: tuple[tuple[float, ...], ...] = ()    # rotation vectors of the policies found so far
    search: str = ""                             # a strategy-search directory, read at the start
    threshold: float = math.pi / 2               # d_threshold (§3.6.2)
    distance: str = "rotation"                   # geodesic angle between rotations

    def __post_init__(self):
        if not self.warm_start:
            raise ValueError("warm_start must name the Stage-1 run directory to start from (a "
                             "`takeoff train` run of the same task and networks)")
        config_io.check_positive(self, ("threshold",))
        try:
            distance_function(self.distance)
        except ValueError as error:
            raise ValueError(f"distance: {error}") from None
        for index, feature in enumerate(self.known):
            if len(feature) != FEATURE_SIZE:
                raise ValueError(f"known[{index}] must be {FEATURE_SIZE} numbers, a rotation "
                                 "vector (the root's orientation at the bar crossing); got "
                                 f"{list(feature)}")
        if not self.known and not self.search:
            raise ValueError("give the features of the policies found so far: known (rotation "
                             "vectors) and/or search (a strategy-search directory)")


def novelty_function(settings: NoveltySettings):
    """features -> r_novelty (eq. 3.12) of the crossing orientation `cross_rotvec`, traced."""
    known = np.asarray(settings.known, float).reshape(-1, FEATURE_SIZE)
    if not len(known):
        raise ConfigError("novelty.known is empty: a Stage-2 reward needs the features of the "
                          "policies found so far (`search` is read when the run starts)")

    def novelty(features):
        feature = features["cross_rotvec"]
        return novelty_reward(feature, jnp.asarray(known, feature.dtype), settings.threshold,
                              settings.distance)
    return novelty


def novelty_env(env, settings: NoveltySettings):
    """`env` with its reward × r_novelty (eq. 3.15); a ConfigError for a task without strategy
    features."""
    if not hasattr(env, "with_novelty"):
        raise ConfigError("this task has no strategy features to reward the novelty of; a "
                          "[novelty] section (Stage 2) goes with a jump task (highjump, obstacle)")
    return env.with_novelty(novelty_function(settings))


# ---- a new Stage-2 run -------------------------------------------------------------------------

def _networks_keys(config) -> tuple[str, ...]:
    """The config keys that size a run's networks."""
    return ("run.task", "ppo.hidden",
            *(f"{config.run.task}.{name}" for name in config.entry.fixed_on_resume))


def prepare(config, source):
    """The config of a new Stage-2 run, its warm start checked against it and the features of
    `search` added to `known`; a ConfigError naming the key for what does not fit."""
    from agents.commands import train_commands
    novelty = config.novelty
    where = Path(novelty.warm_start)
    if not (where / train_commands.CONFIG).is_file():
        raise ConfigError(f"{source}: novelty.warm_start: {where} is not a training run "
                          f"directory (it has no {train_commands.CONFIG})")
    checkpoint = where / trainer_lib.CHECKPOINT
    if not (checkpoint.is_file() or previous_path(checkpoint).is_file()):
        raise ConfigError(f"{source}: novelty.warm_start: {where} has no checkpoint to start "
                          "from")
    stage1 = train_commands.load_run_config(where)
    stage1_sections, sections = stage1.sections(), config.sections()
    for key in _networks_keys(config):
        section, name = key.split(".")
        before, now = stage1_sections[section][name], sections[section][name]
        if before != now:
            raise ConfigError(
                f"{source}: novelty.warm_start: {where} was trained with {key} = {before!r} "
                f"and this config has {now!r}; a warm start needs the same networks (the same "
                f"task, ppo.hidden and {config.run.task} character, actions and pvae)")
    known = list(novelty.known)
    if novelty.search:
        try:
            known += [policy.cross_rotvec for policy in found_policies(novelty.search)]
        except (SearchError, ConfigError) as error:
            raise ConfigError(f"{source}: novelty.search: {error}") from None
        if not known:
            raise ConfigError(f"{source}: novelty.search: {novelty.search} has found no policy "
                              "yet, and known is empty: there is nothing to be novel against")
    return dataclasses.replace(config, novelty=dataclasses.replace(novelty, known=tuple(known)))


def warm_start(trainer, config, source, echo=print):
    """The first state of a Stage-2 run (thesis §3.7.1: "Training is warm started with the
    associated Stage 1 policy"): see the module docstring for what it takes from the Stage-1
    checkpoint. A ConfigError naming novelty.warm_start when that checkpoint's networks do not
    fit this run's."""
    from agents.commands import train_commands
    where = Path(config.novelty.warm_start)
    stage1_envs = train_commands.load_run_config(where).run.envs
    shapes = jax.eval_shape(trainer.init)
    template = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), shapes)
    template = dataclasses.replace(template, runner=jax.tree_util.tree_map(
        lambda s: np.zeros((stage1_envs, *s.shape[1:]), s.dtype), shapes.runner))
    try:
        stage1 = trainer_lib.load_checkpoint(template, where, echo)
    except CheckpointError as error:
        raise ConfigError(f"{source}: novelty.warm_start: the checkpoint of {where} does not "
                          f"fit this run's networks: {error}") from None
    fresh = trainer.init(curriculum=stage1.curriculum)
    ppo = dataclasses.replace(stage1.ppo, iteration=jnp.zeros_like(stage1.ppo.iteration))
    at = ", ".join(f"{name} {float(value):g}"
                   for name, value in trainer.curriculum.metrics(stage1.curriculum).items())
    echo(f"warm start from {where}: its policy after {int(stage1.ppo.iteration)} iterations "
         f"({int(stage1.ppo.samples):,} samples){f', {at}' if at else ''}")
    return trainer_lib.TrainState(ppo, stage1.norm, fresh.runner, fresh.key, stage1.curriculum)


# ---- what a search has found -------------------------------------------------------------------

class Policy(NamedTuple):
    """A policy a search found: its name ("evaluation 3", "stage2 001"), its 3-D crossing
    feature and its result.json."""
    name: str
    cross_rotvec: tuple[float, ...]
    result: dict


class Stage1Strategy(NamedTuple):
    label: int                       # bds.strategies' label, as the search's summary numbers it
    evaluations: tuple[int, ...]     # its evaluations, in the order they were made
    representative: int              # the one that cleared the highest bar (the first of equals)


def read_search(search_dir):
    """(the search's config.json as a dict, its evaluation records within its budget); a
    SearchError when `search_dir` is not the directory of a jump search."""
    directory = Path(search_dir)
    path = directory / "config.json"
    if not path.is_file():
        raise SearchError(f"{directory}: not a strategy-search directory (it has no config.json)")
    config = config_io.read_stored(path)
    if config.get("black_box") != "jump":
        raise SearchError(f"{directory}: a search of the {config.get('black_box')!r} black box; "
                          "Stage 2 needs a jump search (black_box = \"jump\")")
    records = logged_evaluations(directory / SEARCH_LOG)
    return config, records[:config["search"]["budget"]]


def _stage1_result(search_dir, index) -> dict:
    """The result.json of a Stage-1 evaluation the log says succeeded."""
    directory = jump_black_box.evaluation_dir(search_dir, index)
    result = jump_black_box.read_result(directory)
    if result is None or result.get("outcome") != "success":
        why = "it has no result.json" if result is None else "its result.json says it failed"
        raise SearchError(f"{directory}: the search's log has this evaluation succeed, but "
                          f"{why}")
    return result


def _policy(name, result, path) -> Policy:
    feature = (result.get("feature") or {}).get("cross_rotvec")
    if (not isinstance(feature, list) or len(feature) != FEATURE_SIZE
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in feature)):
        raise SearchError(f"{path}: feature.cross_rotvec must be {FEATURE_SIZE} finite numbers; "
                          f"got {feature!r}")
    return Policy(name, tuple(float(v) for v in feature), result)


def stage2_results(stage2_dir) -> list[tuple[int, dict]]:
    """(index, result) of the finished Stage-2 runs under `stage2_dir`, by index."""
    found = []
    for directory in sorted(Path(stage2_dir).glob("[0-9][0-9][0-9]")):
        result = jump_black_box.read_result(directory)
        if result is not None:
            found.append((int(directory.name), result))
    return found


def found_policies(search_dir, stage2_dir=None) -> list[Policy]:
    """Every policy the search in `search_dir` has found so far: its successful Stage-1
    evaluations — each followed by its policy trained again (evaluations/NNN/retrained), where
    Stage 2 had to retrain a lost one and it succeeded: a new training from the same x crosses
    in its own orientation, and a round that warm-starts from it must be novel against that
    one too —, then its successful Stage-2 runs (under `stage2_dir`, default SEARCH/stage2)."""
    _, records = read_search(search_dir)
    policies = []
    for record in records:
        if record["feature"] is not None:
            directory = jump_black_box.evaluation_dir(search_dir, record["index"])
            result = _stage1_result(search_dir, record["index"])
            policies.append(_policy(f"evaluation {record['index']}", result, directory))
            again = jump_black_box.read_result(directory / RETRAINED)
            if again is not None and again.get("outcome") == "success":
                policies.append(_policy(f"evaluation {record['index']} (retrained)", again,
                                        directory / RETRAINED))
    stage2_dir = Path(search_dir) / STAGE2 if stage2_dir is None else Path(stage2_dir)
    for index, result in stage2_results(stage2_dir):
        if result.get("outcome") == "success":
            policies.append(_policy(f"stage2 {index:03d}", result, stage2_dir / f"{index:03d}"))
    return policies


def stage1_strategies(search_dir) -> list[Stage1Strategy]:
    """The distinct Stage-1 strategies of a search, in the order they were found."""
    config, records = read_search(search_dir)
    threshold = config.get("same_strategy") or strategies.UP_ANGLE_THRESHOLD
    labels = strategies.group([r["feature"] for r in records], threshold,
                              config["search"].get("distance", "euclidean"))
    found = []
    for label in range(int(labels.max(initial=-1)) + 1):
        members = tuple(r["index"] for r, l in zip(records, labels) if l == label)
        found.append(Stage1Strategy(label, members, highest_bar(search_dir, members)[0]))
    return found


def highest_bar(search_dir, evaluations) -> tuple[int, float]:
    """(the one of the successful Stage-1 `evaluations` that cleared the highest bar, the first
    of equals; that bar)."""
    cleared = {i: _stage1_result(search_dir, i).get("highest_cleared") or 0.0
               for i in evaluations}
    best = max(evaluations, key=lambda i: (cleared[i], -i))
    return best, cleared[best]


def round_verdict(directory, result) -> dict | None:
    """Eq. 3.12's verdict on the Stage-2 round in `directory` whose measured `result` is a
    success: {novel, nearest (the known policy's name), distance, threshold}, against the
    features it was trained against (KNOWN) with its config's (RUN_CONFIG) threshold and
    distance; None when the round kept no KNOWN. What `takeoff stage2`'s summary and the
    gallery both say of a round."""
    directory = Path(directory)
    if not (directory / KNOWN).is_file():
        return None
    known = json.loads((directory / KNOWN).read_text())
    section = (config_io.read(directory / RUN_CONFIG).get("novelty", {})
               if (directory / RUN_CONFIG).is_file() else {})
    threshold = section.get("threshold", NoveltySettings.threshold)
    novel, nearest, gap = is_novel(result["feature"]["cross_rotvec"],
                                   [k["cross_rotvec"] for k in known], threshold,
                                   section.get("distance", NoveltySettings.distance))
    return {"novel": novel, "nearest": known[nearest]["policy"], "distance": gap,
            "threshold": threshold}


def is_novel(feature, known, threshold, distance="rotation") -> tuple[bool, int, float]:
    """(whether `feature` is farther than `threshold` from every one of `known` (k, 3) — where
    r_novelty (eq. 3.12) reaches 1 —, the index of the nearest, its distance)."""
    gaps = np.asarray(distance_function(distance)(jnp.asarray(feature, float),
                                                  jnp.asarray(known, float)))
    nearest = int(np.argmin(gaps))
    return bool(gaps[nearest] > threshold), nearest, float(gaps[nearest])

