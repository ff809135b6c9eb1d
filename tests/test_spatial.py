"""Spatial algebra identities (Featherstone, RBDA ch. 2)."""

import jax.numpy as jnp
import numpy as np

from jaxsim import rotations, spatial

RNG = np.random.default_rng(0)


def random_transform():
    rotation = rotations.rotvec_to_matrix(jnp.asarray(RNG.normal(size=3)))
    return rotation, jnp.asarray(RNG.normal(size=3))


def test_cross_operators():
    v, u, f = (jnp.asarray(RNG.normal(size=6)) for _ in range(3))
    np.testing.assert_allclose(spatial.crm(v) @ u, spatial.cross_motion(v, u), atol=1e-12)
    np.testing.assert_allclose(spatial.crf(v) @ f, spatial.cross_force(v, f), atol=1e-12)
    np.testing.assert_allclose(spatial.crf(v), -spatial.crm(v).T, atol=1e-12)
    # Power is invariant: (v × u) · f = −u · (v ×* f)
    np.testing.assert_allclose(spatial.cross_motion(v, u) @ f, -u @ spatial.cross_force(v, f),
                               atol=1e-12)


def test_plucker_transforms_and_their_fast_forms():
    rotation, translation = random_transform()
    x = spatial.plucker(rotation, translation)
    v, f = jnp.asarray(RNG.normal(size=6)), jnp.asarray(RNG.normal(size=6))
    np.testing.assert_allclose(spatial.transform_motion(rotation, translation, v), x @ v,
                               atol=1e-12)
    np.testing.assert_allclose(spatial.transform_force_to_parent(rotation, translation, f),
                               x.T @ f, atol=1e-12)
    # A point fixed in B moving with velocity v has the same linear velocity seen from both frames
    point_in_a = translation
    velocity_b = spatial.transform_motion(rotation, translation, v)
    np.testing.assert_allclose(rotation.T @ velocity_b[3:],
                               v[3:] + jnp.cross(v[:3], point_in_a), atol=1e-12)
    # Composition and inverse: X(E2, r2) X(E1, r1) = X(E2 E1, r1 + E1ᵀ r2)
    rotation2, translation2 = random_transform()
    composed = spatial.plucker(rotation2 @ rotation, translation + rotation.T @ translation2)
    np.testing.assert_allclose(spatial.plucker(rotation2, translation2) @ x, composed, atol=1e-12)
    inverse = spatial.plucker(rotation.T, -rotation @ translation)
    np.testing.assert_allclose(inverse @ x, np.eye(6), atol=1e-12)
    # An inertia moved to the parent by blocks equals Xᵀ I X with the 6×6 transform, also for a
    # non-symmetric matrix (the block form transforms all four blocks) and a batch of them.
    matrices = jnp.asarray(RNG.normal(size=(2, 6, 6)))
    for inertia in (matrices[0] @ matrices[0].T, matrices[1]):
        np.testing.assert_allclose(spatial.inertia_to_parent(rotation, translation, inertia),
                                   x.T @ inertia @ x, atol=1e-12)
    batch = spatial.inertia_to_parent(jnp.stack([rotation, rotation2]),
                                      jnp.stack([translation, translation2]), matrices)
    x2 = spatial.plucker(rotation2, translation2)
    np.testing.assert_allclose(batch[1], x2.T @ matrices[1] @ x2, atol=1e-12)


def test_spatial_inertia_matches_rigid_body_momentum():
    mass = jnp.asarray(2.5)
    com = jnp.asarray(RNG.normal(size=3))
    a = RNG.normal(size=(3, 3))
    rot_inertia = jnp.asarray(a @ a.T + np.eye(3))
    inertia = spatial.inertia_matrix(mass, com, rot_inertia)
    np.testing.assert_allclose(inertia, inertia.T, atol=1e-12)
    assert np.linalg.eigvalsh(inertia).min() > 0
    v = jnp.asarray(RNG.normal(size=6))
    momentum = inertia @ v
    com_velocity = v[3:] + jnp.cross(v[:3], com)
    np.testing.assert_allclose(momentum[3:], mass * com_velocity, atol=1e-12)
    np.testing.assert_allclose(momentum[:3], rot_inertia @ v[:3] + jnp.cross(com, mass * com_velocity),
                               atol=1e-12)
    # Kinetic energy ½ vᵀ I v = ½ m |v_c|² + ½ ωᵀ Ī_c ω
    np.testing.assert_allclose(0.5 * v @ momentum, 0.5 * mass * com_velocity @ com_velocity
                               + 0.5 * v[:3] @ rot_inertia @ v[:3], rtol=1e-12)


def test_small_matrix_products_match_matmul():
    a, b = jnp.asarray(RNG.normal(size=(4, 6, 3))), jnp.asarray(RNG.normal(size=(4, 3, 5)))
    v = jnp.asarray(RNG.normal(size=(4, 3)))
    np.testing.assert_allclose(spatial.mat_mat(a, b), a @ b, atol=1e-12)
    np.testing.assert_allclose(spatial.mat_vec(a, v), (a @ v[..., None])[..., 0], atol=1e-12)
