"""Proximal Policy Optimisation with GAE(λ) advantages and TD(λ) value targets (thesis §3.4.1).

PPO (Schulman et al. 2017, "Proximal Policy Optimization Algorithms") maximises the clipped
surrogate E[min(ρ A, clip(ρ, 1 − ε, 1 + ε) A)], ρ = π(a|s) / π_old(a|s), over several epochs of
minibatches drawn from one batch of experience. Advantages are GAE(λ) (Schulman et al. 2016,
"High-Dimensional Continuous Control Using Generalized Advantage Estimation"); the value network
regresses the TD(λ) targets A + V, which are the λ-returns. The policy's σ is not learned: it is
annealed with the number of samples seen (`agents.rl.networks.sigma_at`). Policy and value have
their own Adam optimisers and learning rates.

`make_ppo(obs_size, action_size, settings)` gives the networks' apply functions,
`init(key) -> PPOState` and the pure, jittable
`update(state, batch, key) -> (state, metrics)`. `RunningNorm` keeps the running observation
statistics used to normalise the networks' inputs; `Batch.obs` holds the normalised inputs.
"""

import dataclasses
from dataclasses import dataclass
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax

from agents.config import check_positive
from agents.rl.networks import PolicyNetwork, ValueNetwork, action_distribution, sigma_at

_ADVANTAGE_EPS = 1e-8
_VARIANCE_EPS = 1e-8


@dataclass(frozen=True)
class PPOSettings:
    """The `[ppo]` config section; defaults are the thesis's (docs/design.md, "Agents")."""

    gamma: float = 1.0               # episodic, sparse-reward jump tasks
    lam: float = 0.95
    clip: float = 0.02
    policy_lr: float = 2.5e-5
    value_lr: float = 1e-2
    epochs: int = 5                  # passes over each batch
    minibatch_size: int = 256        # samples per gradient step; the remainder is dropped
    sigma_start: float = 0.5
    sigma_end: float = 0.1
    sigma_horizon: float = 1e7       # samples over which σ goes from start to end
    max_grad_norm: float = 1.0       # global-norm gradient clipping; 0 disables it
    hidden: tuple[int, ...] = (1024, 512)

    def __post_init__(self):
        for name in ("gamma", "lam"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1]; got {getattr(self, name)}")
        check_positive(self, ("clip", "policy_lr", "value_lr", "sigma_start", "sigma_end",
                              "sigma_horizon"))
        check_positive(self, ("max_grad_norm",), allow_zero=True)
        for name in ("epochs", "minibatch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1; got {getattr(self, name)}")
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden must list positive layer widths; got {self.hidden}")


def _register(cls):
    names = [f.name for f in dataclasses.fields(cls)]
    return jax.tree_util.register_dataclass(cls, data_fields=names, meta_fields=[])


@_register
@dataclass(frozen=True)
class Batch:
    """One rollout, time-major (T, N, ...): T control steps of N parallel environments.

    `value` is V(s_t); `next_value` is V(s_{t+1}) of the true next observation, taken before
    any automatic reset, so a time-limit truncation can bootstrap from it. `terminated` marks a
    true terminal state (no bootstrap); `truncated` a time limit (bootstrap from next_value).
    """

    obs: jax.Array            # (T, N, obs) normalised network inputs
    action: jax.Array         # (T, N, action)
    log_prob: jax.Array       # (T, N) log π_old(a_t | s_t)
    reward: jax.Array         # (T, N)
    value: jax.Array          # (T, N)
    next_value: jax.Array     # (T, N)
    terminated: jax.Array     # (T, N) bool
    truncated: jax.Array      # (T, N) bool


def gae(reward, value, next_value, terminated, truncated, gamma, lam):
    """GAE(λ) advantages (T, N) by a backward scan over time (Schulman et al. 2016, eq. 16):

        δ_t = r_t + γ (1 − terminated_t) V(s_{t+1}) − V(s_t)
        A_t = δ_t + γ λ (1 − done_t) A_{t+1},   done_t = terminated_t or truncated_t,

    with V(s_{t+1}) = next_value_t, so a truncated step bootstraps and a terminated one does not,
    and the recursion never crosses an episode boundary. The rollout's last step has A_T = 0
    (it bootstraps from its next_value only).
    """
    dtype = reward.dtype
    delta = reward + gamma * (1.0 - terminated.astype(dtype)) * next_value - value
    carry_on = gamma * lam * (1.0 - (terminated | truncated).astype(dtype))

    def backward(next_advantage, step):
        delta_t, carry_on_t = step
        advantage = delta_t + carry_on_t * next_advantage
        return advantage, advantage

    _, advantages = jax.lax.scan(backward, jnp.zeros_like(delta[0]), (delta, carry_on),
                                 reverse=True)
    return advantages


def td_lambda_targets(reward, value, next_value, terminated, truncated, gamma, lam):
    """TD(λ) value targets A_t + V(s_t) (T, N). These are the λ-returns
    G_t = r_t + γ [(1 − λ) V(s_{t+1}) + λ G_{t+1}], cut to G_t = r_t at a termination and to
    r_t + γ V(s_{t+1}) at a truncation or at the end of the rollout."""
    return gae(reward, value, next_value, terminated, truncated, gamma, lam) + value


