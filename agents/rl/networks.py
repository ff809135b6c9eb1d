"""The policy and value networks of the PPO learner (thesis §3.4.1).

The policy is a ReLU MLP (1024-512 by default) giving the mean of a Gaussian over actions; its
standard deviation σ is not learned but a scalar annealed linearly with the number of samples
seen (0.5 → 0.1 over 1e7 samples), the same on every action dimension. The value function is a
ReLU MLP of the same shape giving one number per observation.
"""

import distrax
import flax.linen as nn
import jax.numpy as jnp

_MEAN_INIT_SCALE = 0.01   # last policy layer: initial action means near zero


def _relu_trunk(hidden, x):
    for width in hidden:
        x = nn.relu(nn.Dense(width)(x))
    return x


class PolicyNetwork(nn.Module):
    """Observation (..., obs) → mean (..., action_size) of the Gaussian policy."""

    action_size: int
    hidden: tuple[int, ...] = (1024, 512)

    @nn.compact
    def __call__(self, obs):
        x = _relu_trunk(self.hidden, obs)
        return nn.Dense(self.action_size,
                        kernel_init=nn.initializers.orthogonal(_MEAN_INIT_SCALE))(x)


class ValueNetwork(nn.Module):
    """Observation (..., obs) → state value V(s) of shape (...,)."""

    hidden: tuple[int, ...] = (1024, 512)

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(_relu_trunk(self.hidden, obs))[..., 0]


def sigma_at(samples, start=0.5, end=0.1, horizon=1e7):
    """The policy's σ after `samples` environment samples: linear from `start` to `end` over
    `horizon` samples, `end` afterwards. `samples` may be a traced array."""
    progress = jnp.clip(samples / horizon, 0.0, 1.0)
    return start + (end - start) * progress


def action_distribution(mean, sigma):
    """N(mean, σ² I): a diagonal Gaussian with the scalar σ on every action dimension."""
    scale = jnp.broadcast_to(jnp.asarray(sigma, mean.dtype), mean.shape)
    return distrax.MultivariateNormalDiag(mean, scale)
