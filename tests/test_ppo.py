"""PPO pieces against independent references: GAE as the explicit sum of discounted TD errors,
TD(λ) targets as recursive λ-returns and Monte-Carlo returns, the clipped surrogate with Gaussian
log-densities written out in NumPy, the σ schedule, running statistics against NumPy over the
concatenated data, and a jitted update that moves the policy the right way."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents import config as config_io
from agents.rl.networks import PolicyNetwork, ValueNetwork, action_distribution, sigma_at
from agents.rl.ppo import (Batch, PPOSettings, RunningNorm, gae, make_ppo, policy_loss,
                        td_lambda_targets)

T, N = 7, 3
GAMMA, LAM = 0.9, 0.8


@pytest.fixture(scope="module")
def trajectory():
    """Hand-made episodes: env 0 never ends; env 1 terminates at t=2 and is truncated at t=5;
    env 2 is truncated at t=1 and terminates at t=4 and at t=6 (the last step). After an episode
    ends, next_value (V of the pre-reset observation) differs from the next step's value."""
    rng = np.random.default_rng(3)
    reward = rng.normal(size=(T, N))
    value = rng.normal(size=(T, N))
    terminated = np.zeros((T, N), bool)
    truncated = np.zeros((T, N), bool)
    terminated[2, 1] = terminated[4, 2] = terminated[6, 2] = True
    truncated[5, 1] = truncated[1, 2] = True
    done = terminated | truncated
    next_value = np.empty((T, N))
    next_value[:-1] = value[1:]
    next_value[-1] = rng.normal(size=N)
    next_value[:-1][done[:-1]] = 5.0 + rng.normal(size=done[:-1].sum())
    return reward, value, next_value, terminated, truncated


def _ours(fn, trajectory, gamma=GAMMA, lam=LAM):
    return np.asarray(fn(*(jnp.asarray(a) for a in trajectory), gamma, lam))


def _reference_gae(reward, value, next_value, terminated, truncated, gamma, lam):
    """A_t = Σ_l (γλ)^l δ_{t+l}, the sum running to the step that ends the episode or the
    rollout (GAE paper, eq. 16), with δ_t by cases."""
    advantage = np.zeros_like(reward)
    for n in range(reward.shape[1]):
        for t in range(reward.shape[0]):
            total, k = 0.0, t
            while True:
                bootstrap = 0.0 if terminated[k, n] else gamma * next_value[k, n]
                total += (gamma * lam) ** (k - t) * (reward[k, n] + bootstrap - value[k, n])
                if terminated[k, n] or truncated[k, n] or k == reward.shape[0] - 1:
                    break
                k += 1
            advantage[t, n] = total
    return advantage


def _lambda_return(reward, next_value, terminated, truncated, gamma, lam, t, n):
    """G_t = r_t + γ[(1 − λ) V(s_{t+1}) + λ G_{t+1}], cut at episode and rollout ends."""
    if terminated[t, n]:
        return reward[t, n]
    if truncated[t, n] or t == reward.shape[0] - 1:
        return reward[t, n] + gamma * next_value[t, n]
    later = _lambda_return(reward, next_value, terminated, truncated, gamma, lam, t + 1, n)
    return reward[t, n] + gamma * ((1 - lam) * next_value[t, n] + lam * later)


def test_gae_matches_the_discounted_sum_of_td_errors(trajectory):
    np.testing.assert_allclose(_ours(gae, trajectory), _reference_gae(*trajectory, GAMMA, LAM),
                               rtol=1e-12, atol=1e-12)


def test_gae_bootstraps_a_truncation_from_next_value_and_not_a_termination(trajectory):
    reward, value, next_value, *_ = trajectory
    advantage = _ours(gae, trajectory)
    assert next_value[5, 1] != value[6, 1]
    assert advantage[5, 1] == pytest.approx(reward[5, 1] + GAMMA * next_value[5, 1] - value[5, 1])
    assert advantage[2, 1] == pytest.approx(reward[2, 1] - value[2, 1])
    assert advantage[4, 2] == pytest.approx(reward[4, 2] - value[4, 2])


