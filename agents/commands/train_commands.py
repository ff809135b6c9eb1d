"""`takeoff train`, `takeoff eval` and `takeoff plot`: training runs from TOML configs.

A config has three sections: `[run]` (which task, how many environments, how long), `[ppo]`,
and the section of its task, named after it (`[imitation]`, `[reach]`, `[highjump]`, …; the
tasks are registered in `agents.tasks.registry`); a jump task's config may have a
`[novelty]` section, which makes the run Stage 2 of strategy discovery
(`agents.discovery.stage2`), and a `[physics]` section, factors on its body and world
(`agents.tasks.physics`).
A run directory holds the resolved config (`config.json`), `metrics.jsonl` (one line per
iteration), `checkpoint.msgpack` (written atomically) and `learning_curve.png`. A resumed run
may change how long it runs, its learning settings and its task's settings with `--set`, but
not what its checkpoint fixes (`[run]`'s `RunSettings.SHAPING`, `ppo.hidden`, the keys its task
declares in `fixed_on_resume`, and a Stage-2 run's `novelty.warm_start`).
"""

import dataclasses
import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents import config as config_io
from agents.checkpoint import previous_path
from agents.rl import parallel
from agents.rl import trainer as trainer_lib
from agents.datadir import data_dir_from
from agents.discovery import stage2
from agents.rl.ppo import PPOSettings
from agents.rl.rollout import start_runner
from agents.rl.trainer import RunSettings
from agents.tasks import physics as physics_lib
from agents.tasks import registry
from jaxsim.atomic import check_writable, hold_directory, write_text_atomic

CONFIG = "config.json"
CURVE = "learning_curve.png"


@dataclass(frozen=True)
class TrainConfig:
    """A training config: `[run]`, `[ppo]` and `task`, the settings of the section named by
    `run.task` (an instance of that task's registered settings dataclass)."""

    run: RunSettings = field(default_factory=RunSettings)
    ppo: PPOSettings = field(default_factory=PPOSettings)
    task: Any = None
    novelty: stage2.NoveltySettings | None = None      # Stage 2 (agents.discovery.stage2)
    physics: physics_lib.PhysicsSettings | None = None  # body and world factors

    def __post_init__(self):
        if not self.run.task:
            raise ValueError(f"run.task must name the task to train: one of "
                             f"{', '.join(registry.names())}")
        entry = registry.get(self.run.task)
        if self.physics is not None and not entry.takes_physics:
            raise ValueError(f"the task {self.run.task!r} does not take a [physics] section; "
                             "the tasks that do: " + ", ".join(
                                 n for n in registry.names() if registry.get(n).takes_physics))
        if not isinstance(self.task, entry.settings):
            raise ValueError(f"the [{self.run.task}] settings must be a "
                             f"{entry.settings.__name__}; got {type(self.task).__name__}")
        run, minibatch = self.run, self.ppo.minibatch_size
        if run.samples_per_iteration < minibatch:
            raise ValueError(f"run.envs × run.steps_per_iteration = {run.envs} × "
                             f"{run.steps_per_iteration} = {run.samples_per_iteration} samples "
                             f"per iteration, fewer than one minibatch (ppo.minibatch_size = "
                             f"{minibatch})")

    @property
    def entry(self) -> registry.Task:
        return registry.get(self.run.task)

    def sections(self) -> dict:
        """The config as nested dicts, its task's section under the task's name (config.json)."""
        return {"run": dataclasses.asdict(self.run), "ppo": dataclasses.asdict(self.ppo),
                self.run.task: dataclasses.asdict(self.task),
                **({} if self.novelty is None else {"novelty": dataclasses.asdict(self.novelty)}),
                **({} if self.physics is None else {"physics": dataclasses.asdict(self.physics)})}

    @property
    def fixed_on_resume(self) -> tuple[str, ...]:
        """Keys a resumed run cannot change: the seed (the checkpoint holds the PRNG state), the
        rollout's size, the hidden layers, and what the task says fixes its networks' sizes."""
        return (*(f"run.{name}" for name in RunSettings.SHAPING), "ppo.hidden",
                *(f"{self.run.task}.{name}" for name in self.entry.fixed_on_resume),
                "novelty.warm_start")


