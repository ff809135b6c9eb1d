"""PPO training as one compiled iteration, and the run directory around it (thesis §3.4.1).

`Trainer(env, env_params, run, ppo)` builds `iteration(state) -> (state, metrics, finite)`: a
rollout of `steps_per_iteration` control steps for `envs` environments, the observation
statistics merged in, then the PPO update — two compiled programs, the rollout with the
simulator's XLA options (`jaxsim.xla_options`; with them, and the environments stepped with the
batch innermost, it runs 2.4× faster) and the rest with XLA's defaults (the update runs
1.2–1.5× slower under the simulator's; docs/benchmarks.md, PPO "Throughput" and "The jump
tasks: training throughput"). `TrainState` holds
everything that evolves (networks, optimisers, observation statistics, environments, PRNG key),
so a checkpoint is one msgpack file and resuming from it continues bit for bit.

A task's curriculum (`agents.rl.curriculum`, the env's `curriculum` attribute) is part of that
state: the iteration gives the environments the task parameters of the current difficulty, and
advances the difficulty by the iteration's reward, inside the compiled programs. The task
parameters go to the environments one set per environment (`env_params` broadcast along the
batch, or given per environment with `params_per_env`), so they may differ within a batch. A
curriculum whose schedule changes something that shapes the program (the control rate) names it
by a static key: the trainer compiles one rollout per key, with the env's `variant(key)`.

The environments may be split over several devices (`run.devices` per process) and processes
(`agents.rl.parallel`): the same two programs, compiled over a mesh of those devices, with the
environment batch sharded along it and the rest replicated; `place` lays out a state made on
the host, `host` gathers one back (a checkpoint is the same whatever the split).

The Python loop in `run` only logs (`metrics.jsonl`, one line per iteration, read back by the
policy of `jaxsim.runlog`), shows progress (saying when it compiles, and leaving compile time out
of the time it estimates), checkpoints atomically with a checksum every `checkpoint_every`
iterations and at the end, keeping the one before (`agents.checkpoint`: a damaged checkpoint is
passed over for it), and on Ctrl-C saves a checkpoint before it stops. The end's checkpoint is
written before the end's record is logged, so a log whose last record says the run stopped (all
its iterations, its time limit, its stop difficulty: what the commands that resume trainings
judge "finished" by) always has that iteration's checkpoint beside it, even after a kill. Each
iteration also reports one flag, computed in the compiled function, that its rewards,
observation statistics, losses and network parameters are all finite; when they are not, the
loop stops with a `TrainingError` naming the iteration and the quantities, and saves nothing,
so the last checkpoint (of finite weights) is kept.
"""

import copy
import functools
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.checkpoint import (CheckpointError, fill, intact, newest_intact, previous_path,
                               read_msgpack, write_msgpack)
from agents.rl import curriculum as curriculum_lib
from agents.rl import parallel
from agents.rl import rollout as rollout_lib
from agents.rl.networks import sigma_at
from agents.rl import ppo as ppo_lib
from agents.rl.ppo import PPOSettings, PPOState, RunningNorm, make_ppo
from jaxsim import runlog, xla_options

CHECKPOINT = "checkpoint.msgpack"
METRICS = "metrics.jsonl"
DIFFICULTY = "curriculum/difficulty"      # the metric a curriculum logs its difficulty as


class TrainingError(ValueError):
    """A run that cannot go on: values that went non-finite, or an unreadable metrics log; the
    message names the run directory or file and the iteration or line."""


