"""The real black box of strategy discovery (thesis §3.5.1, Algorithm 1 line 9): g(x) trains a jump
policy from the take-off state x and returns the Stage-1 strategy feature of what it learned.

One evaluation, in its own directory `<search>/evaluations/NNN/` (NNN its index in the search):

1. Train (`takeoff train` with the config `[jump].train`, its task's `takeoff` set to x) with the
   curriculum from z_min until the bar reaches z_freeze, or the budget (`samples`, and `minutes`
   of training when given) is spent, whichever comes first. A training that is going nowhere
   stops early ("bad initial states will fail fast", §3.4.1), at the first of two give-up
   points that judges it so:
   - `probe_samples` (off at 0): the training's iterations up to there crossed the bar's plane
     in at most `probe_crossing` of their episodes (each iteration's share, averaged over the
     iterations in which an episode ended). Those are the nearly untrained policy's
     exploratory episodes, and in the plain-PD high-jump searches every take-off state whose
     training succeeded had 6.6 % or more of them cross in its first 10 iterations, every one
     that failed 3.6 % or less (docs/discovery, "Does the untrained policy foretell a
     training's outcome?");
   - `give_up_samples` (off at 0): at most `give_up_success` of the episodes of the iteration
     there succeeded.
   A training given up is then measured like any other and, clearing nothing, is a failure.
   The run directory is `train/`; an evaluation killed mid-training resumes from its last
   checkpoint (the budget counts the training minutes its metrics log already holds).
2. Measure: the deterministic policy's episodes at the height the training reached; if most of
   them fail there, at z_min. The evaluation succeeds when most episodes clear the bar at one of
   the two; its feature is then the mean, over the clearing episodes, of `up_angle` (the angle
   between the root's facing direction and the up axis where the centre of mass crosses the bar
   plane, §3.6.1; `agents.tasks.jump`) and its highest bar cleared is that height. Otherwise it
   is a failure (`bds.search.Failure`, with why), which the search logs without a feature.
3. Keep: `result.json` (x, outcome, reason, feature, the 3-D root orientation at the crossing
   for Stage 2, heights, samples, minutes), `episode.npz` (the poses of one evaluated episode
   at its control steps) and `peak.png` (the peak pose along and across the bar).

`result.json` is written last, atomically: an evaluation whose result is there is not trained or
measured again (a search killed after it and before its log line returns it as it was).
"""

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bds.search import Failure, SearchError
from jaxsim.atomic import atomic_path, write_text_atomic

EVALUATIONS = "evaluations"
TRAIN, RESULT, EPISODE, PEAK = "train", "result.json", "episode.npz", "peak.png"
MAJORITY = 0.5              # share of the evaluation episodes that must clear the bar
DIFFICULTY_TOLERANCE = 1e-5


