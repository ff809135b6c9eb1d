"""A small Gaussian process in pure JAX: the surrogate of Bayesian Diversity Search (thesis §3.5.1).

Inputs live in the unit box (`to_unit` maps a user's bounds onto it). Each feature dimension is an
independent output with its own hyperparameters; every function below handles all outputs at once
(the output axis comes first in the hyperparameters and the factorisation).

Model, per output: f ~ GP(μ, k) with a constant prior mean μ and the Matérn-5/2 kernel with ARD
lengthscales (thesis eq. 3.17); observations y = f(x) + ε, ε ~ N(0, σ_n²). The posterior at x*
(thesis eq. 3.6):

    mean(x*) = μ + k*ᵀ (K + σ_n² I)⁻¹ (y − μ)
    var(x*)  = k(x*, x*) − k*ᵀ (K + σ_n² I)⁻¹ k*

Observations are held in fixed-capacity arrays with a mask, so a search that adds one point at a
time reuses one compiled function for many sizes: a masked-out row is decoupled from the others
(its kernel row and column are zero, its diagonal 1 and its target μ), which leaves the solution
for the real rows, the log-determinant and the quadratic form unchanged.

Hyperparameters are fitted by maximising the log marginal likelihood with Adam from several random
starts (vmapped). Each is a bounded log transform, log θ = centre + half-width · tanh(raw), which keeps
them positive and inside a sane range (lengthscales 0.01–10 box widths, signal variance 10⁻³–10²
and noise variance 10⁻⁶–1 of the data variance) with smooth gradients everywhere.

With a handful of observations the marginal likelihood cannot pin the hyperparameters down, and
its maximum is often degenerate. Two features in a 4-D box are best explained either by
lengthscales of a few hundredths, so that the two points are independent, or by noise alone; in
both cases the posterior σ is flat everywhere except right at the data, and an exploration pick
maximising it has nothing to go on (the third high-jump search, docs/discovery). `hyperprior`
maximises the posterior of the hyperparameters instead, with the weak priors that BoTorch
adopted from Hvarfner, Hellsten & Nardi ("Vanilla Bayesian Optimization Performs Great in High
Dimensions", ICML 2024): log ℓ ~ N(√2 + ½ log d, 3) per lengthscale (in box widths, so for
d = 4 a median of 8 widths: smooth unless the data say otherwise) and log σ_n² ~ N(−4, 1) (in
units of the data variance: little noise unless the data say otherwise). The signal variance
keeps no prior.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

JITTER = 1e-6                      # added to the diagonal, in units of the signal variance
LOG_LENGTHSCALE_RANGE = (np.log(0.01), np.log(10.0))
LOG_SIGNAL_RANGE = (np.log(1e-3), np.log(1e2))       # relative to the data variance
LOG_NOISE_RANGE = (np.log(1e-6), np.log(1.0))        # relative to the data variance
# `hyperprior`: log ℓ ~ N(√2 + ½ log d, 3) and log σ_n² ~ N(−4, 1) (see the module docstring)
LENGTHSCALE_PRIOR_STD = np.sqrt(3.0)
NOISE_PRIOR = (-4.0, 1.0)


class Hyperparameters(NamedTuple):
    """Per output (leading axis m): lengthscales (m, d), signal and noise variances (m,), all in
    units where the outputs have unit scale."""
    lengthscales: jax.Array
    signal_variance: jax.Array
    noise_variance: jax.Array


class Posterior(NamedTuple):
    """A fitted GP: the padded observations and everything the predictions need."""
    x: jax.Array               # (capacity, d) inputs in the unit box
    mask: jax.Array            # (capacity,) True for real observations
    prior_mean: jax.Array      # (m,) μ, in the outputs' units
    scale: jax.Array           # (m,) unit of the standardised outputs
    hyper: Hyperparameters
    cholesky: jax.Array        # (m, capacity, capacity) lower factor of the masked K + σ_n² I
    alpha: jax.Array           # (m, capacity) (K + σ_n² I)⁻¹ (y − μ) / scale


def to_unit(x, lower, upper):
    """Map points of the box [lower, upper] onto the unit box."""
    return (x - lower) / (upper - lower)


def from_unit(u, lower, upper):
    """Map points of the unit box onto [lower, upper]."""
    return lower + u * (upper - lower)


def matern52(x1, x2, lengthscales, signal_variance):
    """Matérn-5/2 ARD kernel matrix (thesis eq. 3.17):
    k(x, x') = σ² (1 + √5 r + 5r²/3) exp(−√5 r), r² = Σ_d (x_d − x'_d)² / ℓ_d².
    The square root is guarded so the gradient at r = 0 is the kernel's (zero), not NaN."""
    diff = (x1[:, None, :] - x2[None, :, :]) / lengthscales
    r2 = jnp.sum(diff * diff, axis=-1)
    positive = r2 > 0
    r = jnp.where(positive, jnp.sqrt(jnp.where(positive, r2, 1.0)), 0.0)
    s = jnp.sqrt(5.0) * r
    return signal_variance * (1.0 + s + s * s / 3.0) * jnp.exp(-s)