def policy_loss(policy_apply, params, obs, action, old_log_prob, advantage, sigma, clip):
    """The clipped surrogate loss −E[min(ρ A, clip(ρ, 1 − ε, 1 + ε) A)] of PPO (Schulman et
    al. 2017, eq. 7), ρ = exp(log π(a|s) − log π_old(a|s)), π = N(policy_apply(params, obs), σ²I).

    Returns (loss, aux) with aux the approximate KL E[(ρ − 1) − log ρ], the clip fraction (share
    of samples with |ρ − 1| > ε) and the policy's entropy.
    """
    distribution = action_distribution(policy_apply(params, obs), sigma)
    log_ratio = distribution.log_prob(action) - old_log_prob
    ratio = jnp.exp(log_ratio)
    surrogate = jnp.minimum(ratio * advantage, jnp.clip(ratio, 1.0 - clip, 1.0 + clip) * advantage)
    aux = {"approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
           "clip_fraction": jnp.mean((jnp.abs(ratio - 1.0) > clip).astype(ratio.dtype)),
           "entropy": jnp.mean(distribution.entropy())}
    return -jnp.mean(surrogate), aux


def value_loss(value_apply, params, obs, target):
    """Mean squared error (no ½ factor) of V(obs) to the TD(λ) targets."""
    return jnp.mean((value_apply(params, obs) - target) ** 2)


@_register
@dataclass(frozen=True)
class PPOState:
    """Network parameters, their optimiser states, and the counters of the run."""

    policy_params: dict
    value_params: dict
    policy_opt_state: optax.OptState
    value_opt_state: optax.OptState
    samples: jax.Array        # environment samples seen (drives σ); saturates at the int max
    iteration: jax.Array      # updates done


# The settings a training's program takes as arrays (`hyperparameters`), so several trainings
# that differ in them run as one program (`agents.rl.members`); the rest shape the program.
HYPERPARAMETERS = ("clip", "policy_lr", "value_lr", "sigma_start", "sigma_end", "sigma_horizon")


def hyperparameters(settings: PPOSettings) -> dict:
    """The settings' `HYPERPARAMETERS` ({name: float}; `update` and the trainer's σ take them
    as numbers or as arrays)."""
    return {name: getattr(settings, name) for name in HYPERPARAMETERS}


def _optimiser(max_grad_norm):
    """Adam at learning rate 1 (optionally after global-norm clipping): its step is scaled by
    the learning rate afterwards (`_optimiser_step`), so the rate can be an array; the same
    state and the same arithmetic as Adam at that rate."""
    adam = optax.adam(1.0)
    if max_grad_norm > 0:
        return optax.chain(optax.clip_by_global_norm(max_grad_norm), adam)
    return adam


def _apply_of(module):
    return lambda params, x: module.apply({"params": params}, x)


def _optimiser_step(optimiser, grads, opt_state, params, learning_rate):
    updates, opt_state = optimiser.update(grads, opt_state, params)
    updates = jax.tree_util.tree_map(lambda u: u * jnp.asarray(learning_rate, u.dtype), updates)
    return optax.apply_updates(params, updates), opt_state


def _normalised(advantage):
    return (advantage - advantage.mean()) / (advantage.std() + _ADVANTAGE_EPS)


class PPO(NamedTuple):
    """The networks' apply functions, `init(key, obs_dtype) -> PPOState` and `update`."""

    policy_apply: Callable
    value_apply: Callable
    init: Callable
    update: Callable