@dataclass(frozen=True)
class RunSettings:
    """The `[run]` config section: the size and length of a training run."""

    task: str = ""                    # the task's registered name (agents.tasks.registry)
    envs: int = 256                   # environments stepped in parallel
    steps_per_iteration: int = 16     # control steps per environment per iteration
    iterations: int = 1000
    seed: int = 0
    checkpoint_every: int = 50        # iterations
    progress_every: int = 1           # iterations between progress-line updates
    time_limit_minutes: float = 0.0   # stop (with a checkpoint) after this long; 0: no limit
    stop_difficulty: float = 0.0      # stop once the curriculum reaches it (z_freeze); 0: never
    chunk: int = 0                    # environments simulated at once; 0: the measured default
    devices: int = 1                  # devices (per process) the environments are split over;
                                      # 0: all local ones (on the CPU one per core)

    # What the computation (and the checkpoint) of a run is made of; the rest says how long
    # the loop runs and how often it reports.
    SHAPING = ("task", "envs", "steps_per_iteration", "seed")

    def __post_init__(self):
        for name in ("envs", "steps_per_iteration", "iterations", "checkpoint_every",
                     "progress_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1; got {getattr(self, name)}")
        for name in ("time_limit_minutes", "stop_difficulty", "chunk", "devices"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be ≥ 0; got {getattr(self, name)}")

    @property
    def samples_per_iteration(self) -> int:
        return self.envs * self.steps_per_iteration


@dataclass(frozen=True)
class TrainState:
    ppo: PPOState
    norm: RunningNorm
    runner: rollout_lib.Runner
    key: jax.Array
    curriculum: Any = None    # the task curriculum's state (`agents.rl.curriculum`)


jax.tree_util.register_dataclass(
    TrainState, data_fields=["ppo", "norm", "runner", "key", "curriculum"], meta_fields=[])


class Trainer:
    """One training setup: the networks and PPO (`ppo`), the rollout, `init` and the compiled
    `iteration` (its rollout compiled once per static key of the curriculum)."""

    def __init__(self, env, env_params, run: RunSettings, ppo: PPOSettings,
                 params_per_env: bool = False):
        self.env, self.env_params, self.run_settings, self.ppo_settings = env, env_params, run, ppo
        self.params_per_env = params_per_env
        self.curriculum = getattr(env, "curriculum", None) or curriculum_lib.NoCurriculum()
        # The devices the environments are split over (`agents.rl.parallel`): the programs
        # are the one-device programs, with the batch laid out over the mesh.
        self.layout = layout = parallel.Layout(parallel.mesh(run.devices))
        why = parallel.check_split(run.envs, layout.mesh, run.devices)
        if why:
            raise ValueError(why)
        # The update runs over the same devices across processes, but in one process on its
        # first device alone: there its matrix products already use every core, and split
        # over two host devices it ran 2.4× slower, while the rollout ran 1.8× faster
        # (docs/benchmarks.md, "Both cores"); the samples are gathered to it (a copy).
        one_process = jax.process_count() == 1
        self.update_layout = learn = (parallel.Layout(parallel.first_device(layout.mesh))
                                      if one_process else layout)
        self.ppo = make_ppo(env.observation_size, env.action_size, ppo,
                            spread=learn.spread_samples if learn.size > 1 else None)
        self.policy_apply, self.value_apply = self.ppo.policy_apply, self.ppo.value_apply
        self.rollout = self._rollout_of(env)
        self._compiled = {}                                  # rollouts, by static key
        self._evaluations = {}                   # deterministic episode rollouts, by static key
        self._variants = {}                      # the environment's variants, by static key
        self.state_sharding, self._collected_sharding = _shardings(layout)
        self._params_sharding = layout.envs if params_per_env else layout.replicated
        learn_state, learn_collected = _shardings(learn)
        self._learn_inputs = (learn_state, learn_collected)
        self._learn_compiled = jax.jit(
            self._learn, in_shardings=self._learn_inputs,
            out_shardings=(learn_state, learn.replicated, learn.replicated))

    def _rollout_of(self, env):
        return rollout_lib.make_rollout(env, self.policy_apply, self.value_apply,
                                        self.run_settings.steps_per_iteration, params_axis=0,
                                        chunk=self.run_settings.chunk or None,
                                        per_shard=(self.layout.per_shard
                                                   if self.layout.size > 1 else None))

    def with_run_settings(self, run: RunSettings) -> "Trainer":
        """The same compiled trainer with other loop settings (iterations, checkpointing);
        the settings that shape the computation must be equal."""
        if any(getattr(run, k) != getattr(self.run_settings, k)
               for k in (*run.SHAPING, "devices")):
            raise ValueError("with_run_settings cannot change " + ", ".join(run.SHAPING)
                             + " or devices")
        twin = copy.copy(self)
        twin.run_settings = run
        return twin

    def sigma(self, samples, hyper=None):
        """The policy's σ after `samples` samples, by the settings' schedule (or `hyper`'s,
        `ppo.hyperparameters`)."""
        h = ppo_lib.hyperparameters(self.ppo_settings) if hyper is None else hyper
        return sigma_at(samples, h["sigma_start"], h["sigma_end"], h["sigma_horizon"])

    def env_params_for(self, curriculum_state, envs: int | None = None, base=None):
        """The task parameters of each environment (a leading axis of `envs`, default the run's)
        under the curriculum's state, from the trainer's (or `base`, one training's of
        several in one program: `agents.rl.members`)."""
        envs = self.run_settings.envs if envs is None else envs
        params = self.curriculum.params(self.env_params if base is None else base,
                                        curriculum_state)
        if self.params_per_env:
            return params
        return jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (envs, *jnp.shape(x))),
                                      params)

    def _static_key(self, curriculum_state):
        return self.curriculum.static_key(curriculum_lib.host(curriculum_state))

    def env_for(self, curriculum_state):
        """The environment the curriculum's state is trained in (its static variant, made once
        per key, so what is compiled for it is found again)."""
        key = self._static_key(curriculum_state)
        if key is None:
            return self.env
        if key not in self._variants:
            self._variants[key] = self.env.variant(key)
        return self._variants[key]

    def init(self, curriculum=None, seed=None, env_params=None) -> TrainState:
        """A fresh state from the run's seed (or `seed`, which may be traced); its environments
        start under the curriculum's state `curriculum` (default: the curriculum's start) and
        the trainer's task parameters (or `env_params`)."""
        key = jax.random.PRNGKey(self.run_settings.seed if seed is None else seed)
        ppo_key, env_key, key = jax.random.split(key, 3)
        curriculum = self.curriculum.init() if curriculum is None else curriculum
        runner = rollout_lib.start_runner(self.env,
                                          self.env_params_for(curriculum, base=env_params),
                                          env_key, self.run_settings.envs, params_axis=0)
        norm = RunningNorm.zeros(self.env.observation_size, runner.envs.obs.dtype)
        return TrainState(self.ppo.init(ppo_key, runner.envs.obs.dtype), norm, runner, key,
                          curriculum)

    def evaluation_rollout(self, curriculum_state):
        """The deterministic rollout of whole episodes (`episode_steps` control steps, the
        physics kept) under the curriculum's state, for evaluations: jitted once per static
        key of the curriculum and shared by every copy of this trainer (`with_run_settings`),
        so evaluations of one config in one process compile once per number of
        environments."""
        key = self._static_key(curriculum_state)
        if key not in self._evaluations:
            env = self.env_for(curriculum_state)
            self._evaluations[key] = jax.jit(
                rollout_lib.make_rollout(env, self.policy_apply, self.value_apply,
                                         env.episode_steps, deterministic=True,
                                         keep_physics=True, params_axis=0),
                compiler_options=xla_options.simulation_options())
        return self._evaluations[key]

    def compiles_next(self, state: TrainState) -> str:
        """What the next `iteration(state)` compiles first ("" when nothing): the first
        iteration its rollout and the update, the first at each new static key of the
        curriculum its rollout."""
        key = self._static_key(state.curriculum)
        if key in self._compiled:
            return ""
        return ("the rollout for the curriculum's next stage ({key})" if self._compiled else
                "the rollout and the PPO update").format(key=key)

    def footprint(self, envs: int | None = None, steps: int | None = None) -> tuple[int, int]:
        """(bytes of the training state, bytes of the samples of a rollout of `envs` × `steps`,
        by default one iteration's), from shapes alone (nothing is allocated): the size of a
        checkpoint, and with it a lower bound on the memory the run needs."""
        state = jax.eval_shape(self.init)
        state_bytes = sum(leaf.size * leaf.dtype.itemsize
                          for leaf in jax.tree_util.tree_leaves(state))
        dtype = state.runner.envs.obs.dtype
        # observations raw and normalised, actions and their means, log-probability, value,
        # reward, return, advantage and the two episode flags
        per_sample = 2 * self.env.observation_size + 2 * self.env.action_size + 7
        samples = ((envs or self.run_settings.envs)
                   * (steps or self.run_settings.steps_per_iteration))
        return state_bytes, samples * per_sample * dtype.itemsize

    def iteration(self, state: TrainState):
        """One iteration: (the next state, its metrics, whether what it computed is finite).

        Two compiled programs, each with the XLA options that suit it: the rollout with the
        simulator's (`xla_options.simulation_options`; 2.4× faster there), the PPO update and
        the bookkeeping with XLA's defaults, under which the update's elementwise optimiser
        loops run faster (docs/benchmarks.md, "The jump tasks: training throughput"). The
        rollout is compiled once per static key of the curriculum."""
        return self.learn(state, self.collect(state))

    def collect(self, state: TrainState):
        """The rollout of an iteration (the first program, `rollout_program`), on the run's
        devices."""
        key = self._static_key(state.curriculum)
        compiled = self._compiled.get(key) or self.rollout_program(state.curriculum)
        if self.update_layout is not self.layout:    # (a copy only where the layouts differ)
            state = parallel.lay_out(state, self.state_sharding)
        collected = compiled(state, self.env_params)
        self._compiled[key] = compiled       # known compiled once a call of it has returned
        return collected

    def rollout_program(self, curriculum_state):
        """The jitted rollout of an iteration under the curriculum's state, `(state,
        env_params) -> collected`, compiled on its first call (by `collect`, once per static
        key of the curriculum). The task parameters are an argument of the program, not
        constants in it, so trainings that differ only in them (the evaluations of a strategy
        search, each from its own take-off state x) compile the same program, which a
        persistent compilation cache then finds."""
        rollout = self._rollout_of(self.env_for(curriculum_state))
        return jax.jit(functools.partial(self._collect, rollout),
                       compiler_options=xla_options.simulation_options(),
                       in_shardings=(self.state_sharding, self._params_sharding),
                       out_shardings=self._collected_sharding)

    def learn(self, state: TrainState, collected):
        """The rest of an iteration from its rollout (the second program), on the update's
        devices: (the next state, its metrics, whether what it computed is finite)."""
        if self.update_layout is not self.layout:
            state, collected = parallel.lay_out((state, collected), self._learn_inputs)
        return self._learn_compiled(state, collected)

    def place(self, state: TrainState) -> TrainState:
        """A state made or read on the host (`init`, `load_checkpoint`) laid out over the
        run's devices; in a multi-process run every process must call it, and all get
        process 0's state."""
        return self.layout.place(state, self.state_sharding)

    def host(self, state: TrainState) -> TrainState:
        """The state as numpy arrays, gathered from all devices and processes (what a
        checkpoint holds; in a multi-process run every process must call it)."""
        return self.layout.host(state)

    def _collect(self, rollout, state: TrainState, env_params=None, hyper=None):
        """The rollout of an iteration, from the state's key (under the trainer's task
        parameters and PPO hyperparameters, or `env_params` and `hyper`)."""
        key, rollout_key, update_key = jax.random.split(state.key, 3)
        p = state.ppo
        runner, batch, raw_obs, episodes, env_metrics, _ = rollout(
            self.env_params_for(state.curriculum, base=env_params), state.runner, p.policy_params,
            p.value_params, state.norm, self.sigma(p.samples, hyper), rollout_key)
        return runner, batch, raw_obs, episodes, env_metrics, key, update_key

    def _learn(self, state: TrainState, collected, hyper=None):
        """The rest of an iteration from its rollout: PPO's update (under `hyper`, default the
        settings'), the observation statistics, the curriculum and the metrics."""
        runner, batch, raw_obs, episodes, env_metrics, key, update_key = collected
        norm = state.norm.update(raw_obs)
        ppo_state, metrics = self.ppo.update(state.ppo, batch, update_key, hyper)
        mean_return, mean_length, finished = rollout_lib.episode_summary(episodes)
        curriculum = self.curriculum.update(state.curriculum,
                                            jnp.where(finished > 0, mean_return, 0.0))
        metrics = {**metrics, "return": mean_return, "episode_length": mean_length,
                   "episodes": finished, "reward": jnp.mean(batch.reward),
                   **env_means(env_metrics, episodes.ended),
                   **{f"curriculum/{k}": v
                      for k, v in self.curriculum.metrics(curriculum).items()}}
        state = TrainState(ppo_state, norm, runner, key, curriculum)
        return state, metrics, _all_finite(_watched(state, metrics))