def _masked_covariance(x, mask, lengthscales, signal_variance, noise_variance):
    """K + σ_n² I (+ jitter) over the real rows; identity on the masked-out ones."""
    pair = mask[:, None] & mask[None, :]
    kernel = jnp.where(pair, matern52(x, x, lengthscales, signal_variance), 0.0)
    diagonal = jnp.where(mask, noise_variance + JITTER * signal_variance, 1.0)
    return kernel + jnp.diag(diagonal)


def lengthscale_prior_mean(dim):
    """The mean of the lengthscales' log-normal prior in `dim` dimensions."""
    return np.sqrt(2.0) + 0.5 * np.log(dim)


def log_hyperprior(hyper: Hyperparameters, isotropic=False):
    """log p(θ) of one output's lengthscales and noise variance under `hyperprior`'s priors, up to
    a constant (normal densities of their logarithms); an isotropic fit's one lengthscale (its
    d equal entries) counts once."""
    def log_normal(value, mean, std):
        return -0.5 * jnp.sum(((jnp.log(value) - mean) / std) ** 2)
    lengthscales = hyper.lengthscales[..., :1] if isotropic else hyper.lengthscales
    return (log_normal(lengthscales, lengthscale_prior_mean(hyper.lengthscales.shape[-1]),
                       LENGTHSCALE_PRIOR_STD)
            + log_normal(hyper.noise_variance, *NOISE_PRIOR))


def _unpack(raw, dim):
    """Raw unconstrained vector (k + 2,) → Hyperparameters, with k = d lengthscales (ARD) or
    k = 1 (one lengthscale for every dimension, broadcast to d)."""
    def bounded(value, bounds):
        low, high = bounds
        return jnp.exp(0.5 * (low + high) + 0.5 * (high - low) * jnp.tanh(value))
    count = raw.shape[-1] - 2
    return Hyperparameters(jnp.broadcast_to(bounded(raw[:count], LOG_LENGTHSCALE_RANGE), (dim,)),
                           bounded(raw[count], LOG_SIGNAL_RANGE),
                           bounded(raw[count + 1], LOG_NOISE_RANGE))


def _factor(x, residual, mask, hyper):
    """Cholesky factor and weights (K + σ_n² I)⁻¹ r of one output."""
    chol = jnp.linalg.cholesky(_masked_covariance(x, mask, *hyper))
    return chol, jax.scipy.linalg.cho_solve((chol, True), residual)


def log_marginal_likelihood(x, residual, mask, hyper: Hyperparameters):
    """log p(y | x, θ) of one output, for standardised residuals r = y − μ (Rasmussen & Williams
    eq. 2.30): −½ rᵀ (K + σ_n² I)⁻¹ r − ½ log|K + σ_n² I| − (n/2) log 2π over the real rows."""
    chol, alpha = _factor(x, residual, mask, hyper)
    n = jnp.sum(mask)
    return (-0.5 * residual @ alpha - jnp.sum(jnp.log(jnp.diagonal(chol)))
            - 0.5 * n * jnp.log(2.0 * jnp.pi))


def _fit_one_output(x, residual, mask, key, restarts, steps, learning_rate, isotropic,
                    hyperprior):
    """Best raw hyperparameters of one output over `restarts` Adam runs (restart 0 starts at the
    middle of every range; the others at random): of the marginal likelihood, or with
    `hyperprior` of the hyperparameters' posterior."""
    dim = x.shape[1]

    def loss(raw):
        hyper = _unpack(raw, dim)
        value = -log_marginal_likelihood(x, residual, mask, hyper)
        if hyperprior:
            value = value - log_hyperprior(hyper, isotropic)
        return jnp.where(jnp.isfinite(value), value, jnp.inf)

    optimizer = optax.adam(learning_rate)

    def run(raw):
        def update(carry, _):
            raw, state = carry
            grads = jax.grad(loss)(raw)
            grads = jnp.where(jnp.isfinite(grads), grads, 0.0)
            updates, state = optimizer.update(grads, state)
            return (optax.apply_updates(raw, updates), state), None
        (raw, _), _ = jax.lax.scan(update, (raw, optimizer.init(raw)), None, length=steps)
        return raw, loss(raw)

    lengthscales = 1 if isotropic else dim
    starts = jax.random.normal(key, (restarts, lengthscales + 2)).at[0].set(0.0)
    raws, losses = jax.vmap(run)(starts)
    return raws[jnp.argmin(losses)]


def _standardised_residuals(y, mask, prior_mean, scale):
    return jnp.where(mask[:, None], (y - prior_mean) / scale, 0.0).T                  # (m, n)