def test_td_lambda_targets_are_the_lambda_returns(trajectory):
    reward, value, next_value, terminated, truncated = trajectory
    expected = np.array([[_lambda_return(reward, next_value, terminated, truncated, GAMMA, LAM,
                                         t, n) for n in range(N)] for t in range(T)])
    np.testing.assert_allclose(_ours(td_lambda_targets, trajectory), expected,
                               rtol=1e-12, atol=1e-12)


def test_td_lambda_with_lambda_and_gamma_one_is_the_monte_carlo_return(trajectory):
    reward = trajectory[0]
    targets = _ours(td_lambda_targets, trajectory, gamma=1.0, lam=1.0)
    # env 2's second episode runs t = 2..4 and terminates: the target is the sum of rewards.
    for t in range(2, 5):
        assert targets[t, 2] == pytest.approx(sum(reward[k, 2] for k in range(t, 5)), abs=1e-12)


# ---- The clipped surrogate ---------------------------------------------------------------------

def _gaussian_log_density(action, mean, sigma):
    d = action.shape[-1]
    return (-0.5 * np.sum(((action - mean) / sigma) ** 2, axis=-1)
            - d * math.log(sigma) - 0.5 * d * math.log(2 * math.pi))


def _reference_policy_loss(weights, obs, action, old_log_prob, advantage, sigma, clip):
    ratio = np.exp(_gaussian_log_density(action, obs @ weights, sigma) - old_log_prob)
    surrogate = np.minimum(ratio * advantage, np.clip(ratio, 1 - clip, 1 + clip) * advantage)
    return -surrogate.mean(), ratio


def _linear(weights, obs):
    return obs @ weights


@pytest.fixture(scope="module")
def surrogate_case():
    """A linear policy and old log-probabilities chosen to give these ratios: clipped below
    (0.5 with A < 0), clipped above (1.3 with A > 0), and outside the band but unclipped."""
    rng = np.random.default_rng(7)
    obs = rng.normal(size=(8, 3))
    weights = rng.normal(size=(3, 2))
    action = rng.normal(size=(8, 2))
    sigma, clip = 0.3, 0.2
    ratio = np.array([0.5, 0.7, 0.9, 1.0, 1.1, 1.3, 1.6, 0.85])
    advantage = np.array([-1.0, 2.0, -0.5, 1.0, 1.5, 2.0, -1.0, 0.3])
    old_log_prob = _gaussian_log_density(action, obs @ weights, sigma) - np.log(ratio)
    return weights, obs, action, old_log_prob, advantage, sigma, clip


def test_policy_loss_matches_a_numpy_hand_computation(surrogate_case):
    weights, obs, action, old_log_prob, advantage, sigma, clip = surrogate_case
    loss, aux = policy_loss(_linear, *(jnp.asarray(a) for a in surrogate_case[:5]), sigma, clip)
    expected, ratio = _reference_policy_loss(*surrogate_case)
    np.testing.assert_allclose(ratio, [0.5, 0.7, 0.9, 1.0, 1.1, 1.3, 1.6, 0.85], rtol=1e-12)
    # the min picks the clipped term exactly at samples 0 (low side) and 5 (high side)
    assert expected == pytest.approx(-np.mean([-0.8, 1.4, -0.45, 1.0, 1.65, 2.4, -1.6, 0.255]))
    assert float(loss) == pytest.approx(expected, rel=1e-12)
    assert float(aux["clip_fraction"]) == pytest.approx(4 / 8)
    assert float(aux["approx_kl"]) == pytest.approx(np.mean(ratio - 1 - np.log(ratio)),
                                                    rel=1e-12)
    assert float(aux["entropy"]) == pytest.approx(2 * (0.5 * math.log(2 * math.pi * math.e)
                                                       + math.log(sigma)), rel=1e-12)


def test_policy_loss_gradient_matches_finite_differences(surrogate_case):
    weights, *rest = surrogate_case
    grad = jax.grad(lambda w: policy_loss(_linear, w, *(jnp.asarray(a) for a in rest[:4]),
                                          *rest[4:])[0])(jnp.asarray(weights))
    h, expected = 1e-6, np.zeros_like(weights)
    for index in np.ndindex(weights.shape):
        step = np.zeros_like(weights)
        step[index] = h
        expected[index] = (_reference_policy_loss(weights + step, *rest)[0]
                           - _reference_policy_loss(weights - step, *rest)[0]) / (2 * h)
    np.testing.assert_allclose(np.asarray(grad), expected, rtol=1e-6, atol=1e-8)