def _shardings(layout):
    """(the training state's, the rollout's outputs') shardings over a layout's devices, as
    pytree prefixes: the environments batched on axis 0, their samples on axis 1."""
    replicated, envs, steps = layout.replicated, layout.envs, layout.steps
    return (TrainState(replicated, replicated, envs, replicated, replicated),
            (envs, steps, steps, steps, steps, replicated, replicated))


def env_means(env_metrics, ended) -> dict:
    """The environments' metrics (T, N) as `env/<name>` means: over all steps, or for a metric
    named `episode/<name>` (a value that means something where an episode ends) over the steps
    where an episode ended (NaN when none did)."""
    count = jnp.sum(ended)
    means = {}
    for name, value in env_metrics.items():
        if name.startswith("episode/"):
            total = jnp.sum(jnp.where(ended, value, 0.0))
            means[f"env/{name}"] = jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)
        else:
            means[f"env/{name}"] = jnp.mean(value)
    return means


def _watched(state: TrainState, metrics) -> dict:
    """What must stay finite for a run to go on, by name, in the order the values arise."""
    return {"rewards": metrics["reward"], "observation statistics": state.norm,
            "policy loss": metrics["policy_loss"], "value loss": metrics["value_loss"],
            "policy parameters": state.ppo.policy_params,
            "value parameters": state.ppo.value_params}


