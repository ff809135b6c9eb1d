"""A model of where the black box succeeds, to keep BDS's picks off regions that fail.

A jump training from a bad take-off state learns nothing (thesis §3.3: "bad initial states will
fail fast"), and such an evaluation returns no feature (`bds.search.Failure`). BDS's own
acquisitions (thesis eqs. 3.7, 3.10) know nothing of this: the posterior variance and the expected
distance to the features seen are both largest far from every observation, at the corners of the
box, and that is where failures cluster (docs/discovery, docs/benchmarks.md). Following Bayesian
optimisation with unknown constraints (Gardner et al., "Bayesian Optimization with Inequality
Constraints", ICML 2014; Gelbart, Snoek & Adams, UAI 2014), success is treated as a constraint
c(x) > 0 modelled by its own GP, and each acquisition a(x) is replaced by a(x) · P[c(x) > 0]
(maximised as its logarithm, `weighted`).

The constraint's observations are the evaluations' outcomes as labels, c = +1 for a success and
−1 for a failure, fitted by `bds.gp` like a feature (Matérn-5/2) with prior mean 0 — nothing
known is an even chance — and unit scale, but with one lengthscale for every dimension: a
handful of binary outcomes cannot tell the dimensions apart (fitted per dimension, by the
likelihood alone, to the high-jump search's first four outcomes, the model put all its weight
on ω_z and gave the next pick, which failed, P = 1.00). Then P[c(x) > 0] = Φ(μ_c(x) / σ_c(x)),
with σ_c the latent posterior standard deviation: near a success it tends to 1, near a failure
to 0, and far from every evaluation to ½. GP regression on labels is the least-squares
classifier of Rasmussen & Williams (2006, §6.5); it needs no approximate inference and reuses
the feature GP's code.

Its hyperparameters are fitted under `bds.gp`'s weak priors (`hyperprior`), not by the marginal
likelihood alone. With one success and four failures in 4-D (the narrower-box high-jump search,
docs/discovery) the likelihood has two degenerate maxima, and the random restarts decide which
one the fit lands in: a lengthscale of 0.03–0.07 box widths, where every point not evaluated
gets P = ½, or pure noise (a lengthscale of 5–10 widths and σ_n² ≈ 0.8), where every point gets
P ≈ 0.14, the success's own included. Either way the weights say nothing. Under the priors
every random start gives the same fit, a lengthscale of 0.78 widths with little noise: P ≈ 1
at the success, ≈ 0 at the failures, and in between away from them. A smooth fit can be
confidently wrong too (fitted so to three successes and two failures, it gave a pick that then
failed P = 0.996, docs/discovery "A fourth search"), but it learns from every outcome.
"""

import jax.numpy as jnp
from jax.scipy.stats import norm

from bds import gp

SUCCESS, FAILURE = 1.0, -1.0            # the constraint's observed values
MIN_STD = 1e-6                          # keeps Φ(μ/σ) finite where σ_c vanishes
TINY = 1e-30                            # an acquisition of 0, in the logarithm


def fit(x, succeeded, mask, key, restarts, steps):
    """The constraint GP of padded evaluations x (capacity, d) in the unit box, `succeeded`
    (capacity,) bool, real rows where `mask`."""
    labels = jnp.where(jnp.asarray(succeeded), SUCCESS, FAILURE)[:, None]
    return gp.fit(x, labels, mask, prior_mean=0.0, key=key, restarts=restarts, steps=steps,
                  min_scale=1.0, isotropic=True, hyperprior=True)


def log_success_probability(model: gp.Posterior, x):
    """log P[c(x) > 0] = log Φ(μ_c / σ_c) at points x (n, d) of the unit box; (n,). Finite
    where the probability itself underflows to 0."""
    mean, variance = gp.predict(model, x)
    return norm.logcdf(mean[:, 0] / jnp.sqrt(variance[:, 0] + MIN_STD ** 2))


def success_probability(model: gp.Posterior, x):
    """P[c(x) > 0] = Φ(μ_c / σ_c) at points x (n, d) of the unit box; (n,)."""
    return jnp.exp(log_success_probability(model, x))


def weighted(acquisition, model: gp.Posterior | None):
    """A function with the maximisers of acquisition(x) · P[c(x) > 0], the acquisition itself
    when there is no model. With a model it is the logarithm, log a(x) + log P[c(x) > 0]: the
    product underflows to a flat 0 over a region that fails, where L-BFGS gets no gradient and
    DIRECT no ordering (and optax's L-BFGS once never returned on it, in the ballistic benchmark),
    while the logarithm keeps pointing out of it. The acquisitions are ≥ 0; 0 is taken as
    `TINY`."""
    if model is None:
        return acquisition
    return lambda x: (jnp.log(jnp.maximum(acquisition(x), TINY))
                      + log_success_probability(model, x))
