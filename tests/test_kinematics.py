"""Kinematics in float64: hand trigonometry, finite differences, jvp, DeepMimic's offsets."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import random_state
from jaxsim import builder, characters, kinematics, rotations
from jaxsim.model import rest_pose

fk = jax.jit(kinematics.forward_kinematics)
velocities = jax.jit(kinematics.link_velocities)
qd_to_qdot = jax.jit(kinematics.qd_to_qdot)


def points(model, q, links, offsets):
    """point_positions, jitted; `links` is static (an index array), so it is closed over."""
    links = np.asarray(links)
    return jax.jit(lambda m, x, o: kinematics.point_positions(m, x, links, o))(model, q, offsets)


THIGH, SHIN, HIP_Z = 0.421546, 0.40987, 0.084887


@pytest.fixture(scope="module")
def humanoid():
    """Built in float64 (the shared fixture's models are built in float32, then cast), so that
    DeepMimic's offsets are exact."""
    return characters.humanoid(dtype=jnp.float64)


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def two_link_arm(base_pos, base_rot, l1, l2):
    """A fixed base and two links turning about Z; the second joint sits l1 along the first
    link's X axis, and a box on the second link reaches l2 along its X."""
    links = [
        builder.LinkSpec(name="base", parent=None, joint="fixed", mass=1.0, shape="box",
                         shape_size=(0.05, 0.05, 0.05), joint_pos=base_pos, joint_rot=base_rot),
        builder.LinkSpec(name="upper", parent="base", joint="revolute", mass=1.0, shape="box",
                         shape_size=(l1 / 2, 0.03, 0.03), shape_pos=(l1 / 2, 0.0, 0.0)),
        builder.LinkSpec(name="lower", parent="upper", joint="revolute", mass=0.5, shape="box",
                         shape_size=(l2 / 2, 0.02, 0.02), shape_pos=(l2 / 2, 0.0, 0.0),
                         joint_pos=(l1, 0.0, 0.0)),
    ]
    return builder.build_model(links, source="arm", dtype=jnp.float64)


@pytest.mark.parametrize("base_rot", [np.eye(3), rot_y(np.pi / 2)], ids=["upright", "turned"])
def test_forward_kinematics_of_a_two_link_arm(base_rot):
    base, l1, l2 = np.array([0.5, 2.0, -0.3]), 0.7, 0.45
    model = two_link_arm(base, base_rot, l1, l2)
    assert model.nq == model.nv == 2
    for t1, t2 in [(0.0, 0.0), (0.3, -1.1), (np.pi / 2, np.pi / 2), (-2.5, 0.8)]:
        rot, pos = fk(model, jnp.array([t1, t2]))
        # In the base frame the arm moves in the XY plane.
        elbow = np.array([l1 * np.cos(t1), l1 * np.sin(t1), 0.0])
        tip = elbow + np.array([l2 * np.cos(t1 + t2), l2 * np.sin(t1 + t2), 0.0])
        np.testing.assert_allclose(pos[0], base, atol=1e-14)
        np.testing.assert_allclose(pos[1], base, atol=1e-14)
        np.testing.assert_allclose(pos[2], base + base_rot @ elbow, atol=1e-14)
        np.testing.assert_allclose(rot[0], base_rot, atol=1e-14)
        np.testing.assert_allclose(rot[1], base_rot @ rot_z(t1), atol=1e-14)
        np.testing.assert_allclose(rot[2], base_rot @ rot_z(t1 + t2), atol=1e-14)
        tip_q = points(model, jnp.array([t1, t2]), np.array([2]), jnp.array([[l2, 0.0, 0.0]]))
        np.testing.assert_allclose(tip_q[0], base + base_rot @ tip, atol=1e-14)


def test_fixed_base_arm_has_the_analytic_jacobian():
    """Link velocities of the arm: the tip's world velocity is J(θ) θ̇ by hand."""
    base, l1, l2 = np.array([0.0, 1.0, 0.0]), 0.7, 0.45
    model = two_link_arm(base, np.eye(3), l1, l2)
    t1, t2, w1, w2 = 0.4, -0.9, 1.3, -0.7
    q, qd = jnp.array([t1, t2]), jnp.array([w1, w2])
    rot, _ = fk(model, q)
    v = velocities(model, q, qd)
    np.testing.assert_allclose(v[0], np.zeros(6), atol=0)
    np.testing.assert_allclose(v[1], [0, 0, w1, 0, 0, 0], atol=1e-14)
    # Body-frame velocity of the lower link: ω about Z, and its origin (the elbow) moves
    # tangentially with speed l1·θ̇1.
    elbow_velocity = l1 * w1 * np.array([-np.sin(t1), np.cos(t1), 0.0])
    np.testing.assert_allclose(rot[2] @ v[2, :3], [0, 0, w1 + w2], atol=1e-14)
    np.testing.assert_allclose(rot[2] @ v[2, 3:], elbow_velocity, atol=1e-14)


def central_difference(fn, q, qdot, eps=1e-6):
    return jax.tree_util.tree_map(lambda a, b: (a - b) / (2 * eps),
                                  fn(q + eps * qdot), fn(q - eps * qdot))


def skew_to_vector(m):
    return np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / 2


@pytest.mark.parametrize("seed", [11, 12])
def test_link_velocities_match_finite_differences(models, seed):
    model = models["humanoid"]
    q, qd, _ = random_state(model, seed, velocity_scale=2.0)
    qdot = qd_to_qdot(model, q, qd)
    rot, pos = fk(model, q)
    rot_rate, pos_rate = central_difference(lambda x: fk(model, x), q, qdot)
    v = np.asarray(velocities(model, q, qd))
    rot, rot_rate, pos_rate = np.asarray(rot), np.asarray(rot_rate), np.asarray(pos_rate)
    assert np.abs(pos_rate).max() > 1.0 and np.abs(v[:, :3]).max() > 1.0   # not vacuous
    for i in range(model.n_links):
        # Linear: the world velocity of the link origin is R v_body.
        np.testing.assert_allclose(rot[i] @ v[i, 3:], pos_rate[i], atol=1e-7, err_msg=str(i))
        # Angular: Ṙ Rᵀ = [ω_world]×, with ω_world = R ω_body.
        omega_skew = rot_rate[i] @ rot[i].T
        np.testing.assert_allclose(omega_skew, -omega_skew.T, atol=1e-7)
        np.testing.assert_allclose(rot[i] @ v[i, :3], skew_to_vector(omega_skew), atol=1e-7,
                                   err_msg=str(i))


def test_root_velocity_is_body_frame(models):
    """The root's qd is its body-frame [ω; v] (docs/design.md, "Conventions"): link_velocities
    returns it as is."""
    model = models["humanoid"]
    q, qd, _ = random_state(model, 13)
    np.testing.assert_allclose(velocities(model, q, qd)[0], qd[:6], atol=1e-15)


@pytest.mark.parametrize("name", ["humanoid", "quadruped", "snake10"])
def test_center_of_mass_velocity_is_the_derivative_of_the_center_of_mass(models, name):
    model = models[name]
    q, qd, _ = random_state(model, 14, velocity_scale=2.0)
    qdot = qd_to_qdot(model, q, qd)
    _, expected = jax.jit(lambda x, t: jax.jvp(
        lambda y: kinematics.center_of_mass(model, y), (x,), (t,)))(q, qdot)
    got = jax.jit(kinematics.center_of_mass_velocity)(model, q, qd)
    assert float(jnp.abs(expected).max()) > 0.1
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_center_of_mass_at_rest_by_hand(humanoid):
    """The rest-pose centre of mass from the shapes' centres and DeepMimic's masses."""
    model = humanoid
    com = np.asarray(jax.jit(kinematics.center_of_mass)(model, rest_pose(model)))
    centres = {  # world centre of each link's shape (= its centre of mass), root at the origin
        "root": (0, 0.07, 0), "chest": (0, 0.236151 + 0.12, 0),
        "neck": (0, 0.236151 + 0.223894 + 0.175, 0),
        "right_hip": (0, -0.21, HIP_Z), "right_knee": (0, -THIGH - 0.2, HIP_Z),
        "right_ankle": (0.045, -THIGH - SHIN - 0.0225, HIP_Z),
        "right_shoulder": (-0.02405, 0.236151 + 0.2435 - 0.14, 0.18311),
        "right_elbow": (-0.02405, 0.236151 + 0.2435 - 0.274788 - 0.12, 0.18311),
        "right_wrist": (-0.02405, 0.236151 + 0.2435 - 0.274788 - 0.258947, 0.18311),
    }
    masses = {"root": 6, "chest": 14, "neck": 2, "right_hip": 4.5, "right_knee": 3,
              "right_ankle": 1, "right_shoulder": 1.5, "right_elbow": 1, "right_wrist": 0.5}
    total = np.zeros(3)
    for name, centre in centres.items():
        mirrored = np.array(centre) * (1, 1, -1)
        total += masses[name] * np.array(centre)
        if name.startswith("right_"):
            total += masses[name] * mirrored
    expected = total / 45.0
    np.testing.assert_allclose(com, expected, atol=1e-12)


def test_point_positions_of_the_humanoid_at_rest(humanoid):
    model = humanoid
    topo = model.topology
    q = rest_pose(model)
    names = ["root", "right_ankle", "left_ankle", "right_knee", "neck", "right_wrist",
             "left_wrist"]
    idx = np.array([topo.link_index(n) for n in names])
    p = dict(zip(names, np.asarray(points(model, q, idx, jnp.zeros((len(idx), 3))))))
    np.testing.assert_allclose(p["root"], [0, 0, 0], atol=0)
    np.testing.assert_allclose(p["right_ankle"], [0, -THIGH - SHIN, HIP_Z], atol=1e-15)
    np.testing.assert_allclose(p["left_ankle"], [0, -THIGH - SHIN, -HIP_Z], atol=1e-15)
    np.testing.assert_allclose(p["right_knee"], [0, -THIGH, HIP_Z], atol=1e-15)
    np.testing.assert_allclose(p["neck"], [0, 0.236151 + 0.223894, 0], atol=1e-15)
    np.testing.assert_allclose(p["right_wrist"], [-0.02405, 0.236151 + 0.2435 - 0.274788
                                                  - 0.258947, 0.18311], atol=1e-15)
    assert p["right_ankle"][1] < p["right_knee"][1] < p["root"][1] < p["neck"][1]
    assert p["left_wrist"][2] < 0 < p["right_wrist"][2]     # the left side is −Z
    # A point in a link: the front of the right foot's box (centre 0.045, half-length 0.0885).
    toe = points(model, q, np.array([topo.link_index("right_ankle")]),
                 jnp.array([[0.045 + 0.0885, -0.0225, 0.0]]))
    np.testing.assert_allclose(toe[0], [0.1335, -THIGH - SHIN - 0.0225, HIP_Z], atol=1e-15)


def test_point_positions_follow_the_root_and_the_knee(humanoid):
    """Move and turn the root, bend the right knee: the ankle moves as trigonometry says."""
    model = humanoid
    topo = model.topology
    root_pos, yaw, bend = np.array([1.0, 0.9, -2.0]), 0.7, -1.1
    q = np.array(rest_pose(model))
    q[0:3] = root_pos
    q[3:7] = [np.cos(yaw / 2), 0.0, np.sin(yaw / 2), 0.0]      # yaw about Y (w, x, y, z)
    q[topo.q_offsets[topo.link_index("right_knee")]] = bend
    ankle = points(model, jnp.asarray(q), np.array([topo.link_index("right_ankle")]),
                   jnp.zeros((1, 3)))[0]
    knee = np.array([0.0, -THIGH, HIP_Z])
    shin = rot_z(bend) @ np.array([0.0, -SHIN, 0.0])          # knees turn about local Z
    np.testing.assert_allclose(shin, [SHIN * np.sin(bend), -SHIN * np.cos(bend), 0.0],
                               atol=1e-15)
    expected = root_pos + rot_y(yaw) @ (knee + shin)
    np.testing.assert_allclose(ankle, expected, atol=1e-14)
    np.testing.assert_allclose(np.asarray(rotations.quat_to_matrix(jnp.asarray(q[3:7]))),
                               rot_y(yaw), atol=1e-15)
