"""MJCF export: structure, masses and inertias, and MuJoCo's mass matrix and link positions for
the exported models (MuJoCo is a test dependency: the `test` extra in pyproject.toml)."""

import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from conftest import random_state
from jaxsim import builder, characters, dynamics, kinematics, rotations, to_mjcf


def floats(text):
    return np.array([float(x) for x in text.split()])


@pytest.fixture(scope="module")
def humanoid():
    return characters.humanoid(dtype=jnp.float64)


@pytest.fixture(scope="module")
def humanoid_xml(humanoid):
    return ET.fromstring(to_mjcf(humanoid, name="humanoid"))


def test_humanoid_structure(humanoid_xml):
    root = humanoid_xml
    assert root.tag == "mujoco" and root.get("model") == "humanoid"
    bodies = root.findall(".//worldbody//body")
    assert len(bodies) == 15
    joints = root.findall(".//joint")
    assert sum(j.get("type") == "ball" for j in joints) == 8
    assert sum(j.get("type") == "hinge" for j in joints) == 4
    assert len(joints) == 12
    assert len(root.findall(".//freejoint")) == 1
    # The free joint belongs to the root body, the only child of the world.
    world_children = root.find("worldbody").findall("body")
    assert [b.get("name") for b in world_children] == ["root"]
    assert world_children[0].find("freejoint") is not None
    # The wrists are welded: bodies without a joint.
    for wrist in ("right_wrist", "left_wrist"):
        body = root.find(f".//body[@name='{wrist}']")
        assert body.find("joint") is None and body.find("freejoint") is None
    # Gravity points down Y.
    np.testing.assert_allclose(floats(root.find("option").get("gravity")), [0, -9.81, 0])


def test_humanoid_masses_and_inertias(humanoid, humanoid_xml):
    inertials = {b.get("name"): b.find("inertial") for b in humanoid_xml.iter("body")}
    assert sum(float(i.get("mass")) for i in inertials.values()) == pytest.approx(45.0, rel=1e-9)
    for k, name in enumerate(humanoid.topology.names):
        inertial = inertials[name]
        assert float(inertial.get("mass")) == pytest.approx(float(humanoid.mass[k]), rel=1e-9)
        np.testing.assert_allclose(floats(inertial.get("pos")), humanoid.com[k], atol=1e-9)
        i = np.asarray(humanoid.inertia[k])
        np.testing.assert_allclose(
            floats(inertial.get("fullinertia")),
            [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]], rtol=1e-8, atol=1e-12)


def test_humanoid_joint_placement_and_limits(humanoid, humanoid_xml):
    topo = humanoid.topology
    for k, name in enumerate(topo.names):
        body = humanoid_xml.find(f".//body[@name='{name}']")
        if k > 0:
            np.testing.assert_allclose(floats(body.get("pos")), humanoid.joint_pos[k], atol=1e-9)
            parent = humanoid_xml.find(f".//body[@name='{name}']/..")
            assert parent.get("name") == topo.names[topo.parents[k]]
        if topo.joint_types[k] == "revolute":
            hinge = body.find("joint")
            assert hinge.get("name") == name
            np.testing.assert_allclose(floats(hinge.get("axis")), humanoid.joint_axis[k])
            dof = topo.dof_offsets[k]
            np.testing.assert_allclose(floats(hinge.get("range")),
                                       [humanoid.q_lower[dof], humanoid.q_upper[dof]])
    knee = humanoid_xml.find(".//body[@name='right_knee']/joint")
    np.testing.assert_allclose(floats(knee.get("range")), [-3.14, 0.0])


def test_humanoid_geoms(humanoid_xml):
    geoms = [g for g in humanoid_xml.iter("geom") if g.get("name") != "ground"]
    kinds = sorted(g.get("type") for g in geoms)
    assert kinds == sorted(["sphere"] * 5 + ["capsule"] * 8 + ["box"] * 2)
    # The right thigh's capsule: diameter 0.11, cylinder length 0.3, centred 0.21 below the hip.
    thigh = humanoid_xml.find(".//body[@name='right_hip']/geom")
    assert thigh.get("type") == "capsule"
    assert float(thigh.get("size")) == pytest.approx(0.055)
    np.testing.assert_allclose(floats(thigh.get("fromto")), [0, -0.36, 0, 0, -0.06, 0],
                               atol=1e-9)
    foot = humanoid_xml.find(".//body[@name='left_ankle']/geom")
    np.testing.assert_allclose(floats(foot.get("size")), [0.0885, 0.0275, 0.045], atol=1e-9)
    # The ground plane's normal (its local Z) is world +Y.
    ground = humanoid_xml.find(".//geom[@name='ground']")
    normal = np.asarray(rotations.quat_to_matrix(jnp.asarray(floats(ground.get("quat"))))) \
        @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(normal, [0, 1, 0], atol=1e-8)


