"""Acquisition functions of Bayesian Diversity Search (thesis §3.5.1), to be maximised.

Diversity (thesis eq. 3.7): the expected distance from the feature f(x) to the nearest feature seen
so far, E_f~posterior(x)[min_i d(f, f_i)], estimated by Monte Carlo with reparameterised samples
f = mean(x) + std(x) ⊙ ε, where the base samples ε are drawn once per decision, so the surface is a
deterministic function of x for the optimiser. `diversity_closed_form_1d` is the exact value for a
scalar feature and Euclidean distance, used to test the estimate.

Exploration (thesis eqs. 3.9–3.10): the posterior standard deviation, summed over outputs in their
standardised units.

Distances between features (f of shape (m,), others of shape (n, m) → (n,)):
    euclidean          ‖f − f_i‖
    angle              every component an angle in radians; differences wrapped to (−π, π]
    rotation           f a rotation vector (m = 3); the geodesic angle of R(f)ᵀ R(f_i)
"""

import jax
import jax.numpy as jnp
from jax.scipy.stats import norm

from bds.gp import Posterior, predict
from jaxsim import rotations


def euclidean(f, others):
    diff = others - f
    return jnp.sqrt(jnp.sum(diff * diff, axis=-1) + 1e-30)


def wrapped_angle(f, others):
    diff = jnp.angle(jnp.exp(1j * (others - f)))
    return jnp.sqrt(jnp.sum(diff * diff, axis=-1) + 1e-30)


def rotation_geodesic(f, others):
    """Angle in [0, π] of the relative rotation between rotation vectors f and each of others."""
    r = rotations.rotvec_to_matrix(f)
    r_others = rotations.rotvec_to_matrix(others)
    cos = 0.5 * (jnp.einsum("ij,nij->n", r, r_others) - 1.0)
    # arccos has an infinite slope at ±1: clip a hair inside so gradients stay finite.
    return jnp.arccos(jnp.clip(cos, -1.0 + 1e-7, 1.0 - 1e-7))


DISTANCES = {"euclidean": euclidean, "angle": wrapped_angle, "rotation": rotation_geodesic}


def distance_function(name):
    try:
        return DISTANCES[name]
    except KeyError:
        raise ValueError(f"unknown feature distance {name!r}; choose one of "
                         f"{', '.join(DISTANCES)}") from None


def diversity(posterior: Posterior, x, observed, observed_mask, base_samples, distance=euclidean):
    """Monte-Carlo E[min_i d(f(x), f_i)] (thesis eq. 3.7) at points x (n*, d).

    observed (k, m) are the features seen so far (rows with observed_mask False are ignored);
    base_samples (S, m) are standard normal draws shared by every x. Returns (n*,).
    """
    mean, variance = predict(posterior, x)
    std = jnp.sqrt(variance)

    def at_point(mean, std):
        samples = mean + std * base_samples                                   # (S, m)
        gaps = jax.vmap(lambda f: distance(f, observed))(samples)             # (S, k)
        return jnp.mean(jnp.min(jnp.where(observed_mask, gaps, jnp.inf), axis=1))
    return jax.vmap(at_point)(mean, std)


def exploration(posterior: Posterior, x):
    """Posterior standard deviation at x (n*, d) (thesis eq. 3.10), over outputs in standardised
    units: sqrt(Σ_m var_m / scale_m²). Returns (n*,)."""
    _, variance = predict(posterior, x)
    return jnp.sqrt(jnp.sum(variance / posterior.scale ** 2, axis=-1))


def diversity_closed_form_1d(mean, std, observed):
    """Exact E[min_i |f − f_i|] for f ~ N(mean, std²) and scalar observed features (k,).

    The nearest observed value is piecewise constant in f, changing at midpoints between sorted
    neighbours; on each piece [a, b] with nearest value c the integral of |f − c| against the
    normal density has a closed form (split at c), summed over pieces.
    """
    values = jnp.sort(jnp.asarray(observed))
    midpoints = 0.5 * (values[1:] + values[:-1])
    lows = jnp.concatenate([jnp.array([-jnp.inf]), midpoints])
    highs = jnp.concatenate([midpoints, jnp.array([jnp.inf])])

    def partial_moment(low, high, c):
        """∫_low^high (f − c) N(f; mean, std²) df for low ≤ high."""
        a, b = (low - mean) / std, (high - mean) / std
        return (mean - c) * (norm.cdf(b) - norm.cdf(a)) + std * (norm.pdf(a) - norm.pdf(b))

    def piece(low, high, c):
        below = jnp.minimum(high, c)
        above = jnp.maximum(low, c)
        return (-partial_moment(low, jnp.maximum(below, low), c)
                + partial_moment(jnp.minimum(above, high), high, c))
    return jnp.sum(jax.vmap(piece)(lows, highs, values))
