"""The one jitted rollout: N vmapped environments, T control steps, automatic resets.

`make_rollout(env, policy_apply, value_apply, n_steps)` returns a pure function that scans
`n_steps` control steps (each environment's `step` scans its own simulation substeps) for a batch
of environments and returns the trajectory as a `ppo.Batch` (time-major), the raw observations
(for the running normalisation), the finished episodes' returns and lengths, the environments'
metrics and, on request, their physics states. Actions are sampled from the Gaussian policy, or
its mean when `deterministic` (evaluation). An environment whose episode ends is reset in the
same step, after the value of its last observation has been taken for bootstrapping.
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp

from agents.rl.env import Env, EnvState
from agents.rl.networks import action_distribution
from agents.rl.ppo import Batch, RunningNorm
from jaxsim import batch_last


@dataclasses.dataclass(frozen=True)
class Episodes:
    """Per step and environment (T, N): whether an episode ended there, and its return and
    length (0 where none ended)."""

    ended: jax.Array
    returns: jax.Array
    lengths: jax.Array


jax.tree_util.register_dataclass(Episodes, data_fields=["ended", "returns", "lengths"],
                                 meta_fields=[])


@dataclasses.dataclass(frozen=True)
class Runner:
    """What carries over between rollouts: the environments and their running episode returns
    (their lengths are the environments' own step counts)."""

    envs: EnvState             # batched
    episode_return: jax.Array  # (N,)


jax.tree_util.register_dataclass(Runner, data_fields=["envs", "episode_return"], meta_fields=[])


def start_runner(env: Env, params, key, n_envs: int, params_axis=None) -> Runner:
    """`n_envs` environments, freshly reset; `params` shared (`params_axis` None) or one set per
    environment (0). One compiled program (the resets run op by op took most of a short
    evaluation's time), compiled once per environment object, count and layout."""
    envs = _reset_program(env, n_envs, params_axis)(params, key)
    return Runner(envs, jnp.zeros(n_envs, envs.reward.dtype))


@functools.lru_cache(maxsize=32)
def _reset_program(env: Env, n_envs: int, params_axis):
    @jax.jit
    def reset_all(params, key):
        return jax.vmap(env.reset, in_axes=(params_axis, 0))(params, jax.random.split(key, n_envs))
    return reset_all


def _select(done, fresh, stepped):
    """Per environment: the fresh (reset) state where done, else the stepped one."""
    def pick(a, b):
        return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - done.ndim)), a, b)
    return jax.tree_util.tree_map(pick, fresh, stepped)


def make_rollout(env: Env, policy_apply, value_apply, n_steps: int, deterministic=False,
                 keep_physics=False, params_axis=None, chunk=None, per_shard=None):
    """rollout(params, runner, policy_params, value_params, norm, sigma, key) ->
    (runner, batch, raw_obs, episodes, metrics, physics-or-None); see the module docstring.
    `params` is shared by all environments (`params_axis` None) or has one set per environment
    along axis 0 (`params_axis` 0). The environments step with the batch as the innermost axis
    (`jaxsim.batch_last`), where the simulator runs faster, `chunk` environments at a time
    (None: `batch_last`'s measured default) so that a large batch stays in the CPU's cache;
    their resets, once per control step, with `jax.vmap`. `per_shard` (the trainer's when the
    batch is split over devices, `parallel.Layout.per_shard`) makes the step run on each
    device's own environments, chunked there."""
    batched_step = batch_last.vmap(env.step, in_axes=(params_axis, 0, 0), chunk=chunk)
    if per_shard is not None:
        batched_step = per_shard(batched_step, (params_axis, 0, 0))
    batched_reset = jax.vmap(env.reset, in_axes=(params_axis, 0))

    def rollout(params, runner: Runner, policy_params, value_params, norm: RunningNorm, sigma,
                key):
        def control_step(carry: Runner, step_key):
            envs = carry.envs
            obs = norm.normalize(envs.obs)
            distribution = action_distribution(policy_apply(policy_params, obs), sigma)
            action = distribution.mode() if deterministic else distribution.sample(
                seed=step_key)
            stepped = batched_step(params, envs, action)
            done = stepped.terminated | stepped.truncated
            episode_return = carry.episode_return + stepped.reward
            reset_keys, next_keys = jnp.moveaxis(jax.vmap(jax.random.split)(stepped.key), 1, 0)
            fresh = batched_reset(params, reset_keys)
            next_envs = _select(done, fresh, stepped.replace(key=next_keys))
            record = (
                Batch(obs, action, distribution.log_prob(action), stepped.reward,
                      value_apply(value_params, obs),
                      value_apply(value_params, norm.normalize(stepped.obs)),
                      stepped.terminated, stepped.truncated),
                envs.obs,
                Episodes(done, jnp.where(done, episode_return, 0.0),
                         jnp.where(done, stepped.steps, 0)),
                stepped.metrics,
                stepped.physics if keep_physics else None,
            )
            carry = Runner(next_envs, jnp.where(done, 0.0, episode_return))
            return carry, record

        runner, (batch, raw_obs, episodes, metrics, physics) = jax.lax.scan(
            control_step, runner, jax.random.split(key, n_steps))
        return runner, batch, raw_obs, episodes, metrics, physics

    return rollout


def episode_summary(episodes: Episodes):
    """Mean return and length of the episodes that ended (NaN when none did), and their count."""
    count = jnp.sum(episodes.ended)
    denominator = jnp.maximum(count, 1)
    nan = jnp.nan
    return (jnp.where(count > 0, jnp.sum(episodes.returns) / denominator, nan),
            jnp.where(count > 0, jnp.sum(episodes.lengths) / denominator, nan), count)