def test_clipped_samples_give_no_gradient(surrogate_case):
    weights, obs, action, old_log_prob, advantage, sigma, clip = surrogate_case
    clipped = np.array([0, 5])
    grad = jax.grad(lambda w: policy_loss(
        _linear, w, jnp.asarray(obs[clipped]), jnp.asarray(action[clipped]),
        jnp.asarray(old_log_prob[clipped]), jnp.asarray(advantage[clipped]), sigma, clip)[0])(
        jnp.asarray(weights))
    np.testing.assert_array_equal(np.asarray(grad), 0.0)


# ---- σ schedule, networks -------------------------------------------------------------------

def test_sigma_is_annealed_linearly_then_held():
    samples = jnp.array([0, 5_000_000, 10_000_000, 30_000_000])
    np.testing.assert_allclose(np.asarray(jax.jit(jax.vmap(sigma_at))(samples)),
                               [0.5, 0.3, 0.1, 0.1], rtol=1e-12)
    assert float(sigma_at(500, start=1.0, end=0.0, horizon=1000)) == pytest.approx(0.5)


def test_networks_shapes_and_small_initial_actions():
    obs = jax.random.normal(jax.random.PRNGKey(0), (4, 6, 5))
    policy, value = PolicyNetwork(3, (32, 32)), ValueNetwork((32, 32))
    mean = policy.apply(policy.init(jax.random.PRNGKey(1), obs), obs)
    assert mean.shape == (4, 6, 3) and float(jnp.abs(mean).max()) < 0.05
    assert value.apply(value.init(jax.random.PRNGKey(2), obs), obs).shape == (4, 6)
    assert action_distribution(mean, 0.2).sample(seed=jax.random.PRNGKey(3)).shape == (4, 6, 3)


# ---- Observation normalisation ------------------------------------------------------------------

def test_running_norm_merges_uneven_batches_like_numpy():
    rng = np.random.default_rng(11)
    shapes = [(1, 4), (5, 4), (2, 7, 4), (3, 2, 3, 4)]
    batches = [100.0 + rng.normal(scale=[0.1, 1.0, 3.0, 10.0], size=s) for s in shapes]
    merge = jax.jit(RunningNorm.update)
    norm = RunningNorm.zeros(4)
    for batch in batches:
        norm = merge(norm, jnp.asarray(batch))
    data = np.concatenate([b.reshape(-1, 4) for b in batches])
    assert float(norm.count) == len(data)
    np.testing.assert_allclose(np.asarray(norm.mean), data.mean(0), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(norm.var), data.var(0), rtol=1e-10)
    x = np.array([[100.0, 100.0, 100.0, 100.0], [100.5, 130.0, 95.0, 80.0]])
    expected = np.clip((x - data.mean(0)) / np.sqrt(data.var(0) + 1e-8), -10.0, 10.0)
    assert np.abs(expected).max() == 10.0
    np.testing.assert_allclose(np.asarray(norm.normalize(jnp.asarray(x))), expected, rtol=1e-10)


def test_running_norm_before_any_data_leaves_inputs_unscaled():
    x = jnp.array([0.5, -2.0, 30.0])
    np.testing.assert_allclose(np.asarray(RunningNorm.zeros(3).normalize(x)), [0.5, -2.0, 10.0],
                               rtol=1e-6)


# ---- The update --------------------------------------------------------------------------------

OBS, ACTIONS, STEPS, ENVS = 5, 3, 8, 33
SETTINGS = PPOSettings(hidden=(32, 32), minibatch_size=64, epochs=2, policy_lr=1e-3,
                       value_lr=1e-3)


@pytest.fixture(scope="module")
def ppo():
    ppo = make_ppo(OBS, ACTIONS, SETTINGS)
    init, update = ppo.init, ppo.update
    return init(jax.random.PRNGKey(0)), jax.jit(update)


def _log_prob(params, obs, action):
    mean = PolicyNetwork(ACTIONS, SETTINGS.hidden).apply({"params": params}, obs)
    return action_distribution(mean, SETTINGS.sigma_start).log_prob(action)