@dataclass(frozen=True)
class _Sections:
    run: RunSettings = field(default_factory=RunSettings)
    ppo: PPOSettings = field(default_factory=PPOSettings)


def build_config(data: dict, source) -> TrainConfig:
    """A TrainConfig from the nested dict of a TOML file or config.json; a ConfigError naming
    `source` and the key for anything wrong, an unknown section included."""
    if not isinstance(data, dict):
        raise config_io.ConfigError(f"{source}: the file must be a table")
    run_data = data.get("run", {})
    task = run_data.get("task") if isinstance(run_data, dict) else None
    if not task:
        raise config_io.ConfigError(f"{source}: [run]: run.task must name the task to train: "
                                    f"one of {', '.join(registry.names())}")
    if not isinstance(task, str):
        raise config_io.ConfigError(f"{source}: key 'run.task' must be a str; got {task!r}")
    try:
        entry = registry.get(task)
    except ValueError as error:
        raise config_io.ConfigError(f"{source}: [run]: {error}") from None
    unknown = sorted(set(data) - {"run", "ppo", task, "novelty", "physics"})
    if unknown:
        raise config_io.ConfigError(
            f"{source}: unknown section {unknown[0]!r}; a config for the task {task!r} takes "
            f"[run], [ppo], [{task}], [physics] and (Stage 2) [novelty]")
    sections = config_io.build(_Sections, {k: data[k] for k in ("run", "ppo") if k in data},
                               source)
    settings = config_io.build(entry.settings, data.get(task, {}), source, f"{task}.")
    novelty = (config_io.build(stage2.NoveltySettings, data["novelty"], source, "novelty.")
               if "novelty" in data else None)
    physics = (config_io.build(physics_lib.PhysicsSettings, data["physics"], source, "physics.")
               if "physics" in data else None)
    try:
        return TrainConfig(sections.run, sections.ppo, settings, novelty, physics)
    except ValueError as error:
        raise config_io.ConfigError(f"{source}: config: {error}") from None


def load_config(path, overrides=()) -> TrainConfig:
    """The training config in the TOML file `path`, with `--set` overrides."""
    return build_config(config_io.read(path, overrides), path)


def make_env(config: TrainConfig, data_dir=None):
    entry = config.entry
    env = entry.make_env(config.task, data_dir_from(data_dir) if entry.needs_data else None)
    if config.physics is not None:
        try:
            physics_lib.check_fits(env.model, config.physics)
        except ValueError as error:
            raise config_io.ConfigError(str(error)) from None
    return env if config.novelty is None else stage2.novelty_env(env, config.novelty)


def task_params(config: TrainConfig, env) -> dict:
    """The task parameters of the config's environment `env`: its defaults, with the
    `[physics]` factors when the config has that section."""
    params = env.default_params()
    if config.physics is None:
        return params
    dtype = jax.tree_util.tree_leaves(params)[0].dtype
    return {**params, "physics": physics_lib.params_of(config.physics, dtype)}


def make_trainer(config: TrainConfig, data_dir=None) -> trainer_lib.Trainer:
    """The trainer of a config. Configs that differ only in how long the loop runs share one
    trainer, and so its compiled iteration (a resumed run does not compile again)."""
    loop_only = dict(iterations=1, checkpoint_every=1, progress_every=1, time_limit_minutes=0.0,
                     stop_difficulty=0.0)
    compiled = _compiled_trainer(dataclasses.replace(
        config, run=dataclasses.replace(config.run, **loop_only)), data_dir)
    return compiled.with_run_settings(config.run)


@functools.lru_cache(maxsize=8)
def _compiled_trainer(config: TrainConfig, data_dir) -> trainer_lib.Trainer:
    env = make_env(config, data_dir)
    return trainer_lib.Trainer(env, task_params(config, env), config.run, config.ppo)