@dataclass(frozen=True)
class JumpBlackBoxSettings:
    """The `[jump]` section of a search config whose black box is a jump task."""

    train: str = "configs/highjump.toml"    # the training config of every evaluation
    set: tuple[str, ...] = ()               # its overrides, as `takeoff train --set`
    samples: int = 2_000_000                # training budget per evaluation (samples)
    minutes: float = 0.0                    # and (when > 0) training minutes
    z_freeze: float = 0.0                   # where training stops; 0: the task's own z_freeze
    probe_samples: int = 0                  # stop a training going nowhere here (0: never) …
    probe_crossing: float = 0.05            # … when at most this share of its episodes crossed
    give_up_samples: int = 0                # stop a training going nowhere here (0: never) …
    give_up_success: float = 0.01           # … when at most this share of its episodes succeed
    episodes: int = 4                       # deterministic evaluation episodes

    def __post_init__(self):
        if self.samples < 1:
            raise ValueError(f"samples must be at least 1; got {self.samples}")
        for name in ("probe_samples", "give_up_samples"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be ≥ 0; got {getattr(self, name)}")
        for name in ("probe_crossing", "give_up_success"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name} must be in [0, 1); got {getattr(self, name)}")
        if self.episodes < 1:
            raise ValueError(f"episodes must be at least 1; got {self.episodes}")
        for name in ("minutes", "z_freeze"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be ≥ 0; got {getattr(self, name)}")


def evaluation_dir(search_dir, index: int) -> Path:
    """Where evaluation `index` of the search in `search_dir` keeps its files."""
    return Path(search_dir) / EVALUATIONS / f"{index:03d}"


def read_result(directory) -> dict | None:
    """An evaluation directory's result.json (None when it has none yet)."""
    path = Path(directory) / RESULT
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise SearchError(f"{path}: unreadable ({error}); delete it to evaluate again") from None


def outcome(result: dict):
    """What g(x) returns for a result: its feature, or its Failure."""
    if result["outcome"] == "failure":
        return Failure(result["reason"])
    return np.array([result["feature"]["up_angle"]])


@dataclass(frozen=True, eq=False)
class JumpBlackBox:
    """g(x) of a jump task (see the module docstring); picklable, so worker processes can run
    it."""

    settings: JumpBlackBoxSettings
    search_dir: Path
    data_dir: Path | None = None

    def _overrides(self, x, base, iterations):
        """The training config's overrides for the evaluation at x, trained for `iterations`."""
        z_freeze = self.settings.z_freeze or base.task.z_freeze
        return [*self.settings.set, f"{base.run.task}.takeoff={[float(v) for v in x]}",
                f"run.stop_difficulty={z_freeze}", f"run.iterations={iterations}",
                f"run.time_limit_minutes={self.settings.minutes}"]

    def evaluate(self, index: int, x) -> np.ndarray | Failure:
        directory = evaluation_dir(self.search_dir, index)
        x = np.asarray(x, float)
        done = read_result(directory)
        if done is not None:
            if not same_x(done["x"], x):
                raise SearchError(f"{directory / RESULT} holds the evaluation of x = "
                                  f"{done['x']}, but this search's evaluation {index} is at "
                                  f"x = {x.tolist()}; the directory belongs to another search")
            return outcome(done)
        why = self.train(directory / TRAIN, x)
        return outcome(self._measure(directory, index, x, why))

    def give_up_points(self, samples_per_iteration: int) -> list:
        """(iteration, judge) of each give-up point of the module docstring that is on, in the
        order a training reaches them; judge(records, iteration) says why a training whose
        metrics records are `records` is given up there, or None."""
        settings = self.settings
        points = [(_iterations(samples, samples_per_iteration), judge) for samples, judge in (
            (settings.probe_samples, self._too_few_crossed),
            (settings.give_up_samples, self._too_few_succeeded))
            if 0 < samples < settings.samples]
        return sorted(points, key=lambda point: point[0])

    def _too_few_crossed(self, records, iteration: int) -> str | None:
        """The `probe_samples` point's judge: the share of the episodes of iterations 1 …
        `iteration` that crossed the bar's plane (each iteration's share, averaged)."""
        crossed = early_share(records, "env/episode/crossed", iteration)
        if crossed is None:
            raise SearchError(_no_share("probe_samples", "env/episode/crossed", records,
                                        iteration))
        if crossed > self.settings.probe_crossing:
            return None
        return (f"{crossed:.1%} of its first {iteration} iterations' episodes crossed the bar's "
                f"plane (given up at {self.settings.probe_crossing:.1%} or less)")

    def _too_few_succeeded(self, records, iteration: int) -> str | None:
        """The `give_up_samples` point's judge, by the share of iteration `iteration`'s
        episodes that succeeded (of the last iteration before it in which an episode ended,
        when none did in it)."""
        key = "env/episode/success"
        shares = _shares(records, key, iteration)
        if not shares:
            raise SearchError(_no_share("give_up_samples", key, records, iteration))
        if shares[-1] > self.settings.give_up_success:
            return None
        return (f"{shares[-1]:.1%} of the episodes succeeded after "
                f"{self.settings.give_up_samples:,} samples (given up at "
                f"{self.settings.give_up_success:.1%} or less)")

    def train(self, run_dir: Path, x) -> str | None:
        """Train the policy of x in `run_dir` in legs that end at the give-up points and at
        `samples`, stopping at the first point that judges the training to be going nowhere
        (see the module docstring); resume it from its checkpoint, or do nothing when it is
        finished. Returns why it gave up, or None."""
        from agents.commands import train_commands
        from agents.rl import trainer as trainer_lib
        settings = self.settings
        x = np.asarray(x, float)
        base = train_commands.load_config(settings.train, settings.set)
        points = self.give_up_points(base.run.samples_per_iteration)
        legs = [*points, (_iterations(settings.samples, base.run.samples_per_iteration), None)]
        echo = prefixed_echo(f"  [g {run_dir.parent.name}] ")
        for leg_iterations, judge in legs:
            def finished(config, last):
                if not same_x(config.sections()[config.run.task]["takeoff"], x):
                    raise SearchError(f"{run_dir} trains from another take-off state than x = "
                                      f"{x.tolist()}; the directory belongs to another search")
                return self._stopped(config, last, leg_iterations)

            def resume_overrides(config, last):  # this leg's end, the time budget left
                limit = max(self._minutes_left(last), 1e-3) if settings.minutes else 0.0
                return [f"run.iterations={leg_iterations}", f"run.time_limit_minutes={limit}"]

            train_commands.train_or_resume(settings.train, run_dir,
                                           self._overrides(x, base, leg_iterations),
                                           self.data_dir, echo, finished, resume_overrides)
            records = trainer_lib.read_metrics(run_dir)
            # a training that stopped before the point (at z_freeze, or out of minutes) is not
            # judged there: it was not given up
            why = (judge and records[-1]["iteration"] >= leg_iterations
                   and judge(records, leg_iterations))
            if why:
                echo(f"gave up: {why}")
                return why
        return None

    def trained(self, run_dir: Path) -> bool:
        """Whether the training in `run_dir` has a checkpoint and stopped where its last leg
        was to stop (`_stopped`): the iterations that leg asked for (all of `samples`, or a
        give-up point's), the bar at z_freeze, or (when given) `minutes` spent, counted over
        all its legs and resumes. A killed training has not.

        One gap, with `minutes`: a training hard-killed (SIGKILL) after logging iterations past
        its checkpoint is resumed with the minutes left after its last logged iteration, not
        after its checkpoint's, so its time runs out up to one checkpoint interval short of
        `minutes`, and it does not count as trained here (Stage 2 then trains it on for those
        minutes). The checkpoint's iteration is known only to whoever reads the checkpoint."""
        from agents.commands import train_commands
        from agents.rl import trainer as trainer_lib
        if not trainer_lib.has_checkpoint(run_dir):
            return False
        config = train_commands.load_run_config(run_dir)
        return self._stopped(config, trainer_lib.last_record(run_dir), config.run.iterations)

    def _stopped(self, config, last: dict, iterations: int) -> bool:
        """Whether a training with the stored `config`, whose last metrics record is `last`,
        stops there when trained to `iterations`: it has run them, its bar has reached its
        stop difficulty (z_freeze), or its minutes are spent."""
        from agents.rl import trainer as trainer_lib
        return (last.get("iteration", 0) >= iterations
                or trainer_lib.reached(last, config.run.stop_difficulty)
                or bool(self.settings.minutes and self._minutes_left(last) <= 0))

    def _minutes_left(self, last: dict) -> float:
        """The training minutes `minutes` leaves after the metrics record `last` (whose
        seconds count every leg and resume)."""
        return self.settings.minutes - last.get("seconds", 0.0) / 60

    def _measure(self, directory: Path, index: int, x, why: str | None) -> dict:
        """Evaluate the trained policy (see the module docstring), keep its files, return its
        result (`gave_up` and, when it did, `gave_up_because`)."""
        given_up = {"gave_up": True, "gave_up_because": why} if why else {"gave_up": False}
        return measure(directory, directory / TRAIN, self.settings.episodes, self.data_dir,
                       index=index, x=x.tolist(), **given_up)


def measure(directory: Path, run_dir: Path, episodes: int, data_dir=None, **fields) -> dict:
    """Steps 2 and 3 of the module docstring, for the policy trained in `run_dir`: measure it
    with `episodes` deterministic episodes, keep episode.npz, peak.png and result.json in
    `directory`, and return the result, which begins with `fields` (what the caller records of
    the policy: its index, x, …). Stage 1's evaluations and Stage 2's runs are measured by it."""
    from agents.commands import train_commands
    from agents.rl import trainer as trainer_lib
    directory = Path(directory)
    config = train_commands.load_run_config(run_dir)
    z_min = config.sections()[config.run.task]["z_min"]
    quiet = lambda *_: None
    measured = train_commands.run_episodes(run_dir, episodes, data_dir, echo=quiet)
    reached = float(measured.summary["episode/difficulty"])
    feature = crossing_feature(measured.outcomes)
    if feature is None and reached > z_min + DIFFICULTY_TOLERANCE:
        measured = train_commands.run_episodes(run_dir, episodes, data_dir, difficulty=z_min,
                                               echo=quiet)
        feature = crossing_feature(measured.outcomes)
    cleared = _cleared(measured.outcomes)
    last = trainer_lib.read_metrics(run_dir)[-1]
    height = float(measured.summary["episode/difficulty"])
    result = {**fields, "task": config.run.task,
              "reached": reached, "samples": int(last["samples"]),
              "minutes": last["seconds"] / 60, "iterations": int(last["iteration"]),
              "training_success": last.get("env/episode/success"),
              "episodes": episodes, "cleared_share": float(cleared.mean()),
              "evaluated_at": height}
    if feature is not None:
        result.update(outcome="success", reason=None, highest_cleared=height, feature=feature)
    else:
        result.update(outcome="failure", highest_cleared=None, feature=None, reason=(
            f"the deterministic policy cleared {int(cleared.sum())} of {cleared.size} "
            f"episodes at {height:.2f} m after {result['samples']:,} training samples "
            f"({result['minutes']:.0f} min{_given_up(fields)}); "
            f"in its last training iteration {_share_text(result['training_success'])}"))
    _keep_episode(directory, measured, height)
    write_text_atomic(directory / RESULT, json.dumps(result, indent=2) + "\n")
    return result


def early_share(records, key: str, iterations: int) -> float | None:
    """The mean of the metric `key` (an episode share, e.g. "env/episode/crossed") over training
    iterations 1 … `iterations` of a metrics log's `records`, leaving out iterations in which
    no episode ended (None); None when no iteration has it."""
    shares = _shares(records, key, iterations)
    return float(np.mean(shares)) if shares else None


def _shares(records, key: str, iterations: int) -> list:
    """The metric `key` of training iterations 1 … `iterations`, in order, leaving out those in
    which no episode ended (None) or that lack it."""
    return [r[key] for r in records if r["iteration"] <= iterations and r.get(key) is not None]


def same_x(stored, x) -> bool:
    """Whether a take-off state kept in a run's files is the x it is now asked for (one
    tolerance for every such check: the files hold x as JSON floats)."""
    stored, x = np.asarray(stored, float), np.asarray(x, float)
    return stored.shape == x.shape and bool(np.allclose(stored, x, rtol=0, atol=1e-9))


def _no_share(point: str, key: str, records, iteration: int) -> str:
    """Why the give-up point `point` cannot judge a training by the episode share `key`."""
    if not any(key in r for r in records):
        return (f"the give-up point {point} needs the training iterations' {key}, which this "
                "task's metrics do not have")
    return (f"the give-up point {point} judges by {key}, but no episode ended in the training's "
            f"first {iteration} iterations; set {point} later")


def _share_text(success) -> str:
    """The last training iteration's success share, for a failure's reason."""
    if success is None:
        return "no episode ended"
    return f"{100 * success:.1f}% of the episodes succeeded"


def _given_up(fields) -> str:
    """', given up' and why, for a failure's reason, when the training was given up."""
    if not fields.get("gave_up"):
        return ""
    because = fields.get("gave_up_because")
    return f", given up: {because}" if because else ", given up"


def _iterations(samples: int, samples_per_iteration: int) -> int:
    """The training iterations that `samples` take (the last one may run past them)."""
    return math.ceil(samples / samples_per_iteration)


def _cleared(outcomes) -> np.ndarray:
    return np.asarray(outcomes["episode/success"]) > 0.5


def crossing_feature(outcomes) -> dict | None:
    """The strategy features of deterministic episodes (`outcomes`: each `episode/` metric per
    episode, where it ended) when more than half of them cleared the bar: the means, over the
    clearing episodes, of the up angle (Stage 1's feature), the 3-D root orientation at the
    crossing (Stage 2's), the centre of mass's height over the bar there and its peak height.
    None when too few cleared."""
    cleared = _cleared(outcomes)
    if not cleared.mean() > MAJORITY:
        return None
    mean = lambda name: float(np.mean(np.asarray(outcomes[f"episode/{name}"])[cleared]))
    return {"up_angle": mean("up_angle"),
            "cross_rotvec": [mean(f"cross_rotvec_{axis}") for axis in "xyz"],
            "clearance": mean("clearance"), "peak_com": mean("peak_com")}


def _keep_episode(directory: Path, episodes, height: float):
    """episode.npz and peak.png of the evaluated episode 0."""
    from agents.discovery import pictures
    env, poses = episodes.env, episodes.poses
    with atomic_path(directory / EPISODE) as path:
        with open(path, "wb") as f:
            np.savez(f, poses=poses, control_dt=env.control_dt, difficulty=height,
                     takeoff=np.asarray(episodes.task["takeoff"]))
    pictures.peak_views(env, poses, episodes.task, directory / PEAK)


def read_episode(directory, dtype):
    """The episode `_keep_episode` kept in `directory`: its poses (T, nq), control step and the
    task parameters it ran with (take-off state and bar height, as `dtype` arrays)."""
    import jax.numpy as jnp
    with np.load(Path(directory) / EPISODE) as data:
        task = {name: jnp.asarray(data[name], dtype) for name in ("takeoff", "difficulty")}
        return np.asarray(data["poses"]), float(data["control_dt"]), task


def prefixed_echo(prefix):
    """An echo that prints each line of its text behind `prefix`, so that the lines of jobs
    sharing one log say whose they are. A message's leading newlines (the trainer starts its
    "interrupted" line with one, to leave a terminal's ^C behind) are dropped, not printed as
    empty prefixed lines."""
    def echo(text=""):
        print("\n".join(prefix + line for line in str(text).lstrip("\n").split("\n")))
    return echo