def make_ppo(obs_size: int, action_size: int, settings: PPOSettings, spread=None) -> PPO:
    """The policy and value networks, `init` and the pure, jittable `update(state, batch, key,
    hyper=None) -> (state, metrics)` (`hyper`: the `HYPERPARAMETERS`, numbers or arrays;
    default the settings'): GAE advantages and TD(λ) targets of `batch`, then `settings.epochs`
    epochs, each a shuffle and a scan of one policy and one value Adam step per minibatch of
    `settings.minibatch_size` flattened (T·N) samples (the remainder is dropped; advantages are
    normalised per minibatch). Metrics are means over all minibatches. `spread`, when given,
    lays out the shuffled minibatches (n_minibatches, minibatch, …) of an epoch (the trainer's
    on several devices: each minibatch's samples over the devices, `parallel.spread_samples`);
    it does not change what is computed."""
    policy_net = PolicyNetwork(action_size, tuple(settings.hidden))
    value_net = ValueNetwork(tuple(settings.hidden))
    policy_apply, value_apply = _apply_of(policy_net), _apply_of(value_net)
    policy_optimiser = _optimiser(settings.max_grad_norm)
    value_optimiser = _optimiser(settings.max_grad_norm)
    minibatch = settings.minibatch_size

    def init(key, obs_dtype=jnp.float32):
        policy_key, value_key = jax.random.split(key)
        dummy = jnp.zeros((1, obs_size), obs_dtype)
        policy_params = policy_net.init(policy_key, dummy)["params"]
        value_params = value_net.init(value_key, dummy)["params"]
        return PPOState(policy_params, value_params, policy_optimiser.init(policy_params),
                        value_optimiser.init(value_params), jnp.zeros((), jnp.int32),
                        jnp.zeros((), jnp.int32))

    def minibatch_step(sigma, hyper, carry, data):
        policy_params, value_params, policy_opt_state, value_opt_state = carry
        obs, action, old_log_prob, advantage, target = data
        (loss_pi, aux), policy_grads = jax.value_and_grad(policy_loss, argnums=1, has_aux=True)(
            policy_apply, policy_params, obs, action, old_log_prob, _normalised(advantage),
            sigma, hyper["clip"])
        loss_v, value_grads = jax.value_and_grad(value_loss, argnums=1)(
            value_apply, value_params, obs, target)
        policy_params, policy_opt_state = _optimiser_step(
            policy_optimiser, policy_grads, policy_opt_state, policy_params, hyper["policy_lr"])
        value_params, value_opt_state = _optimiser_step(
            value_optimiser, value_grads, value_opt_state, value_params, hyper["value_lr"])
        metrics = {"policy_loss": loss_pi, "value_loss": loss_v, **aux}
        return (policy_params, value_params, policy_opt_state, value_opt_state), metrics

    def update(state: PPOState, batch: Batch, key, hyper=None):
        hyper = hyperparameters(settings) if hyper is None else hyper
        steps, envs = batch.reward.shape
        count = steps * envs
        n_minibatches = count // minibatch
        if n_minibatches == 0:
            raise ValueError(f"a batch of {count} samples ({steps} steps × {envs} envs) is "
                             f"smaller than one minibatch (minibatch_size = {minibatch})")
        target = td_lambda_targets(batch.reward, batch.value, batch.next_value,
                                   batch.terminated, batch.truncated, settings.gamma, settings.lam)
        advantage = target - batch.value
        flat = jax.tree_util.tree_map(lambda x: x.reshape(count, *x.shape[2:]),
                                      (batch.obs, batch.action, batch.log_prob, advantage, target))
        sigma = sigma_at(state.samples, hyper["sigma_start"], hyper["sigma_end"],
                         hyper["sigma_horizon"])

        def epoch(carry, epoch_key):
            order = jax.random.permutation(epoch_key, count)[: n_minibatches * minibatch]
            order = order.reshape(n_minibatches, minibatch)
            shuffled = jax.tree_util.tree_map(lambda x: x[order], flat)
            if spread is not None:
                shuffled = spread(shuffled)
            return jax.lax.scan(lambda c, d: minibatch_step(sigma, hyper, c, d), carry,
                                shuffled)

        carry = (state.policy_params, state.value_params, state.policy_opt_state,
                 state.value_opt_state)
        carry, metrics = jax.lax.scan(epoch, carry, jax.random.split(key, settings.epochs))
        metrics = {name: jnp.mean(value) for name, value in metrics.items()}
        metrics["sigma"] = sigma
        headroom = jnp.iinfo(state.samples.dtype).max - count
        state = PPOState(*carry, samples=jnp.minimum(state.samples, headroom) + count,
                         iteration=state.iteration + 1)
        return state, metrics

    return PPO(policy_apply, value_apply, init, update)


@_register
@dataclass(frozen=True)
class RunningNorm:
    """Running mean and variance of observations (features on the last axis), merged batch by
    batch with Chan et al.'s parallel formula; `m2` is the sum of squared deviations."""

    count: jax.Array          # () float
    mean: jax.Array           # (features,)
    m2: jax.Array             # (features,)

    @classmethod
    def zeros(cls, size, dtype=float):
        return cls(jnp.zeros((), dtype), jnp.zeros(size, dtype), jnp.zeros(size, dtype))

    @property
    def var(self):
        """Population variance; 1 before any data, so the first normalisation is harmless."""
        return jnp.where(self.count > 0, self.m2 / jnp.maximum(self.count, 1.0), 1.0)

    def update(self, x):
        """Merge the samples x (any leading dims, features last): with n = n_a + n_b and
        δ = mean_b − mean_a, mean = mean_a + δ n_b / n, M2 = M2_a + M2_b + δ² n_a n_b / n."""
        x = x.reshape(-1, x.shape[-1])
        n_b = x.shape[0]
        mean_b = x.mean(axis=0)
        m2_b = jnp.sum((x - mean_b) ** 2, axis=0)
        total = self.count + n_b
        delta = mean_b - self.mean
        return RunningNorm(total, self.mean + delta * (n_b / total),
                           self.m2 + m2_b + delta**2 * (self.count * n_b / total))

    def normalize(self, x, clip=10.0):
        """clip((x − mean) / sqrt(var + 1e-8), −clip, clip)."""
        return jnp.clip((x - self.mean) / jnp.sqrt(self.var + _VARIANCE_EPS), -clip, clip)