def _trainer_for(config: TrainConfig, source, data_dir) -> trainer_lib.Trainer:
    """`make_trainer`, with a task setting that does not fit the data (a ConfigError of the
    task) reported against the config file `source`."""
    try:
        return make_trainer(config, data_dir)
    except config_io.ConfigError as error:
        raise config_io.ConfigError(f"{source}: [{config.run.task}]: {error}") from None


def load_run_config(run_dir) -> TrainConfig:
    path = Path(run_dir) / CONFIG
    if not path.exists():
        raise config_io.ConfigError(f"{path}: missing; is {run_dir} a training run directory?")
    return build_config(config_io.read_stored(path), str(path))


def train_or_resume(config_path, run_dir, overrides=(), data_dir=None, echo=print,
                    finished=None, resume_overrides=None):
    """Train the run of `config_path` with `overrides` in `run_dir`, or, when `run_dir` already
    holds a checkpoint (a run killed part way), resume it: not at all when `finished(config,
    last metrics record)` says its budget was spent (by default: all its iterations done),
    else with the overrides `resume_overrides(config, last record)` gives (default: none). The
    rule every command that runs trainings as parts of its own work follows (a sweep's members,
    a search's evaluations), so a killed one loses at most one checkpoint interval."""
    run_dir = Path(run_dir)
    if not trainer_lib.has_checkpoint(run_dir):
        return train(config_path, run_dir, overrides, data_dir=data_dir, echo=echo)
    config = load_run_config(run_dir)
    last = trainer_lib.last_record(run_dir)
    done = (finished(config, last) if finished is not None
            else last.get("iteration", 0) >= config.run.iterations)
    if not done:
        train(resume=run_dir, data_dir=data_dir, echo=echo,
              overrides=resume_overrides(config, last) if resume_overrides else ())


def train(config_path=None, out_dir=None, overrides=(), resume=None, data_dir=None,
          echo=print, cluster=None):
    """Start a run from a config (in out_dir, default runs/<config name>) or resume one. With
    `cluster` (a `parallel.Cluster`), as one process of a multi-process run: every process
    calls this with the same arguments; only process 0 reads the checkpoint, writes the run
    directory and shows progress (the others read the config, and on resuming the run's
    config.json, so on a cluster the run directory must be on a shared filesystem to resume)."""
    if resume is not None:
        run_dir = Path(resume)
        source = run_dir / CONFIG
        config = load_run_config(run_dir)
        if overrides:
            config = overridden(config, overrides, source)
    else:
        source = config_path
        config = load_config(config_path, overrides)
        if config.novelty is not None:      # Stage 2: its warm start checked, `search` read
            config = stage2.prepare(config, source)
    parallel.start(config.run.devices, cluster)        # before anything starts JAX's backend
    writer = parallel.is_writer()
    if not writer:
        echo = _quiet
    if resume is None:
        run_dir = config_io.run_directory(
            config_path, out_dir, lambda d: writer and any(f.exists() for f in (
                d / trainer_lib.CHECKPOINT, previous_path(d / trainer_lib.CHECKPOINT))),
            "resume it with `takeoff train --resume {run_dir}` or pick another --out")
    _check_devices(config, source)
    trainer = _trainer_for(config, source, data_dir)
    state_bytes, sample_bytes = trainer.footprint()
    _check_memory(state_bytes + sample_bytes, source,
                  f"run.envs × run.steps_per_iteration = {config.run.envs} × "
                  f"{config.run.steps_per_iteration}")
    if not writer:
        return trainer, _train_in(run_dir, trainer, config, source, resume, writer, echo)
    existing = sum(f.stat().st_size for f in (run_dir / trainer_lib.CHECKPOINT,
                   previous_path(run_dir / trainer_lib.CHECKPOINT)) if f.is_file())
    check_writable(run_dir, 3 * state_bytes - existing + 2**20, "the run's checkpoints")
    with hold_directory(run_dir, "the run"):
        return trainer, _train_in(run_dir, trainer, config, source, resume, writer, echo)