@pytest.fixture(scope="module")
def batch(ppo):
    """Actions from the initial policy; every step terminal with reward sign(a_0) + 2 obs_0 and
    a recorded value 2 obs_0, so the advantage is sign(a_0): a positive first action is good."""
    state, _ = ppo
    obs_key, action_key = jax.random.split(jax.random.PRNGKey(1))
    obs = jax.random.normal(obs_key, (STEPS, ENVS, OBS))
    mean = PolicyNetwork(ACTIONS, SETTINGS.hidden).apply({"params": state.policy_params}, obs)
    action = action_distribution(mean, SETTINGS.sigma_start).sample(seed=action_key)
    value = 2.0 * obs[..., 0]
    return Batch(obs=obs, action=action, log_prob=_log_prob(state.policy_params, obs, action),
                 reward=jnp.sign(action[..., 0]) + value, value=value,
                 next_value=jnp.zeros((STEPS, ENVS)),
                 terminated=jnp.ones((STEPS, ENVS), bool),
                 truncated=jnp.zeros((STEPS, ENVS), bool))


def test_update_changes_parameters_and_advances_counters(ppo, batch):
    state, update = ppo
    new, metrics = update(state, batch, jax.random.PRNGKey(2))
    assert int(new.samples) == STEPS * ENVS and int(new.iteration) == 1
    for old_leaf, new_leaf in zip(jax.tree_util.tree_leaves((state.policy_params,
                                                             state.value_params)),
                                  jax.tree_util.tree_leaves((new.policy_params,
                                                             new.value_params))):
        assert not np.allclose(old_leaf, new_leaf)
    assert set(metrics) == {"policy_loss", "value_loss", "approx_kl", "clip_fraction",
                            "entropy", "sigma"}
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert float(metrics["sigma"]) == SETTINGS.sigma_start


def test_repeated_updates_raise_the_log_probability_of_good_actions(ppo, batch):
    state, update = ppo
    before = _log_prob(state.policy_params, batch.obs, batch.action)
    value_losses = []
    for seed in range(15):
        state, metrics = update(state, batch, jax.random.PRNGKey(seed))
        value_losses.append(float(metrics["value_loss"]))
    change = _log_prob(state.policy_params, batch.obs, batch.action) - before
    good = batch.action[..., 0] > 0
    assert float(change[good].mean()) > 0.05 and float(change[~good].mean()) < -0.05
    assert int(state.iteration) == 15 and int(state.samples) == 15 * STEPS * ENVS
    assert value_losses[-1] < 0.5 * value_losses[0]


def test_a_batch_smaller_than_one_minibatch_is_refused(ppo, batch):
    state, update = ppo
    small = jax.tree_util.tree_map(lambda x: x[:2, :3], batch)
    with pytest.raises(ValueError, match=r"6 samples .*\(minibatch_size = 64\)"):
        update(state, small, jax.random.PRNGKey(0))


# ---- Settings -----------------------------------------------------------------------------------

@pytest.mark.parametrize("key, value", [
    ("gamma", -0.1), ("lam", 1.5), ("clip", 0.0), ("policy_lr", -1e-3), ("epochs", 0),
    ("minibatch_size", 0), ("sigma_end", 0.0), ("sigma_horizon", 0.0), ("max_grad_norm", -1.0),
    ("hidden", (32, 0)), ("clip", math.inf), ("value_lr", math.inf), ("sigma_start", math.inf),
    ("sigma_horizon", math.inf), ("max_grad_norm", math.inf)])
def test_settings_errors_name_the_key(key, value):
    with pytest.raises(ValueError, match=f"^{key} must"):
        PPOSettings(**{key: value})


def test_config_loader_reports_file_section_and_key():
    with pytest.raises(config_io.ConfigError, match=r"run\.toml: \[ppo\]: lam must be in "
                                                    r"\[0, 1\]; got 1\.5"):
        config_io.build(PPOSettings, {"lam": 1.5}, "run.toml", "ppo.")
    assert config_io.build(PPOSettings, {"hidden": [64, 64]}, "run.toml").hidden == (64, 64)