def _fit(x, y, mask, prior_mean, min_scale, key, restarts, steps, learning_rate, isotropic,
         hyperprior):
    count = jnp.maximum(jnp.sum(mask), 1)
    observed_mean = jnp.sum(jnp.where(mask[:, None], y, 0.0), axis=0) / count
    variance = jnp.sum(jnp.where(mask[:, None], (y - observed_mean) ** 2, 0.0), axis=0) / count
    scale = jnp.maximum(jnp.sqrt(variance), min_scale)
    scale = jnp.where(scale > 0, scale, 1.0)
    residuals = _standardised_residuals(y, mask, prior_mean, scale)
    keys = jax.random.split(key, y.shape[1])
    raws = jax.vmap(_fit_one_output, in_axes=(None, 0, None, 0, None, None, None, None, None))(
        x, residuals, mask, keys, restarts, steps, learning_rate, isotropic, hyperprior)
    hyper = jax.vmap(_unpack, in_axes=(0, None))(raws, x.shape[1])
    return condition(Posterior(x, mask, prior_mean, scale, hyper, None, None), x, y, mask)


@jax.jit
def condition(posterior: Posterior, x, y, mask):
    """The GP with `posterior`'s hyperparameters, prior mean and scale, conditioned on a new set of
    (padded) observations x (n, d), y (n, m) instead: used to add fantasised outcomes of pending
    points in batched search without refitting."""
    residuals = _standardised_residuals(y, mask, posterior.prior_mean, posterior.scale)
    chol, alpha = jax.vmap(_factor, in_axes=(None, 0, None, 0))(x, residuals, mask,
                                                                posterior.hyper)
    return posterior._replace(x=x, mask=mask, cholesky=chol, alpha=alpha)


_fit_jit = jax.jit(_fit, static_argnames=("restarts", "steps", "isotropic", "hyperprior"))


def fit(x, y, mask=None, prior_mean=None, key=None, restarts=8, steps=200, learning_rate=0.05,
        min_scale=0.0, isotropic=False, hyperprior=False):
    """Fit a GP to observations x (n, d) in the unit box and y (n, m) (or (n,)).

    `mask` (n,) marks the real rows of padded arrays (default: all). `prior_mean` (m,) is the constant
    μ; by default the middle of the observed range of each output. The outputs are standardised by
    their observed standard deviation, but by no less than `min_scale` (m,): with few observations,
    or all of one value, the observed spread says little about how far the function can vary, and
    the fitted signal variance is a multiple of this unit. `isotropic` fits one lengthscale for
    every input dimension instead of one each (ARD). `hyperprior` fits the hyperparameters'
    posterior under weak priors instead of the marginal likelihood alone (module docstring).
    Returns a `Posterior`.
    """
    x = jnp.asarray(x)
    y = jnp.asarray(y, x.dtype)
    y = y[:, None] if y.ndim == 1 else y
    if x.ndim != 2 or y.shape[0] != x.shape[0]:
        raise ValueError(f"fit needs x of shape (n, d) and y of shape (n, m); got {x.shape} and "
                         f"{y.shape}")
    mask = jnp.ones(x.shape[0], bool) if mask is None else jnp.asarray(mask, bool)
    if not bool(jnp.any(mask)):
        raise ValueError("fit needs at least one observation")
    if prior_mean is None:
        low = jnp.min(jnp.where(mask[:, None], y, jnp.inf), axis=0)
        high = jnp.max(jnp.where(mask[:, None], y, -jnp.inf), axis=0)
        prior_mean = 0.5 * (low + high)
    prior_mean = jnp.broadcast_to(jnp.asarray(prior_mean, x.dtype), (y.shape[1],))
    min_scale = jnp.broadcast_to(jnp.asarray(min_scale, x.dtype), (y.shape[1],))
    key = jax.random.PRNGKey(0) if key is None else key
    return _fit_jit(x, y, mask, prior_mean, min_scale, key, restarts, steps, learning_rate,
                    isotropic, hyperprior)


@jax.jit
def predict(posterior: Posterior, x_star):
    """Posterior mean and variance of f (thesis eq. 3.6) at x_star (n*, d): two (n*, m) arrays in
    the outputs' units. The variance is that of the latent f (no observation noise)."""
    def one_output(hyper, chol, alpha, scale, mean):
        k_star = matern52(x_star, posterior.x, hyper.lengthscales, hyper.signal_variance)
        k_star = jnp.where(posterior.mask[None, :], k_star, 0.0)
        v = jax.scipy.linalg.solve_triangular(chol, k_star.T, lower=True)
        variance = jnp.maximum(hyper.signal_variance - jnp.sum(v * v, axis=0), 0.0)
        return mean + scale * (k_star @ alpha), scale * scale * variance
    means, variances = jax.vmap(one_output)(posterior.hyper, posterior.cholesky, posterior.alpha,
                                            posterior.scale, posterior.prior_mean)
    return means.T, variances.T