def _train_in(run_dir, trainer, config, source, resume, writer, echo):
    """`train`'s work once the run directory is settled (and, by process 0, held): the
    starting state (new, warm-started or resumed), then the training; returns the last state."""
    state = (stage2.warm_start(trainer, config, source, echo)
             if resume is None and config.novelty is not None and writer else trainer.init())
    if resume is not None and writer:
        # the checkpoint must fit (overrides included) before anything in run_dir is rewritten
        state = trainer_lib.load_checkpoint(state, run_dir, echo)
    state = trainer.place(state)                    # every process gets process 0's state
    done = trainer_lib.completed_iterations(state)  # 0: also a run that died before its first
    if resume is not None:                          # checkpoint
        echo(f"resuming {run_dir} at iteration {done}")
    if writer:
        trainer_lib.trim_metrics(run_dir, done, echo)  # left lines that do not count
        write_text_atomic(run_dir / CONFIG, json.dumps(config.sections(), indent=2) + "\n")
    s = config.run
    echo(f"training {s.task}: {s.envs} environments × {s.steps_per_iteration} steps = "
         f"{s.samples_per_iteration} samples per iteration, {s.iterations} iterations"
         f"{parallel.describe(trainer.layout.mesh)} → {run_dir}")
    try:
        return trainer_lib.run(trainer, state, run_dir, echo)
    finally:                      # the curve of what was done, whatever ended the run; its own
        if writer:                # failure must not hide the run's error
            _plot_after_run(run_dir, echo)


def _quiet(*_):
    """The echo of a process that shows nothing (all but process 0 of a multi-process run)."""


def _check_devices(config: TrainConfig, source):
    """A ConfigError naming `source` when the devices `run.devices` asks for are not there, or
    `run.envs` cannot be split evenly over the run's devices."""
    try:
        mesh = parallel.mesh(config.run.devices)
    except config_io.ConfigError as error:
        raise config_io.ConfigError(f"{source}: {error}") from None
    why = parallel.check_split(config.run.envs, mesh, config.run.devices)
    if why:
        raise config_io.ConfigError(f"{source}: {why}")


def _plot_after_run(run_dir, echo):
    """`plot`, its failure said as a warning (a run's result does not depend on its picture)."""
    try:
        plot(run_dir, quiet=True)
    except Exception as error:          # noqa: BLE001 — any failure of the picture
        echo(f"warning: the learning curve was not drawn: {error}")


def _available_memory() -> int | None:
    """The bytes of memory available to the run: the accelerator's free memory, or on the CPU
    Linux's MemAvailable (None where neither is known)."""
    device = jax.devices()[0]
    if device.platform != "cpu":
        stats = device.memory_stats() or {}
        if "bytes_limit" in stats:
            return stats["bytes_limit"] - stats.get("bytes_in_use", 0)
        return None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _check_memory(need: int, source, what: str):
    """A ConfigError naming `what` (the keys that size the run, with their values) when `need`
    bytes, a lower bound of what the run needs, exceed the memory available."""
    available = _available_memory()
    if available is not None and need > available:
        raise config_io.ConfigError(
            f"{source}: {what} needs at least {need / 1e9:,.1f} GB of memory (the training "
            f"state and the samples of one rollout), and {available / 1e9:,.1f} GB is "
            "available")


def overridden(config: TrainConfig, overrides, source) -> TrainConfig:
    """The config of a run (to resume or evaluate it) with `overrides` applied; a ConfigError
    if one changes a key of its `fixed_on_resume`."""
    data = json.loads(json.dumps(config.sections()))    # tuples become lists
    for override in overrides:
        config_io.apply_override(data, override, source)
    changed = build_config(data, str(source))
    for key in config.fixed_on_resume:
        before, after = (_get(c.sections(), key) for c in (config, changed))
        if before != after:
            raise config_io.ConfigError(
                f"{source}: {key} cannot change when a run is resumed (the run has {before!r}, "
                f"the override gives {after!r}): its checkpoint fixes it; start a new run "
                f"instead")
    return changed


