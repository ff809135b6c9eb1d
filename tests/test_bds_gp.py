"""The Gaussian process and the acquisition functions of BDS, against independent references."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bds import acquisition, gp
from bds.novelty import novelty_reward


def numpy_matern52(x1, x2, lengthscales, variance):
    r = np.sqrt(np.sum(((x1[:, None] - x2[None]) / lengthscales) ** 2, axis=-1))
    return variance * (1 + np.sqrt(5) * r + 5 * r ** 2 / 3) * np.exp(-np.sqrt(5) * r)


def test_kernel_matrix_is_symmetric_positive_definite_with_finite_gradients():
    x = np.random.default_rng(0).uniform(size=(30, 3))
    k = np.asarray(gp.matern52(jnp.asarray(x), jnp.asarray(x), jnp.array([0.3, 0.5, 1.0]), 2.0))
    np.testing.assert_allclose(k, k.T, atol=1e-14)
    np.testing.assert_allclose(np.diag(k), 2.0)
    assert np.linalg.eigvalsh(k).min() > 0
    np.testing.assert_allclose(k, numpy_matern52(x, x, np.array([0.3, 0.5, 1.0]), 2.0), rtol=1e-12)
    # At zero distance the kernel is flat: the gradient is zero, not NaN.
    grad = jax.grad(lambda p: gp.matern52(p[None], jnp.zeros((1, 3)), jnp.ones(3), 1.0)[0, 0])(
        jnp.zeros(3))
    np.testing.assert_array_equal(grad, 0.0)


def test_posterior_matches_a_numpy_reference_and_ignores_padding():
    rng = np.random.default_rng(1)
    x, x_star = rng.uniform(size=(12, 2)), rng.uniform(size=(7, 2))
    y = np.stack([np.sin(6 * x[:, 0]) + x[:, 1], np.cos(4 * x[:, 1])], axis=1)
    prior_mean = np.array([0.2, -0.1])
    posterior = gp.fit(x, y, prior_mean=prior_mean, restarts=2, steps=50)
    mean, variance = gp.predict(posterior, jnp.asarray(x_star))
    for m in range(2):
        hyper = jax.tree.map(lambda leaf: np.asarray(leaf[m]), posterior.hyper)
        scale = float(posterior.scale[m])
        k = numpy_matern52(x, x, hyper.lengthscales, hyper.signal_variance)
        k += np.eye(12) * (hyper.noise_variance + gp.JITTER * hyper.signal_variance)
        k_star = numpy_matern52(x_star, x, hyper.lengthscales, hyper.signal_variance)
        expected_mean = prior_mean[m] + scale * k_star @ np.linalg.solve(
            k, (y[:, m] - prior_mean[m]) / scale)
        expected_var = scale ** 2 * (hyper.signal_variance
                                     - np.sum(k_star * np.linalg.solve(k, k_star.T).T, axis=1))
        np.testing.assert_allclose(mean[:, m], expected_mean, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(variance[:, m], expected_var, rtol=1e-6, atol=1e-10)
    # The same data padded to 16 rows with junk in the masked rows gives the same posterior.
    padded_x = np.concatenate([x, rng.uniform(size=(4, 2))])
    padded_y = np.concatenate([y, rng.normal(size=(4, 2)) * 100])
    mask = np.arange(16) < 12
    conditioned = gp.condition(posterior, jnp.asarray(padded_x), jnp.asarray(padded_y),
                               jnp.asarray(mask))
    mean_padded, variance_padded = gp.predict(conditioned, jnp.asarray(x_star))
    np.testing.assert_allclose(mean_padded, mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(variance_padded, variance, rtol=1e-10, atol=1e-12)


def test_marginal_likelihood_fit_recovers_known_lengthscales():
    """Draw from a GP with lengthscales (0.15, 1.5) and check the fit finds a short scale on the
    first input and a long one on the second."""
    rng = np.random.default_rng(2)
    x = rng.uniform(size=(120, 2))
    true_scales = np.array([0.15, 1.5])
    k = numpy_matern52(x, x, true_scales, 1.0) + 1e-4 * np.eye(120)
    y = np.linalg.cholesky(k) @ rng.normal(size=120)
    posterior = gp.fit(x, y, prior_mean=0.0, key=jax.random.PRNGKey(3), restarts=4, steps=300)
    scales = np.asarray(posterior.hyper.lengthscales[0])
    # Lengthscales are in units where y has unit scale; they do not depend on the scale.
    assert 0.08 < scales[0] < 0.3, scales
    assert scales[1] > 0.7, scales
    assert float(posterior.hyper.noise_variance[0]) < 0.05


def test_an_isotropic_fit_shares_one_lengthscale_and_recovers_it():
    """Draw from a GP with one lengthscale 0.3 on both inputs: the isotropic fit returns equal
    lengthscales near it, and its marginal likelihood is the ARD one's at those lengthscales."""
    rng = np.random.default_rng(4)
    x = rng.uniform(size=(120, 2))
    k = numpy_matern52(x, x, np.array([0.3, 0.3]), 1.0) + 1e-4 * np.eye(120)
    y = np.linalg.cholesky(k) @ rng.normal(size=120)
    posterior = gp.fit(x, y, prior_mean=0.0, key=jax.random.PRNGKey(3), restarts=4, steps=300,
                       isotropic=True)
    scales = np.asarray(posterior.hyper.lengthscales[0])
    assert scales.shape == (2,) and scales[0] == scales[1]
    assert 0.15 < scales[0] < 0.6, scales