def _all_finite(tree):
    """One boolean: every number in the pytree is finite."""
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(leaf))
                              for leaf in jax.tree_util.tree_leaves(tree)]))


# ---- Checkpoints -------------------------------------------------------------------------------

def save_checkpoint(state: TrainState, run_dir):
    """The state's leaves (arrays, in pytree order), written atomically with their checksum;
    the checkpoint it replaces is kept as checkpoint.previous.msgpack."""
    leaves = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(jax.device_get(state))]
    path = Path(run_dir) / CHECKPOINT
    try:
        write_msgpack(path, leaves)
    except OSError as error:
        kept = next((f" ({f} is kept)" for f in (path, previous_path(path)) if intact(f)), "")
        raise CheckpointError(f"{path}: could not be written ({error.strerror or error})"
                              f"{kept}") from None


def has_checkpoint(run_dir) -> bool:
    """Whether `run_dir` holds a checkpoint to resume from: the newest, or the one before it
    (which `load_checkpoint` falls back to)."""
    path = Path(run_dir) / CHECKPOINT
    return path.exists() or previous_path(path).exists()


def load_checkpoint(template: TrainState, run_dir, echo=print) -> TrainState:
    """The newest intact checkpoint read into the structure of `template` (a fresh
    `Trainer.init()` of the same config): a damaged checkpoint is passed over for the one before
    it, saying so through `echo`; with none intact, or leaves that do not match in number,
    shape or dtype, a `CheckpointError` naming the file."""
    path = Path(run_dir) / CHECKPOINT

    def read(file):
        stored = read_msgpack(file, "the run has no checkpoint to resume from")
        return fill(template, stored, file, "this run's config")

    state, note = newest_intact(path, read)
    if note:
        echo(f"warning: {note}")
    return state