def _get(sections, key):
    section, name = key.split(".")
    return sections.get(section, {}).get(name)          # (a run without [novelty]: None)


class Episodes(NamedTuple):
    """Deterministic evaluation episodes of a trained policy (`run_episodes`)."""
    summary: dict          # means over each environment's first episode (see `evaluate`)
    outcomes: dict         # per environment: its first episode's return and length, and each
                           # `episode/` metric where that episode ended
    env: object            # the environment, at the difficulty evaluated
    poses: np.ndarray      # (steps, nq) of environment 0's first episode, one per control step
    task: dict             # environment 0's task values at its reset (to draw its world)


def run_episodes(run_dir, episodes: int = 8, data_dir=None, difficulty=None, echo=print,
                 check_writable_path=None, overrides=(), vary=None) -> Episodes:
    """Run the deterministic policy (the Gaussian's mean) of the run in `run_dir` for one
    episode in each of `episodes` environments, at the run's curriculum difficulty or at
    `difficulty` (the jump tasks' bar height / obstacle width), under the run's config with
    `overrides` ("key=value", as `--set`). `vary(params)`, when given, turns the task
    parameters (one set per environment, all alike) into those to run (a sweep's members)."""
    source = Path(run_dir) / CONFIG
    config = overridden(load_run_config(run_dir), overrides, source)
    config = dataclasses.replace(config, run=dataclasses.replace(config.run, devices=1))
                                               # (evaluation runs on one device, however the
    trainer = _trainer_for(config, source, data_dir)      # run was trained)
    env = trainer.env_for(trainer.curriculum.init())
    state_bytes, sample_bytes = trainer.footprint(episodes, env.episode_steps)
    _check_memory(state_bytes + sample_bytes, source, f"--episodes {episodes}")
    if check_writable_path is not None:
        check_writable(Path(check_writable_path).parent, what="the animation")
    state = trainer_lib.load_checkpoint(trainer.init(), run_dir, echo)
    curriculum = state.curriculum
    if difficulty is not None:
        if not isinstance(curriculum, dict) or "difficulty" not in curriculum:
            raise config_io.ConfigError(f"{source}: this run's task has no difficulty to "
                                        "evaluate at")
        curriculum = {**curriculum, "difficulty": jnp.asarray(
            difficulty, jnp.asarray(curriculum["difficulty"]).dtype)}
    env = trainer.env_for(curriculum)                # at the difficulty evaluated
    params = trainer.env_params_for(curriculum, episodes)
    if vary is not None:
        params = vary(params)
    rollout = trainer.evaluation_rollout(curriculum)
    start_key, rollout_key = jax.random.split(jax.random.PRNGKey(config.run.seed + 1))
    runner = start_runner(env, params, start_key, episodes, params_axis=0)
    p = state.ppo
    _, batch, _, records, metrics, physics = rollout(
        params, runner, p.policy_params, p.value_params, state.norm,
        trainer.sigma(p.samples), rollout_key)
    ended = np.asarray(records.ended)
    first = _first_episode_mask(ended)
    steps = first.sum(0)
    at_end = first * ended                     # the step where each first episode ended
    summary = {"episodes": episodes,
               "return": float(np.mean((np.asarray(batch.reward) * first).sum(0))),
               "episode_length": float(steps.mean()),
               "terminated": float((np.asarray(batch.terminated) * first).any(0).mean()),
               **{k: _mean(np.asarray(v), at_end if k.startswith("episode/") else first)
                  for k, v in metrics.items()}}
    outcomes = {"return": (np.asarray(batch.reward) * first).sum(0),
                "episode_length": steps.astype(float),
                **{k: np.where(at_end.any(0), (np.asarray(v) * at_end).sum(0), np.nan)
                   for k, v in metrics.items() if k.startswith("episode/")}}
    task = jax.tree_util.tree_map(lambda x: x[0], runner.envs.task)
    return Episodes(summary, outcomes, env, np.asarray(physics.q)[:int(steps[0]), 0], task)


