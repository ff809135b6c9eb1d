"""Stage-2 novelty reward of strategy discovery (thesis §3.5.2)."""

import jax.numpy as jnp

from bds.acquisition import euclidean


def novelty_reward(feature, known_features, threshold):
    """r_novelty(f) = clip(min_i ‖f − f_i‖ / d_threshold, 0.01, 1) (thesis eq. 3.12).

    feature (..., m) against known_features (k, m) of the strategies found so far; pure and
    jittable, so it runs inside rollouts (leading batch axes of `feature` broadcast).
    """
    feature = jnp.asarray(feature)
    nearest = jnp.min(euclidean(feature[..., None, :], jnp.asarray(known_features)), axis=-1)
    return jnp.clip(nearest / threshold, 0.01, 1.0)
