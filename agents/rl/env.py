"""The environment interface: pure `reset` and `step` over pytrees
(docs/design.md, "Agents").

An environment is a Python object that holds what is fixed for a whole run (the character, the
world, the clip, reward weights) and exposes pure functions of one environment:

    reset(params, key) -> EnvState
    step(params, state, action) -> EnvState

Two optional methods serve rendering (`takeoff eval --render`): `world_for(task)`, the world of
an episode whose task state is `task` (a bar at its height), and `markers(task)`, world points
(k, 3) to draw over it (a goal).

`params` is the task-parameter pytree (gravity, bar height, …: anything a sweep may vmap over or
differentiate); `default_params()` gives it. Batching is `jax.vmap` over states (and keys), done by
the rollout, which also resets finished environments automatically.

A step ends an episode in one of two ways that learning must keep apart: `terminated` (a true
terminal state, e.g. the character fell: its value is 0, no bootstrapping) or `truncated` (the
time limit: the episode was cut short, so the value of the last observation is bootstrapped).
`truncated` is only set when `terminated` is not.
"""

import dataclasses
from typing import Any, Protocol

import jax
import jax.numpy as jnp

from agents.config import MAX_INT, check_positive


@dataclasses.dataclass(frozen=True)
class EnvState:
    """One environment after a reset or a step.

    physics     the simulated state (a `jaxsim.model.State`, or any pytree for other tasks)
    obs         (observation_size,) the observation the policy sees next
    reward      () the reward of the step that led here (0 after a reset)
    terminated  () bool, truncated () bool: see the module docstring
    steps       () int, control steps since the reset
    key         the environment's own PRNG key (reset randomness)
    task        task-specific pytree (e.g. the clip time at which the episode started)
    metrics     dict of () numbers to average in the logs (reward terms, errors, …)
    """

    physics: Any
    obs: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    steps: jax.Array
    key: jax.Array
    task: Any
    metrics: dict

    def replace(self, **changes) -> "EnvState":
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(
    EnvState, data_fields=[f.name for f in dataclasses.fields(EnvState)], meta_fields=[])


class Env(Protocol):
    observation_size: int
    action_size: int
    episode_steps: int          # the time limit, in control steps

    def default_params(self) -> Any: ...

    def reset(self, params, key) -> EnvState: ...

    def step(self, params, state: EnvState, action) -> EnvState: ...


def end_of_step(state: EnvState, physics, obs, reward, terminated, task, metrics,
                episode_steps: int, time_is_up=False) -> EnvState:
    """The state after a step: counts it, and truncates it unless terminated when the time limit
    of `episode_steps` is reached or the task says its own time is up (`time_is_up`)."""
    steps = state.steps + 1
    terminated = jnp.asarray(terminated, bool)
    truncated = (steps >= episode_steps) | jnp.asarray(time_is_up, bool)
    return EnvState(physics, obs, jnp.asarray(reward, obs.dtype), terminated,
                    truncated & ~terminated, steps, state.key, task, metrics)


def start_of_episode(physics, obs, key, task, metrics) -> EnvState:
    """The state after a reset: no reward yet, not done, step 0."""
    false = jnp.zeros((), bool)
    return EnvState(physics, obs, jnp.zeros((), obs.dtype), false, false,
                    jnp.zeros((), jnp.int32), key, task, metrics)


class TaskTiming:
    """Mixed into a task's settings dataclass, which has the fields `control_hz`, `sim_hz`,
    `episode_seconds` and `action_scale`: the step counts they give."""

    @property
    def substeps(self) -> int:
        """Simulation steps per control step."""
        return int(round(self.sim_hz / self.control_hz))

    @property
    def episode_steps(self) -> int:
        """The time limit, in control steps."""
        return int(round(self.episode_seconds * self.control_hz))


def check_timing(settings: TaskTiming):
    """Validate a task's `control_hz`, `sim_hz`, `episode_seconds` and `action_scale` (finite and
    positive; the simulation rate a whole multiple of the control rate, so each control step
    is a whole number of substeps; an episode at least one control step long); a ValueError
    names the key."""
    check_positive(settings, ("control_hz", "sim_hz", "episode_seconds", "action_scale"))
    ratio = settings.sim_hz / settings.control_hz
    if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
        raise ValueError(f"sim_hz must be a whole multiple of control_hz; got "
                         f"{settings.sim_hz} and {settings.control_hz}")
    if settings.episode_steps < 1:
        raise ValueError(f"episode_seconds must last at least one control step "
                         f"(1/{settings.control_hz} s); got {settings.episode_seconds}")
    if settings.episode_steps * settings.substeps > MAX_INT:
        raise ValueError(f"episode_seconds = {settings.episode_seconds} is "
                         f"{settings.episode_steps:,} control steps of {settings.substeps} "
                         f"substeps; an episode may have at most {MAX_INT:,} simulation steps")
