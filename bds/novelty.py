"""Stage-2 novelty reward of strategy discovery (thesis §3.5.2)."""

import jax
import jax.numpy as jnp

from bds.acquisition import distance_function


def novelty_reward(feature, known_features, threshold, distance="euclidean"):
    """r_novelty(f) = clip(min_i d(f, f_i) / d_threshold, 0.01, 1) (thesis eq. 3.12).

    feature (..., m) against known_features (k, m) of the policies found so far, with k ≥ 1;
    `distance` is a feature distance of `bds.acquisition` by name ("euclidean", the ‖f − f_i‖
    of eq. 3.12; "rotation", the geodesic angle between rotation vectors, for Stage 2's 3-D root
    orientation at the bar crossing, §3.6.1) or a function d(f (m,), others (k, m)) -> (k,).
    Pure and jittable, so it runs inside rollouts; leading axes of `feature` are batch axes.
    """
    measure = distance_function(distance) if isinstance(distance, str) else distance
    feature, known = jnp.asarray(feature), jnp.asarray(known_features)
    flat = feature.reshape(-1, feature.shape[-1])
    nearest = jax.vmap(lambda f: jnp.min(measure(f, known)))(flat)
    return jnp.clip(nearest.reshape(feature.shape[:-1]) / threshold, 0.01, 1.0)