def completed_iterations(state: TrainState) -> int:
    return int(state.ppo.iteration)


# ---- The loop --------------------------------------------------------------------------------

def _line(record, total, seconds_per_iteration):
    """The progress line of an iteration; the time left from the mean time of the iterations
    that did not compile (None: none yet)."""
    left = ("—" if seconds_per_iteration is None else
            f"{seconds_per_iteration * (total - record['iteration']) / 60:5.1f} min")
    ret = record["return"]
    task = ""                                       # what a task with a curriculum shows
    if record.get(DIFFICULTY) is not None:
        task += f"  z {record[DIFFICULTY]:.2f}"
    if record.get("env/episode/success") is not None:
        task += f"  success {100 * record['env/episode/success']:5.1f}%"
    return (f"iter {record['iteration']:>5}/{total}  {record['samples_per_second']:>8.0f} "
            f"samples/s  return {'—' if ret is None else f'{ret:8.3f}'}  "
            f"len {record['episode_length'] or 0:6.1f}{task}  σ {record['sigma']:.3f}  "
            f"left {left}")


def _json_value(value):
    """A metric as a JSON number; NaN (the mean return and length of an iteration in which no
    episode ended) becomes null."""
    value = float(value)
    return None if not np.isfinite(value) else value


def run(trainer: Trainer, state: TrainState, run_dir, echo=print) -> TrainState:
    """Train until `iterations` are done (or the time limit passes, or the curriculum reaches
    `stop_difficulty`), logging, showing progress and checkpointing in run_dir; a Ctrl-C or a
    SIGTERM checkpoints the last logged iteration and raises KeyboardInterrupt (`parallel.Stop`).
    In a multi-process run every process runs this loop and only process 0 logs, shows progress
    and writes checkpoints; the processes agree, between iterations, on a Ctrl-C, a SIGTERM or
    the time limit, so they stop together."""
    run_dir = Path(run_dir)
    settings = trainer.run_settings
    writer = parallel.is_writer()
    if not writer:
        echo = _quiet
    first = completed_iterations(state)
    saved = first                       # the iteration of the checkpoint in run_dir (0: none)
    logged = ([r for r in read_metrics(run_dir) if r["iteration"] == first]
              if first and writer else [])
    before = logged[-1]["seconds"] if logged else 0.0   # a resumed run's clock goes on
    resumed_at = last_time = time.perf_counter()
    started = resumed_at - before
    timed_seconds, timed_iterations = 0.0, 0    # iterations that did not compile, for the ETA
    stop = parallel.Stop().listen()
    try:
        for _ in range(first, settings.iterations):
            # `state` moves on only once its iteration is logged, so a Ctrl-C checkpoints
            # the last state whose line is in the log.
            compiling = trainer.compiles_next(state)
            if compiling:
                echo(f"compiling {compiling}…")
            new_state, metrics, finite = trainer.iteration(state)
            metrics = jax.device_get(metrics)
            if not finite:
                raise _non_finite(new_state, metrics, run_dir, saved)
            now = time.perf_counter()
            if compiling:
                echo(f"compiled, and ran the iteration, in {now - last_time:.1f} s")
            else:
                timed_seconds += now - last_time
                timed_iterations += 1
            record = {"iteration": completed_iterations(new_state),
                      "samples": int(new_state.ppo.samples),
                      "samples_per_second": settings.samples_per_iteration / (now - last_time),
                      "seconds": now - started,
                      **{k: _json_value(v) for k, v in metrics.items()}}
            last_time = now
            interrupted, time_up = stop.agreed(  # (in one process: no one to ask)
                record["iteration"], settings.time_limit_minutes
                and now - resumed_at > 60 * settings.time_limit_minutes)
            stopping = (record["iteration"] >= settings.iterations or time_up
                        or reached(record, settings.stop_difficulty))
            # The last iteration's checkpoint goes before its record: a log that says the run
            # stopped has that state beside it, even after a kill between the two.
            if stopping:
                _save(trainer, new_state, run_dir, writer)
                saved = record["iteration"]
            if writer:
                runlog.append(run_dir / METRICS, record)
            state = new_state
            if record["iteration"] % settings.progress_every == 0:
                echo(_line(record, settings.iterations,
                           timed_seconds / timed_iterations if timed_iterations else None))
            if record["iteration"] % settings.checkpoint_every == 0 and not stopping:
                _save(trainer, state, run_dir, writer)
                saved = record["iteration"]
            if interrupted:
                raise KeyboardInterrupt
            if time_up:
                echo(f"time limit of {settings.time_limit_minutes:g} min reached")
                break
            if reached(record, settings.stop_difficulty):
                echo(f"difficulty {record[DIFFICULTY]:g} reached at "
                     f"{record['seconds'] / 60:.1f} min")
                break
        if stop.noted_alone():          # a SIGTERM that came with the last iteration's end
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        if completed_iterations(state) != saved:
            _save(trainer, state, run_dir, writer)
        echo(f"\ninterrupted: checkpoint at iteration {completed_iterations(state)} in {run_dir}")
        raise
    finally:
        stop.close()
    return state