def evaluate(run_dir, episodes: int = 8, render_path=None, data_dir=None, echo=print):
    """Run the deterministic policy (the Gaussian's mean) for `episodes` episodes from random
    starts; report the mean return, length and task metrics over each first episode. Returns
    the summary, the environment and the poses of episode 0 (steps, nq)."""
    summary, _, env, poses, task = run_episodes(run_dir, episodes, data_dir, echo=echo,
                                                check_writable_path=render_path)
    broken = sorted(k for k, v in summary.items() if v is not None and not np.isfinite(v))
    echo(json.dumps({k: v if k not in broken else None for k, v in summary.items()}, indent=2))
    if broken:
        raise trainer_lib.TrainingError(
            f"{run_dir}: the evaluation's {', '.join(broken)} came out non-finite (shown as "
            "null above)")
    if render_path is not None:
        from jaxsim import render
        world = env.world_for(task) if hasattr(env, "world_for") else env.world
        render.animation(env.model, poses, render_path, world=world, fps=1.0 / env.control_dt,
                         times=env.control_dt * np.arange(1, len(poses) + 1),
                         markers=env.markers(task) if hasattr(env, "markers") else None)
        echo(f"animation of episode 0 ({len(poses)} steps) → {render_path}")
    return summary, env, poses


def minutes_axis(records):
    """(samples → minutes, minutes → samples) by interpolation of the log, for a second axis;
    past the log's ends, by its mean rate (the axis's margins reach beyond them, and a clamped
    map would put every tick out there on the last sample, one over another)."""
    samples = np.array([r["samples"] for r in records], float)
    minutes = np.array([r["seconds"] for r in records], float) / 60
    span = samples[-1] - samples[0]
    if span > 0:
        slope = (minutes[-1] - minutes[0]) / span
        samples = np.concatenate([[samples[0] - span], samples, [samples[-1] + span]])
        minutes = np.concatenate([[minutes[0] - slope * span], minutes,
                                  [minutes[-1] + slope * span]])
    return (lambda x: np.interp(x, samples, minutes), lambda m: np.interp(m, minutes, samples))


def _mean(values, mask):
    """The mean of `values` where `mask` is 1 (None, JSON's null, where it is nowhere)."""
    count = mask.sum()
    return float((values * mask).sum() / count) if count else None


def _first_episode_mask(ended):
    """(T, N) 1 for the steps of each environment's first episode (up to and including the
    step where it ended), 0 after."""
    before = np.cumsum(ended, axis=0) - ended
    return (before == 0).astype(float)


def plot(run_dir, quiet=False):
    """The learning curve (return and episode length against samples) as a PNG."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise config_io.ConfigError(f"{run_dir}: no such run directory")
    try:
        from jaxsim import render
        plt = render.pyplot()
    except ImportError as error:
        if not quiet:
            raise SystemExit(f"takeoff plot: {error}")
        return None
    records = trainer_lib.read_metrics(run_dir)
    if not records:
        return None
    samples = np.array([r["samples"] for r in records], float)
    panels = [("return", "mean episode return"), ("episode_length", "mean episode length (steps)")]
    if trainer_lib.DIFFICULTY in records[-1]:               # a task with a curriculum (Fig. 3.10)
        panels.append((trainer_lib.DIFFICULTY, "difficulty z (bar height / width, m)"))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.5))
    for ax, (key, label) in zip(axes, panels):
        values = np.array([np.nan if r.get(key) is None else r[key] for r in records], float)
        ax.plot(samples, values, lw=1)
        ax.set_xlabel("samples")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if len(panels) == 3:                                     # and against wall-clock minutes
        minutes = axes[2].secondary_xaxis("top", functions=minutes_axis(records))
        minutes.set_xlabel("minutes")
    render.save_figure(fig, run_dir / CURVE, title=f"{run_dir.name}: learning curve", dpi=110)
    return run_dir / CURVE
