import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import rotations as R


def random_rotvecs(n, seed=0, scale=1.5):
    return jnp.asarray(np.random.default_rng(seed).normal(scale=scale, size=(n, 3)))


def test_rotvec_quat_matrix_round_trips():
    v = random_rotvecs(64)
    q = R.rotvec_to_quat(v)
    np.testing.assert_allclose(jnp.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    m = R.quat_to_matrix(q)
    np.testing.assert_allclose(m, R.rotvec_to_matrix(v), atol=1e-12)
    np.testing.assert_allclose(m @ jnp.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape),
                               atol=1e-12)
    np.testing.assert_allclose(jnp.linalg.det(m), 1.0, atol=1e-12)
    # log(exp(v)) = v for angles below π
    small = v * (2.5 / jnp.maximum(jnp.linalg.norm(v, axis=-1, keepdims=True), 2.5))
    np.testing.assert_allclose(R.quat_to_rotvec(R.rotvec_to_quat(small)), small, atol=1e-10)
    # matrix → quaternion recovers q up to sign, including near-π rotations
    q_back = R.matrix_to_quat(m)
    sign = jnp.sign(jnp.sum(q_back * q, -1, keepdims=True))
    np.testing.assert_allclose(q_back * sign, q, atol=1e-10)
    near_pi = R.rotvec_to_quat(jnp.array([[np.pi - 1e-4, 0.0, 0.0], [0.0, 0.0, -np.pi + 1e-6]]))
    back = R.matrix_to_quat(R.quat_to_matrix(near_pi))
    np.testing.assert_allclose(jnp.abs(jnp.sum(back * near_pi, -1)), 1.0, atol=1e-10)


def test_quaternion_product_composes_rotations():
    a, b = R.rotvec_to_quat(random_rotvecs(16, 1)), R.rotvec_to_quat(random_rotvecs(16, 2))
    np.testing.assert_allclose(R.quat_to_matrix(R.quat_multiply(a, b)),
                               R.quat_to_matrix(a) @ R.quat_to_matrix(b), atol=1e-12)
    np.testing.assert_allclose(R.quat_multiply(a, R.quat_conjugate(a)),
                               np.tile([1.0, 0, 0, 0], (16, 1)), atol=1e-12)


def test_axis_angle_and_euler_against_rotvec():
    axis = jnp.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(R.axis_angle_to_matrix(axis, 0.7),
                               R.rotvec_to_matrix(0.7 * axis), atol=1e-12)
    np.testing.assert_allclose(R.quat_to_matrix(R.axis_angle_to_quat(axis, 0.7)),
                               R.rotvec_to_matrix(0.7 * axis), atol=1e-12)
    angles = jnp.array([0.3, -0.5, 1.1])
    expected = (R.rotvec_to_matrix(jnp.array([0, 0, 1.1])) @ R.rotvec_to_matrix(
        jnp.array([0, -0.5, 0])) @ R.rotvec_to_matrix(jnp.array([0.3, 0, 0])))
    np.testing.assert_allclose(R.euler_xyz_to_matrix(angles), expected, atol=1e-12)


def test_6d_round_trip_and_projection():
    m = R.rotvec_to_matrix(random_rotvecs(32, 3))
    np.testing.assert_allclose(R.sixd_to_matrix(R.matrix_to_6d(m)), m, atol=1e-12)
    noisy = R.matrix_to_6d(m) + 0.01 * jnp.asarray(np.random.default_rng(4).normal(size=(32, 6)))
    fixed = R.sixd_to_matrix(noisy)
    np.testing.assert_allclose(fixed @ jnp.swapaxes(fixed, -1, -2),
                               np.broadcast_to(np.eye(3), fixed.shape), atol=1e-12)


@pytest.mark.parametrize("fn", [R.rotvec_to_quat, R.rotvec_to_matrix,
                                lambda v: R.quat_to_rotvec(R.rotvec_to_quat(v))])
def test_gradients_finite_and_correct_at_zero_rotation(fn):
    zero = jnp.zeros(3)
    jac = jax.jacfwd(lambda v: jnp.ravel(fn(v)))(zero)
    jac_rev = jax.jacrev(lambda v: jnp.ravel(fn(v)))(zero)
    assert np.all(np.isfinite(jac)) and np.all(np.isfinite(jac_rev))
    eps = 1e-6
    fd = np.stack([(np.ravel(fn(zero.at[k].set(eps))) - np.ravel(fn(zero.at[k].set(-eps))))
                   / (2 * eps) for k in range(3)], -1)
    np.testing.assert_allclose(jac, fd, atol=1e-8)
    np.testing.assert_allclose(jac_rev, fd, atol=1e-8)


def test_log_map_gradient_finite_at_identity_quaternion():
    grad = jax.jacrev(R.quat_to_rotvec)(jnp.array([1.0, 0.0, 0.0, 0.0]))
    assert np.all(np.isfinite(grad))
    np.testing.assert_allclose(grad[:, 1:], 2 * np.eye(3), atol=1e-12)
    grad_m = jax.jacrev(lambda m: R.matrix_to_rotvec(m))(jnp.eye(3))
    assert np.all(np.isfinite(grad_m))