def test_snake_63_export():
    root = ET.fromstring(to_mjcf(characters.snake(63)))
    assert len(root.findall(".//worldbody//body")) == 64
    assert len(root.findall(".//joint[@type='ball']")) == 63
    assert len(root.findall(".//freejoint")) == 1
    assert sum(float(i.get("mass")) for i in root.iter("inertial")) == pytest.approx(64.0)
    # A chain: each body nests inside the previous one.
    depth, body = 0, root.find("worldbody/body")
    while body is not None:
        depth += 1
        body = body.find("body")
    assert depth == 64


def test_fixed_base_export():
    links = [
        builder.LinkSpec(name="base", parent=None, joint="fixed", mass=1.0, shape="box",
                         shape_size=(0.1, 0.1, 0.1), joint_pos=(0.0, 1.5, 0.0)),
        builder.LinkSpec(name="arm", parent="base", joint="revolute", mass=2.0, shape="sphere",
                         shape_size=(0.05, 0, 0), shape_pos=(0.0, -0.5, 0.0), axis=(1.0, 0, 0)),
    ]
    root = ET.fromstring(to_mjcf(builder.build_model(links)))
    base = root.find("worldbody/body")
    assert base.get("name") == "base"
    np.testing.assert_allclose(floats(base.get("pos")), [0, 1.5, 0])
    assert base.find("joint") is None and base.find("freejoint") is None
    hinge = base.find("body/joint")
    assert hinge.get("type") == "hinge"
    np.testing.assert_allclose(floats(hinge.get("axis")), [1, 0, 0])
    assert hinge.get("range") is None        # unlimited


# ----------------------------------------------------------------------------------------------
# Load the export in MuJoCo (a test dependency) and compare the physics with an independent
# simulator.


def mujoco_mass_matrix(mj_model, mj_data):
    dense = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, mj_data, dense)
    return dense


@pytest.mark.parametrize("name", ["humanoid", "snake5", "quadruped"])
def test_mujoco_mass_matrix_and_positions_agree(name):
    """MuJoCo's CRBA on the exported model equals ours at a random pose. MuJoCo orders DoFs by
    its depth-first body order and its free joint's velocity is (world linear, body angular);
    ours is (body angular, body linear): map by joint name and by the root rotation."""
    model = {"humanoid": lambda: characters.humanoid(dtype=jnp.float64),
             "snake5": lambda: characters.snake(5, dtype=jnp.float64),
             "quadruped": lambda: characters.quadruped(dtype=jnp.float64)}[name]()
    topo = model.topology
    mj_model = mujoco.MjModel.from_xml_string(to_mjcf(model))
    mj_data = mujoco.MjData(mj_model)
    q, _, _ = random_state(model, 21)
    assert (mj_model.nq, mj_model.nv) == (model.nq, model.nv)

    # qd_ours = T qvel_mujoco
    transform = np.zeros((model.nv, model.nv))
    for i, link in enumerate(topo.names):
        if topo.joint_types[i] == "fixed":
            continue
        j = mj_model.joint(link).id
        qpos_adr, dof_adr = mj_model.jnt_qposadr[j], mj_model.jnt_dofadr[j]
        q_slice = slice(topo.q_offsets[i], topo.q_offsets[i + 1])
        mj_data.qpos[qpos_adr:qpos_adr + q_slice.stop - q_slice.start] = q[q_slice]
        ours = topo.dof_offsets[i]
        if topo.joint_types[i] == "free":
            rot = np.asarray(rotations.quat_to_matrix(q[3:7]))
            transform[ours + 3:ours + 6, dof_adr:dof_adr + 3] = rot.T      # linear
            transform[ours:ours + 3, dof_adr + 3:dof_adr + 6] = np.eye(3)  # angular
        else:
            for k in range(topo.dof_offsets[i + 1] - ours):
                transform[ours + k, dof_adr + k] = 1.0
    mujoco.mj_forward(mj_model, mj_data)

    ours = np.asarray(jax.jit(dynamics.mass_matrix)(model, q))
    expected = transform.T @ ours @ transform
    theirs = mujoco_mass_matrix(mj_model, mj_data)
    # The XML carries 9 significant digits.
    np.testing.assert_allclose(theirs, expected, atol=1e-8 * np.abs(expected).max())
    _, positions = jax.jit(kinematics.forward_kinematics)(model, q)
    for i, link in enumerate(topo.names):
        np.testing.assert_allclose(mj_data.xpos[mj_model.body(link).id], positions[i], atol=1e-8)