def _quiet(*_):
    """The echo of a process that shows nothing (all but process 0 of a multi-process run)."""


def _save(trainer: Trainer, state: TrainState, run_dir, writer: bool):
    """The state gathered to the host (by every process) and written (by process 0)."""
    on_host = trainer.host(state)
    if writer:
        save_checkpoint(on_host, run_dir)


def reached(record, stop_difficulty) -> bool:
    """Whether an iteration's metrics `record` has the curriculum at `stop_difficulty` (0:
    never); to within 1e-5, for a float32 difficulty raised by repeated steps."""
    return bool(stop_difficulty) and record.get(DIFFICULTY, -np.inf) >= stop_difficulty - 1e-5


def _non_finite(state: TrainState, metrics, run_dir, saved) -> TrainingError:
    """The error of an iteration that produced non-finite values, naming which."""
    names = [name for name, tree in _watched(state, metrics).items() if not _all_finite(tree)]
    kept = (f"the checkpoint of iteration {saved} in {run_dir} is kept" if saved else
            "no checkpoint was written")
    return TrainingError(f"{run_dir}: iteration {completed_iterations(state)} produced "
                         f"non-finite {', '.join(names)}; the run stopped without saving it, "
                         f"and {kept}")


def read_metrics(run_dir) -> list[dict]:
    """The log's records, read by the one policy of `jaxsim.runlog` (a torn last line is not a
    record; a bad line before it is a `runlog.LogError` naming the file and line); each must
    carry its iteration number."""
    log = runlog.read(Path(run_dir) / METRICS)
    _check_iterations(log)
    return log.records


