"""Several trainings of one config in one compiled program (PureJaxRL-style): the members'
training states stacked along a leading axis, every iteration's rollout and PPO update
`jax.vmap`ped over it. Members differ by their seed and, optionally, their task parameters (a
sweep's vmappable keys, `agents.sweep`) and PPO's hyperparameters (learning rates, clip, the
σ schedule: `agents.rl.ppo.HYPERPARAMETERS`); everything that shapes the program — networks, batch,
the task's static settings — is shared, and so is the curriculum's static stage (a jump's
control rate): members whose curricula reach different stages cannot go on in one program, and
a `TrainingError` says so.

Member i computes what `takeoff train` computes with its config (tests/test_sweep.py compares
them). `train(...)` runs the members: one metrics log per member directory, a checkpoint of all
of them in the group directory every `checkpoint_every` iterations (a killed group resumes
there, each member's log trimmed to it), and at the end each member directory made a run
directory of its own (`config.json`, `checkpoint.msgpack`) that `takeoff eval` reads.
"""

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.rl import trainer as trainer_lib
from jaxsim import runlog, xla_options
from jaxsim.atomic import write_text_atomic


class MemberTraining:
    """The trainings of `trainer`'s config with `seeds`, under `env_params` (the task parameters
    with a leading axis of members; None: the trainer's for every member) and `hyper` (PPO's
    `HYPERPARAMETERS`, each an array of one value per member; None: the config's)."""

    def __init__(self, trainer: trainer_lib.Trainer, seeds, env_params=None, hyper=None):
        self.trainer, self.seeds = trainer, np.asarray(seeds)
        self.env_params, self.hyper = env_params, hyper
        self._collect, self._learn = {}, None
        axis = None if env_params is None else 0
        self._init = jax.jit(jax.vmap(lambda seed, params: trainer.init(seed=seed,
                                                                        env_params=params),
                                      in_axes=(0, axis)))
        self._axes = (axis, None if hyper is None else 0)

    @property
    def count(self) -> int:
        return len(self.seeds)

    def init(self) -> trainer_lib.TrainState:
        return self._init(jnp.asarray(self.seeds), self.env_params)

    def member(self, state, index: int):
        """Member `index`'s training state (numpy arrays)."""
        return jax.tree_util.tree_map(lambda x: np.asarray(x[index]), state)

    def iteration(self, state):
        """(the next states, each member's metrics, whether each member's is finite)."""
        trainer = self.trainer
        stages = {trainer._static_key(self.member(state.curriculum, i))
                  for i in range(self.count)}
        if len(stages) > 1:
            raise trainer_lib.TrainingError(
                f"the members' curricula have reached different stages ({sorted(stages)}), "
                "which cannot run in one program; run the sweep's members as separate runs "
                "(sweep.vmap = false)")
        [stage] = stages
        if stage not in self._collect:
            rollout = trainer._rollout_of(trainer.env_for(self.member(state.curriculum, 0)))
            params_axis, hyper_axis = self._axes
            self._collect[stage] = jax.jit(
                jax.vmap(lambda params, hyper, s: trainer._collect(rollout, s, params, hyper),
                         in_axes=(params_axis, hyper_axis, 0)),
                compiler_options=xla_options.simulation_options())
            self._learn = self._learn or jax.jit(jax.vmap(
                lambda hyper, s, collected: trainer._learn(s, collected, hyper),
                in_axes=(hyper_axis, 0, 0)))
        collected = self._collect[stage](self.env_params, self.hyper, state)
        return self._learn(self.hyper, state, collected)


def train(members: MemberTraining, configs, member_dirs, group_dir, echo=print):
    """Train every member to `run.iterations` (see the module docstring); `configs` are the
    members' resolved configs (dicts, each member directory's config.json)."""
    settings = members.trainer.run_settings
    group_dir, member_dirs = Path(group_dir), [Path(d) for d in member_dirs]
    group_dir.mkdir(parents=True, exist_ok=True)
    state = members.init()
    if (group_dir / trainer_lib.CHECKPOINT).exists():
        state = trainer_lib.load_checkpoint(state, group_dir, echo)
    done = int(np.asarray(state.ppo.iteration)[0])
    for directory, config in zip(member_dirs, configs):
        directory.mkdir(parents=True, exist_ok=True)
        trainer_lib.trim_metrics(directory, done, echo)
        write_text_atomic(directory / "config.json", json.dumps(config, indent=2) + "\n")
    if done:
        echo(f"resuming {members.count} members at iteration {done}")
    started = time.perf_counter()
    before = _seconds(member_dirs[0], done)
    for _ in range(done, settings.iterations):
        tick = time.perf_counter()
        new_state, metrics, finite = members.iteration(state)
        metrics = jax.device_get(metrics)
        broken = np.flatnonzero(~np.asarray(finite))
        if broken.size:
            raise trainer_lib.TrainingError(
                f"{group_dir}: member(s) {', '.join(map(str, broken))} went non-finite at "
                f"iteration {done + 1}; the checkpoint of iteration "
                f"{done - done % settings.checkpoint_every} is kept")
        done += 1
        now = time.perf_counter()
        for i, directory in enumerate(member_dirs):
            runlog.append(directory / trainer_lib.METRICS, {
                "iteration": done, "samples": int(np.asarray(new_state.ppo.samples)[i]),
                "seconds": before + now - started,
                "samples_per_second": settings.samples_per_iteration * members.count
                / (now - tick),
                **{k: _number(v[i]) for k, v in metrics.items()}})
        state = new_state
        if done % settings.progress_every == 0:
            returns = np.asarray(metrics["return"], float)
            echo(f"iter {done:>5}/{settings.iterations}  {members.count} members  "
                 f"{settings.samples_per_iteration * members.count / (now - tick):9.0f} "
                 f"samples/s  return {np.nanmin(returns):.3f} … {np.nanmax(returns):.3f}")
        if done % settings.checkpoint_every == 0 or done == settings.iterations:
            trainer_lib.save_checkpoint(state, group_dir)
    for i, directory in enumerate(member_dirs):
        trainer_lib.save_checkpoint(members.member(state, i), directory)
    return state


def _seconds(directory, done) -> float:
    records = [r for r in trainer_lib.read_metrics(directory) if r["iteration"] == done]
    return records[-1]["seconds"] if records else 0.0


def _number(value):
    value = float(value)
    return value if np.isfinite(value) else None