def test_success_probability_is_phi_of_mean_over_std_and_follows_the_outcomes():
    """P[c > 0] = Φ(μ_c/σ_c) of the ±1 label GP (bds.feasibility): ½ halfway between a success
    and a failure (μ_c = 0 by symmetry), high near successes, low near failures."""
    from jax.scipy.stats import norm
    from bds import feasibility
    x = np.array([[0.2, 0.5], [0.25, 0.3], [0.8, 0.5], [0.75, 0.7]])
    succeeded = np.array([True, True, False, False])
    model = feasibility.fit(x, succeeded, np.ones(4, bool), jax.random.PRNGKey(0), 4, 200)
    assert float(model.hyper.lengthscales[0, 0]) == float(model.hyper.lengthscales[0, 1])
    points = jnp.array([[0.5, 0.5], [0.22, 0.4], [0.78, 0.6]])
    mean, variance = gp.predict(model, points)
    probability = feasibility.success_probability(model, points)
    np.testing.assert_allclose(probability, norm.cdf(mean[:, 0] / jnp.sqrt(variance[:, 0])),
                               rtol=1e-6)
    assert abs(float(probability[0]) - 0.5) < 1e-6
    assert float(probability[1]) > 0.8 and float(probability[2]) < 0.2
    acquisition_value = lambda z: jnp.sum(z, axis=1)
    np.testing.assert_allclose(jnp.exp(feasibility.weighted(acquisition_value, model)(points)),
                               jnp.sum(points, axis=1) * probability, rtol=1e-12)
    assert feasibility.weighted(acquisition_value, None) is acquisition_value


def test_success_model_fit_does_not_depend_on_the_restarts():
    """The narrower-box high-jump search's first five outcomes (one success, four failures; the
    unit-box x of docs/discovery/box2/evaluations.jsonl, rounded): by the marginal likelihood
    alone the fit fell, key by key, into a lengthscale of a few hundredths (P = ½ at every point
    not evaluated) or into pure noise (P ≈ 0.14 everywhere, the success included). Under
    bds.gp's priors every key gives one fit, and it follows the outcomes (bds.feasibility)."""
    from bds import feasibility
    x = np.array([[0.637, 0.27, 0.041, 0.017], [0.89, 0.557, 0.801, 0.957],
                  [0.081, 0.402, 0.601, 0.145], [0.895, 0.86, 0.321, 0.317],
                  [0.0, 1.0, 0.0, 1.0]])
    succeeded = np.array([True, False, False, False, False])
    fits = [feasibility.fit(x, succeeded, np.ones(5, bool), jax.random.PRNGKey(key), 8, 200)
            for key in range(4)]
    lengthscales = [float(model.hyper.lengthscales[0, 0]) for model in fits]
    np.testing.assert_allclose(lengthscales, lengthscales[0], rtol=1e-3)
    assert 0.2 < lengthscales[0] < 5.0, lengthscales
    far_corner = np.array([[0.0, 0.0, 0.0, 1.0]])        # 1 box width from the nearest failure
    probability = feasibility.success_probability(fits[0], jnp.asarray(np.vstack([x, far_corner])))
    assert float(probability[0]) > 0.9, probability
    assert float(jnp.max(probability[1:5])) < 0.1, probability
    assert 0.2 < float(probability[5]) < 0.8, probability