def last_record(run_dir) -> dict:
    """The log's last record, the one a resume judges the run by ({} when it has none)."""
    records = read_metrics(run_dir)
    return records[-1] if records else {}


def _check_iterations(log: runlog.Log):
    """A LogError naming the record unless every record has the whole numbers `iteration` and
    `samples` and the number `seconds`, none below 0 (what resuming and plotting read)."""
    for record in log.records:
        for key, kinds in (("iteration", int), ("samples", int), ("seconds", (int, float))):
            value = record.get(key)
            if not isinstance(value, kinds) or isinstance(value, bool) or value < 0:
                raise runlog.LogError(f"{log.path}: the record {json.dumps(record)[:80]} has "
                                      f"no {key} (a number ≥ 0)")


def trim_metrics(run_dir, iterations: int, echo=print):
    """Make the log hold iterations 1..`iterations` only (a killed run wrote lines past its
    last checkpoint), so a resumed run's log has each iteration once; 0 empties it. A torn last
    line is set aside in `metrics.jsonl.torn`, and iterations the checkpoint has done but the
    log has no record of (a log cut short or deleted) are named: both said through `echo`."""
    if iterations == 0:                # nothing counts: whatever the log held is not this run's
        runlog.repair(runlog.Log(Path(run_dir) / METRICS), [])
        return
    log = runlog.read(Path(run_dir) / METRICS)
    _check_iterations(log)
    kept = [r for r in log.records if r["iteration"] <= iterations]
    note = runlog.repair(log, kept)
    if note:
        echo(f"warning: {note}")
    missing = sorted(set(range(1, iterations + 1)) - {r["iteration"] for r in kept})
    if missing:
        echo(f"warning: {log.path} has no record of iteration{'s' if len(missing) > 1 else ''} "
             f"{_ranges(missing)} (the log was cut short or deleted); the run goes on from its "
             f"checkpoint at iteration {iterations}, and those records stay missing"
             + ("; its clock starts again at 0" if iterations in missing else ""))


def _ranges(numbers) -> str:
    """Sorted whole numbers as "1–3, 7"."""
    spans, start = [], numbers[0]
    for previous, number in zip(numbers, numbers[1:] + [None]):
        if number != previous + 1:
            spans.append(f"{start}" if start == previous else f"{start}–{previous}")
            start = number
    return ", ".join(spans)
