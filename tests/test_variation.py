"""Body variations (`jaxsim.variation.scaled_body`): factors of 1 change nothing, a uniform
length factor scales every link's place about the root (and the inertia by s², the mass kept),
a leg factor moves only what hangs from the legs, and unlimited joints stay unlimited with a
finite gradient."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import characters, kinematics
from jaxsim.model import rest_pose
from jaxsim.variation import scaled_body


@pytest.fixture(scope="module")
def humanoid():
    return characters.humanoid().astype(jnp.float64)


def random_pose(model, seed=0):
    rng = np.random.default_rng(seed)
    q = np.array(rest_pose(model))
    topo = model.topology
    for i, kind in enumerate(topo.joint_types):
        start = topo.q_offsets[i]
        if kind in ("free", "spherical"):
            at = start + (3 if kind == "free" else 0)
            quat = rng.normal(size=4)
            q[at:at + 4] = quat / np.linalg.norm(quat)
        elif kind == "revolute":
            q[start] = rng.uniform(-1, 1)
    q[:3] = (0.3, 1.0, -0.2)
    return jnp.asarray(q)


def test_factors_of_one_give_the_model_back(humanoid):
    n, nv = humanoid.n_links, humanoid.nv
    same = scaled_body(humanoid, jnp.ones(n), jnp.ones(n), jnp.ones(nv), jnp.ones(nv))
    for a, b in zip(jax.tree_util.tree_leaves(humanoid), jax.tree_util.tree_leaves(same)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_uniform_length_factor_scales_the_body_about_its_root(humanoid):
    s = 1.3
    q = random_pose(humanoid)
    bigger = scaled_body(humanoid, length=jnp.full(humanoid.n_links, s))
    _, pos = kinematics.forward_kinematics(humanoid, q)
    _, pos_big = kinematics.forward_kinematics(bigger, q)
    np.testing.assert_allclose(pos_big - pos_big[0], s * (pos - pos[0]), atol=1e-12)
    com, com_big = (kinematics.center_of_mass(m, q) for m in (humanoid, bigger))
    np.testing.assert_allclose(com_big - pos[0], s * (com - pos[0]), atol=1e-12)
    np.testing.assert_allclose(bigger.inertia, s**2 * humanoid.inertia)
    np.testing.assert_array_equal(bigger.mass, humanoid.mass)


def test_a_leg_factor_moves_only_the_feet_and_shins(humanoid):
    legs = np.array([name.endswith(("_hip", "_knee")) for name in humanoid.topology.names])
    q = random_pose(humanoid, 1)
    longer = scaled_body(humanoid, length=jnp.where(legs, 1.2, 1.0))
    _, pos = kinematics.forward_kinematics(humanoid, q)
    _, pos_long = kinematics.forward_kinematics(longer, q)
    moved = np.linalg.norm(np.asarray(pos_long - pos), axis=1) > 1e-9
    names = humanoid.topology.names
    assert {names[i] for i in np.flatnonzero(moved)} == {
        "right_knee", "right_ankle", "left_knee", "left_ankle"}


def test_unlimited_joints_stay_unlimited_with_a_finite_gradient(humanoid):
    limits = humanoid.torque_limit.at[:6].set(jnp.inf)      # the root's: no limit

    def total(scale):
        scaled = scaled_body(humanoid.replace(torque_limit=limits),
                             torque_limit=jnp.full(humanoid.nv, scale))
        return jnp.sum(jnp.where(jnp.isfinite(scaled.torque_limit), scaled.torque_limit, 0.0))

    assert np.isinf(np.asarray(scaled_body(humanoid.replace(torque_limit=limits),
                                           torque_limit=jnp.full(humanoid.nv, 2.0))
                               .torque_limit[:6])).all()
    gradient = jax.grad(total)(1.5)
    assert np.isfinite(gradient)
    assert gradient == pytest.approx(float(jnp.sum(jnp.where(jnp.isfinite(limits), limits, 0))))