def test_monte_carlo_diversity_converges_to_the_closed_form():
    rng = np.random.default_rng(4)
    x = rng.uniform(size=(6, 1))
    y = np.sin(5 * x[:, 0])
    posterior = gp.fit(x, y, restarts=2, steps=50)
    x_star = jnp.array([[0.05], [0.5], [0.97]])
    mean, variance = gp.predict(posterior, x_star)
    observed = jnp.asarray(y[:, None])
    exact = np.array([acquisition.diversity_closed_form_1d(m, np.sqrt(v), y)
                      for m, v in zip(np.asarray(mean[:, 0]), np.asarray(variance[:, 0]))])
    base = jax.random.normal(jax.random.PRNGKey(0), (200_000, 1))
    estimate = acquisition.diversity(posterior, x_star, observed, jnp.ones(6, bool), base)
    np.testing.assert_allclose(estimate, exact, rtol=1e-2)
    # The closed form itself against direct numerical integration of the density.
    f = np.linspace(-8, 8, 400_001)
    density = np.exp(-0.5 * ((f - 0.3) / 0.7) ** 2) / (0.7 * np.sqrt(2 * np.pi))
    nearest = np.min(np.abs(f[:, None] - y[None]), axis=1)
    np.testing.assert_allclose(acquisition.diversity_closed_form_1d(0.3, 0.7, y),
                               np.trapezoid(nearest * density, f), rtol=1e-6)


def test_exploration_is_largest_away_from_data():
    x = np.random.default_rng(5).uniform(0.1, 0.4, size=(8, 2))
    posterior = gp.fit(x, np.sin(3 * x[:, 0]) + x[:, 1], restarts=2, steps=100)
    std = acquisition.exploration(posterior, jnp.array([[0.25, 0.25], [0.9, 0.9]]))
    assert std[1] > 3 * std[0]


def test_the_hyperprior_keeps_two_observations_from_making_the_posterior_flat():
    """The third high-jump search's first model pick (docs/discovery): two features in a 4-D
    box, 74° and 165° with the prior mean at 90°. By the marginal likelihood alone the posterior
    σ is the same nearly everywhere, so exploration cannot tell a corner from a point beside
    the data; under the hyperparameter priors it is several times larger far from the data, and
    it fits a few-percent noise rather than near none or all."""
    x = np.array([[0.64, 0.27, 0.04, 0.02], [0.90, 0.86, 0.32, 0.32]])      # 000 and 003
    y = np.radians([[74.0], [165.0]])
    rest = dict(prior_mean=np.pi / 2, min_scale=np.pi / 4, key=jax.random.PRNGKey(4),
                restarts=8, steps=200)
    points = jnp.asarray(np.random.default_rng(0).uniform(size=(2000, 4)))
    near = jnp.asarray(x + 0.1)
    for hyperprior, spread in ((False, 1.05), (True, 2.0)):
        posterior = gp.fit(x, y, hyperprior=hyperprior, **rest)
        std = np.asarray(acquisition.exploration(posterior, points))
        ratio = std.max() / float(np.max(acquisition.exploration(posterior, near)))
        assert (ratio < spread) if not hyperprior else (ratio > spread), (hyperprior, ratio)
    noise = float(posterior.hyper.noise_variance[0])
    assert 1e-3 < noise < 0.2
    # the prior's density, by hand: log ℓ ~ N(√2 + ½ log d, 3), log σ_n² ~ N(−4, 1)
    hyper = gp.Hyperparameters(jnp.array([1.0, np.e]), jnp.array(1.0), jnp.array(np.exp(-3.0)))
    mean = np.sqrt(2) + 0.5 * np.log(2)
    expected = -0.5 * (mean ** 2 + (1 - mean) ** 2) / 3 - 0.5
    np.testing.assert_allclose(float(gp.log_hyperprior(hyper)), expected, rtol=1e-12)
    # an isotropic fit's one lengthscale, broadcast over d = 2, counts once
    one = gp.Hyperparameters(jnp.array([np.e, np.e]), jnp.array(1.0), jnp.array(np.exp(-3.0)))
    np.testing.assert_allclose(float(gp.log_hyperprior(one, isotropic=True)),
                               -0.5 * (1 - mean) ** 2 / 3 - 0.5, rtol=1e-12)


