"""Curricula over task difficulty, held in the training state (thesis §3.6.1, Table 3.1).

A curriculum's state is a small pytree of traced values (the difficulty z and whatever it keeps
to decide when z rises). It lives in `TrainState`, so it is checkpointed with the networks and a
resumed run continues it bit for bit, and it is advanced by a pure function inside the compiled
iteration, so raising the bar never recompiles. The task reads it through `params`: the task
parameters the rollout sees (bar height, offset penalty, …) are a function of it.

What cannot be traced (the number of simulation substeps per control step, which shapes the
scan) is named by `static_key`: the trainer compiles one iteration per key it meets, so a
schedule with a handful of keys compiles a handful of programs, each once.

The interface (a `Curriculum`):
    init() -> state
    update(state, iteration_reward) -> state            pure, traced
    params(env_params, state) -> env_params             pure, traced
    static_key(state) -> hashable or None               on host values, between iterations
    metrics(state) -> {name: value}                     logged with the iteration
"""

import dataclasses

import jax
import jax.numpy as jnp


class NoCurriculum:
    """The curriculum of a task without one: no state, the parameters as they are."""

    def init(self):
        return {}

    def update(self, state, iteration_reward):
        return state

    def params(self, env_params, state):
        return env_params

    def static_key(self, state):
        return None

    def metrics(self, state):
        return {}


@dataclasses.dataclass(frozen=True)
class RewardAccumulator:
    """The thesis's adaptive schedule (§3.6.1): every iteration adds its reward to an accumulator;
    when the accumulator exceeds `threshold` (R_T), the difficulty z rises by `step` (Δz), up to
    `maximum`, and the accumulator starts again from 0.

    "The average sample reward" of an iteration is, in our code, the mean return of the episodes
    that ended in it (0 when none did): with the sparse jump rewards a per-step mean would be
    ~20× smaller, and with R_T = 30 the bar would rise 1 cm per ~1,000 iterations, far slower
    than the paper's release (~12,000 iterations from 0.5 m to its highest bars).

    State: {"difficulty": z, "accumulated": the accumulator, "raises": how often z rose}.
    """

    start: float
    step: float
    threshold: float
    maximum: float

    def init(self, dtype=jnp.float32):
        return {"difficulty": jnp.asarray(self.start, dtype),
                "accumulated": jnp.zeros((), dtype), "raises": jnp.zeros((), jnp.int32)}

    def update(self, state, iteration_reward):
        accumulated = state["accumulated"] + iteration_reward.astype(state["accumulated"].dtype)
        rise = (accumulated > self.threshold) & (state["difficulty"] < self.maximum)
        difficulty = jnp.where(rise, jnp.minimum(state["difficulty"] + self.step, self.maximum),
                               state["difficulty"])
        return {"difficulty": difficulty,
                "accumulated": jnp.where(accumulated > self.threshold, 0.0, accumulated),
                "raises": state["raises"] + rise.astype(jnp.int32)}

    def metrics(self, state):
        return {"difficulty": state["difficulty"], "accumulated_reward": state["accumulated"]}


def host(state):
    """The curriculum state as Python numbers (for `static_key`)."""
    return jax.tree_util.tree_map(lambda x: x.item(), jax.device_get(state))