def test_the_hyperprior_changes_little_where_the_data_decide():
    rng = np.random.default_rng(6)
    x, x_star = rng.uniform(size=(40, 2)), rng.uniform(size=(50, 2))
    y = np.sin(5 * x[:, 0]) + 0.5 * x[:, 1]
    plain, with_prior = (gp.fit(x, y, restarts=4, steps=300, hyperprior=h) for h in (False, True))
    truth = np.sin(5 * x_star[:, 0]) + 0.5 * x_star[:, 1]
    for posterior in (plain, with_prior):
        mean, _ = gp.predict(posterior, jnp.asarray(x_star))
        assert np.max(np.abs(np.asarray(mean[:, 0]) - truth)) < 0.05


def test_a_known_feature_range_keeps_the_prior_wide_when_every_observation_agrees():
    # Five points of one strategy: the observed spread is only the noise (0.01).
    x = np.random.default_rng(2).uniform(0.0, 0.3, size=(5, 2))
    y = 0.6 + 0.01 * np.random.default_rng(3).standard_normal(5)
    far = jnp.array([[0.95, 0.95]])
    narrow = gp.fit(x, y, restarts=2, steps=100)
    wide = gp.fit(x, y, prior_mean=0.5, min_scale=0.25, restarts=2, steps=100)
    assert float(narrow.scale[0]) < 0.02 and float(wide.scale[0]) == 0.25
    mean, variance = gp.predict(wide, far)
    # Far from the data the posterior returns towards the given prior mean …
    assert abs(float(mean[0, 0]) - 0.5) < abs(float(mean[0, 0]) - 0.6)
    # … and is unsure on the scale of the range, not of the noise.
    assert np.sqrt(float(variance[0, 0])) > 0.05 > np.sqrt(float(gp.predict(narrow, far)[1][0, 0]))


def test_distances():
    f, others = jnp.array([3.0]), jnp.array([[-3.0], [0.0]])
    np.testing.assert_allclose(acquisition.wrapped_angle(f, others),
                               [2 * np.pi - 6.0, 3.0], rtol=1e-6)
    np.testing.assert_allclose(acquisition.euclidean(f, others), [6.0, 3.0], rtol=1e-6)
    # Geodesic: rotations by 0.4 rad and by −0.5 rad about the same axis are 0.9 rad apart; a
    # rotation by π − 0.1 and one by −(π − 0.1) about the same axis are 0.2 rad apart.
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    np.testing.assert_allclose(
        acquisition.rotation_geodesic(jnp.asarray(0.4 * axis),
                                      jnp.asarray([-0.5 * axis, (np.pi - 0.1) * axis])),
        [0.9, np.pi - 0.5], rtol=1e-6)
    np.testing.assert_allclose(
        acquisition.rotation_geodesic(jnp.asarray((np.pi - 0.1) * axis),
                                      jnp.asarray([-(np.pi - 0.1) * axis])), [0.2], rtol=1e-5)
    with pytest.raises(ValueError, match="unknown feature distance 'manhattan'"):
        acquisition.distance_function("manhattan")


def test_novelty_reward_matches_eq_3_12():
    known = jnp.array([[0.0, 0.0], [1.0, 0.0]])
    rewards = novelty_reward(jnp.array([[0.0, 0.0], [0.0, 0.25], [0.5, 0.3], [5.0, 0.0]]),
                             known, threshold=0.5)
    expected = [0.01, 0.5, min(np.hypot(0.5, 0.3) / 0.5, 1.0), 1.0]
    np.testing.assert_allclose(rewards, expected, rtol=1e-12)
    assert jax.jit(novelty_reward, static_argnums=2)(jnp.array([0.2, 0.0]), known, 0.5) == 0.4
