"""Characters: the built-in humanoid, quadruped and snakes, DeepMimic's files, shape inertias."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from jaxsim import characters, kinematics, limits
from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.humanoid import SEGMENTS
from jaxsim.model import rest_pose
from jaxsim.world import make_world

HUMANOID_JOINTS = {
    "root": "free", "chest": "spherical", "neck": "spherical",
    "right_hip": "spherical", "right_knee": "revolute", "right_ankle": "spherical",
    "right_shoulder": "spherical", "right_elbow": "revolute", "right_wrist": "fixed",
    "left_hip": "spherical", "left_knee": "revolute", "left_ankle": "spherical",
    "left_shoulder": "spherical", "left_elbow": "revolute", "left_wrist": "fixed",
}
# Every array of a Model (the topology is compared separately).
MODEL_ARRAYS = ("joint_pos", "joint_rot", "joint_axis", "mass", "com", "inertia", "shape_pos",
                "shape_rot", "shape_size", "kp", "kd", "torque_limit", "q_lower", "q_upper")


def deepmimic_file(data_dir, name):
    return data_dir / "deepmimic" / "characters" / name


def controller_file(data_dir, name):
    return data_dir / "deepmimic" / "controllers" / name


def standing_height(model):
    low, high = characters.vertical_extent(model)
    return high - low


# ----------------------------------------------------------------------------------------------
# The built-in humanoid


def test_humanoid_structure():
    model = characters.humanoid()
    topo = model.topology
    assert model.n_links == 15
    assert (model.nq, model.nv) == (43, 34)
    assert dict(zip(topo.names, topo.joint_types)) == HUMANOID_JOINTS
    assert topo.floating
    assert float(jnp.sum(model.mass)) == pytest.approx(45.0, rel=1e-6)
    # Parents come before children, and the limbs hang where DeepMimic puts them.
    assert all(p < i for i, p in enumerate(topo.parents))
    parent_name = {n: (topo.names[p] if p >= 0 else None) for n, p in zip(topo.names, topo.parents)}
    assert parent_name["right_knee"] == "right_hip"
    assert parent_name["left_shoulder"] == "chest"
    assert parent_name["right_wrist"] == "right_elbow"
    # Each joint type gets its number of DoF: 6 + 8·3 + 4·1 + 2·0.
    dofs = np.diff(topo.dof_offsets)
    assert dofs.tolist() == [{"free": 6, "spherical": 3, "revolute": 1, "fixed": 0}[t]
                             for t in topo.joint_types]


def test_reference_humanoid_height_from_deepmimic_body_dimensions(data_dir):
    """The reference humanoid stands as tall as DeepMimic's character file makes it: from the
    sole of the foot box to the top of the head sphere, summing the file's vertical offsets."""
    data = json.loads(deepmimic_file(data_dir, "humanoid3d.txt").read_text())
    joints = {j["Name"]: j for j in data["Skeleton"]["Joints"]}
    bodies = {b["Name"]: b for b in data["BodyDefs"]}
    for name in ("root", "chest", "neck", "right_hip", "right_knee", "right_ankle"):
        assert [joints[name][f"AttachTheta{a}"] for a in "XYZ"] == [0, 0, 0]
        assert [bodies[name][f"AttachTheta{a}"] for a in "XYZ"] == [0, 0, 0]
    head_top = (joints["chest"]["AttachY"] + joints["neck"]["AttachY"]
                + bodies["neck"]["AttachY"] + bodies["neck"]["Param0"] / 2)
    sole = (joints["right_hip"]["AttachY"] + joints["right_knee"]["AttachY"]
            + joints["right_ankle"]["AttachY"] + bodies["right_ankle"]["AttachY"]
            - bodies["right_ankle"]["Param1"] / 2)
    assert head_top - sole == pytest.approx(1.618961, abs=1e-6)
    assert standing_height(characters.humanoid(dtype=jnp.float64)) == pytest.approx(
        head_top - sole, abs=1e-9)


def test_humanoid_resized_to_height_and_mass():
    reference = characters.humanoid()
    model = characters.humanoid(height=1.70, mass=60)
    assert float(jnp.sum(model.mass)) == pytest.approx(60.0, rel=1e-6)
    assert abs(standing_height(model) - 1.70) < 1e-6
    assert abs(standing_height(reference) - 1.70) > 0.05       # the reference is shorter
    # Masses scale uniformly, lengths uniformly, and inertias as mass × length².
    mass_ratio, length_ratio = 60.0 / 45.0, 1.70 / standing_height(reference)
    np.testing.assert_allclose(model.mass, reference.mass * mass_ratio, rtol=1e-6)
    np.testing.assert_allclose(model.joint_pos, reference.joint_pos * length_ratio, rtol=1e-5,
                               atol=1e-7)
    np.testing.assert_allclose(model.inertia, reference.inertia * mass_ratio * length_ratio**2,
                               rtol=1e-5, atol=1e-9)


def test_humanoid_longer_thighs():
    reference = characters.humanoid(dtype=jnp.float64)
    model = characters.humanoid(segment_scales={"thigh": 1.2}, dtype=jnp.float64)
    topo = model.topology
    _, pos_ref = kinematics.forward_kinematics(reference, rest_pose(reference))
    _, pos = kinematics.forward_kinematics(model, rest_pose(model))
    for side in ("right", "left"):
        hip, knee, ankle = (topo.link_index(f"{side}_{j}") for j in ("hip", "knee", "ankle"))
        thigh_ref = np.linalg.norm(pos_ref[knee] - pos_ref[hip])
        thigh = np.linalg.norm(pos[knee] - pos[hip])
        assert thigh_ref == pytest.approx(0.421546, rel=1e-12)
        assert thigh == pytest.approx(1.2 * thigh_ref, rel=1e-12)
        # The shin keeps its length; the thigh's capsule is longer, not fatter.
        assert np.linalg.norm(pos[ankle] - pos[knee]) == pytest.approx(0.40987, rel=1e-12)
        assert model.shape_size[hip, 1] == pytest.approx(1.2 * reference.shape_size[hip, 1])
        assert model.shape_size[hip, 0] == reference.shape_size[hip, 0]
    # The feet reach 0.2 × 0.421546 lower; the top of the head stays where it was.
    low_ref, high_ref = characters.vertical_extent(reference)
    low, high = characters.vertical_extent(model)
    assert low == pytest.approx(low_ref - 0.2 * 0.421546, abs=1e-12)
    assert high == pytest.approx(high_ref, abs=1e-12)
    # Nothing above the hips changed.
    for name in ("chest", "neck", "right_shoulder", "left_elbow"):
        i = topo.link_index(name)
        np.testing.assert_array_equal(model.joint_pos[i], reference.joint_pos[i])
        np.testing.assert_array_equal(model.inertia[i], reference.inertia[i])


def test_humanoid_resized_with_longer_thighs_keeps_the_requested_height():
    model = characters.humanoid(height=1.70, mass=60, segment_scales={"thigh": 1.2})
    assert abs(standing_height(model) - 1.70) < 1e-6
    assert float(jnp.sum(model.mass)) == pytest.approx(60.0, rel=1e-6)
    knee = model.topology.link_index("right_knee")
    ankle = model.topology.link_index("right_ankle")
    # The thigh is 1.2× the shin's proportion of the reference.
    ratio = float(jnp.linalg.norm(model.joint_pos[knee]) / jnp.linalg.norm(model.joint_pos[ankle]))
    assert ratio == pytest.approx(1.2 * 0.421546 / 0.40987, rel=1e-6)


@pytest.mark.parametrize("segment", sorted(SEGMENTS))
def test_every_segment_scale_changes_the_body(segment):
    """Every key that `segment_scales` accepts changes the character's geometry.

    A regression test: {"hand": s} once had no effect, because the wrist is a childless sphere
    at its joint and only capsule lengths, shape positions and child joints were scaled.
    """
    reference = characters.humanoid(dtype=jnp.float64)
    model = characters.humanoid(segment_scales={segment: 1.5}, dtype=jnp.float64)
    changed = [field for field in ("joint_pos", "shape_pos", "shape_size")
               if not np.array_equal(getattr(model, field), getattr(reference, field))]
    assert changed, f"segment_scales={{{segment!r}: 1.5}} left the humanoid unchanged"


def test_humanoid_rejects_unknown_segments_and_bad_scales():
    with pytest.raises(ValueError, match="wing"):
        characters.humanoid(segment_scales={"wing": 1.1})
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="thigh"):
            characters.humanoid(segment_scales={"thigh": bad})
    with pytest.raises(ValueError):
        characters.humanoid(height=-1.0)
    with pytest.raises(ValueError):
        characters.humanoid(mass=0.0)


# ----------------------------------------------------------------------------------------------
# Quadruped and snakes


def test_quadruped():
    model = characters.quadruped()
    assert model.nv == 72
    assert model.n_links == 23
    assert model.topology.max_path_dofs == 24
    assert model.topology.floating
    assert set(model.topology.joint_types[1:]) == {"spherical"}


@pytest.mark.parametrize("n_links, nv", [(10, 36), (22, 72), (63, 195)])
def test_snake_dof(n_links, nv):
    model = characters.snake(n_links)
    assert model.nv == nv
    assert model.n_links == n_links + 1
    assert model.nq == 7 + 4 * n_links
    # A chain: the deepest path holds every DoF.
    assert model.topology.max_path_dofs == nv
    assert model.topology.parents == tuple(range(-1, n_links))


def test_snake_far_from_the_origin_feels_no_joint_limit_on_its_root():
    """The segments' limits stay on the segments: the free head's coordinates are its world
    pose, so a snake 5 m from the origin must not be pulled back towards it."""
    model = characters.snake(3, dtype=jnp.float64)
    q = rest_pose(model).at[0].set(5.0)
    spring, damper = limits.joint_limit_forces(model, make_world(dtype=jnp.float64), q,
                                             jnp.zeros(model.nv))
    np.testing.assert_array_equal(spring, np.zeros(model.nv))
    np.testing.assert_array_equal(damper, np.zeros(model.nv))
    assert np.all(np.isinf(np.asarray(model.q_lower[:6])))
    assert np.all(np.isinf(np.asarray(model.torque_limit[:6])))
    np.testing.assert_array_equal(model.q_upper[6:], np.ones(model.nv - 6))
    np.testing.assert_array_equal(model.torque_limit[6:], np.full(model.nv - 6, 200.0))


def test_snake_needs_a_link():
    with pytest.raises(ValueError, match="n_links"):
        characters.snake(0)


# ----------------------------------------------------------------------------------------------
# DeepMimic files


def test_deepmimic_humanoid_matches_the_builtin(data_dir):
    loaded = characters.load_deepmimic(deepmimic_file(data_dir, "humanoid3d.txt"),
                                       controller_file(data_dir, "humanoid3d_ctrl.txt"),
                                       dtype=jnp.float64)
    builtin = characters.humanoid(dtype=jnp.float64)
    assert (loaded.nq, loaded.nv) == (43, 34)
    assert float(jnp.sum(loaded.mass)) == pytest.approx(45.0, rel=1e-12)
    assert loaded.topology == builtin.topology
    for field in MODEL_ARRAYS:
        a, b = np.asarray(getattr(loaded, field)), np.asarray(getattr(builtin, field))
        assert a.shape == b.shape, field
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15, err_msg=field)


def test_deepmimic_humanoid_without_controller_has_zero_gains(data_dir):
    model = characters.load_deepmimic(deepmimic_file(data_dir, "humanoid3d.txt"))
    assert (model.nq, model.nv) == (43, 34)
    assert float(jnp.sum(model.mass)) == pytest.approx(45.0, rel=1e-6)
    assert not np.any(np.asarray(model.kp)) and not np.any(np.asarray(model.kd))


def test_deepmimic_controller_gains(data_dir):
    model = characters.load_deepmimic(deepmimic_file(data_dir, "humanoid3d.txt"),
                                      controller_file(data_dir, "humanoid3d_ctrl.txt"))
    topo = model.topology
    chest = topo.link_index("chest")
    dofs = slice(topo.dof_offsets[chest], topo.dof_offsets[chest + 1])
    np.testing.assert_array_equal(model.kp[dofs], [1000.0] * 3)
    np.testing.assert_array_equal(model.kd[dofs], [100.0] * 3)
    knee = topo.link_index("right_knee")
    assert float(model.kp[topo.dof_offsets[knee]]) == 500.0
    assert float(model.kd[topo.dof_offsets[knee]]) == 50.0
    np.testing.assert_array_equal(model.kp[:6], np.zeros(6))    # the root is unactuated


def test_deepmimic_dog(data_dir):
    model = characters.load_deepmimic(deepmimic_file(data_dir, "dog3d.txt"),
                                      controller_file(data_dir, "dog3d_ctrl.txt"))
    assert model.n_links == 23
    assert model.nv == 64
    assert model.nq == 83           # the dog's DeepMimic pose has 83 numbers
    assert model.topology.floating
    assert np.all(np.asarray(model.mass) > 0)
    assert np.all(np.asarray(model.kp[6:]) > 0)
    # The file gives the spherical joints LimLow 1 > LimHigh 0, DeepMimic's mark of a joint
    # without limits; the revolute legs keep theirs.
    topo = model.topology
    shoulder = topo.dof_offsets[topo.link_index("left_shoulder")] + np.arange(3)
    np.testing.assert_array_equal(model.q_lower[shoulder], np.full(3, -np.inf))
    np.testing.assert_array_equal(model.q_upper[shoulder], np.full(3, np.inf))
    knee = topo.dof_offsets[topo.link_index("left_leg")]
    assert float(model.q_lower[knee]) == pytest.approx(-3.14)
    assert float(model.q_upper[knee]) == 0.0


# ----------------------------------------------------------------------------------------------
# Inertias computed from shapes, against independent computations


def single_link(shape, half_size, mass, shape_pos=(0.0, 0.0, 0.0), shape_rot=None):
    link = LinkSpec(name="body", parent=None, joint="free", mass=mass, shape=shape,
                    shape_size=half_size, shape_pos=shape_pos, shape_rot=shape_rot)
    return build_model([link], source="test", dtype=jnp.float64)


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def inside(shape, half_size, points):
    """Membership of points (in the shape's frame) in the solid."""
    r = half_size[0]
    if shape == "sphere":
        return np.sum(points**2, -1) <= r * r
    if shape == "box":
        return np.all(np.abs(points) <= np.asarray(half_size), -1)
    h = half_size[1]                     # capsule: segment from -h to +h along Y, radius r
    nearest = np.clip(points[:, 1], -h, h)
    return points[:, 0]**2 + (points[:, 1] - nearest)**2 + points[:, 2]**2 <= r * r


def monte_carlo_inertia(shape, half_size, mass, rot, offset, samples=1_000_000, seed=0):
    """Centre of mass and inertia about it, in the link frame, from uniform samples."""
    r = half_size[0]
    bound = np.array({"sphere": (r, r, r), "box": tuple(half_size),
                      "capsule": (r, half_size[1] + r, r)}[shape])
    rng = np.random.default_rng(seed)
    points = rng.uniform(-bound, bound, size=(samples, 3))
    points = points[inside(shape, half_size, points)] @ rot.T + offset
    com = points.mean(0)
    d = points - com
    inertia = mass * (np.eye(3) * np.mean(np.sum(d * d, -1)) - d.T @ d / len(d))
    return com, inertia


def test_sphere_inertia_closed_form():
    m, r = 3.0, 0.13
    model = single_link("sphere", (r, 0, 0), m)
    np.testing.assert_allclose(model.inertia[0], np.eye(3) * 2.0 / 5.0 * m * r * r, rtol=1e-12)
    np.testing.assert_allclose(model.com[0], 0.0, atol=0)


def test_box_inertia_closed_form():
    m, full = 2.5, np.array([0.2, 0.4, 0.7])           # full edge lengths a, b, c
    model = single_link("box", full / 2, m)
    a, b, c = full
    expected = m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(model.inertia[0], expected, rtol=1e-12)


def test_capsule_inertia_by_numerical_integration():
    """Integrate the capsule (radius r, cylinder half-length h along Y) slice by slice: each
    slice y is a disc of radius ρ(y), with area πρ², polar moment πρ⁴/2 and diametral πρ⁴/4."""
    m, r, h = 4.5, 0.055, 0.15
    model = single_link("capsule", (r, h, 0), m)

    def rho2(y):
        y = abs(y)
        return r * r if y <= h else max(r * r - (y - h) ** 2, 0.0)

    def integral(f):
        value, _ = integrate.quad(f, -(h + r), h + r, points=[-h, h], epsabs=0, epsrel=1e-13,
                                  limit=200)
        return value

    volume = integral(lambda y: math.pi * rho2(y))
    assert volume == pytest.approx(math.pi * r * r * 2 * h + 4 / 3 * math.pi * r**3, rel=1e-12)
    density = m / volume
    axial = density * integral(lambda y: math.pi * rho2(y) ** 2 / 2)
    transverse = density * integral(
        lambda y: math.pi * rho2(y) ** 2 / 4 + math.pi * rho2(y) * y * y)
    np.testing.assert_allclose(model.inertia[0], np.diag([transverse, axial, transverse]),
                               rtol=1e-10)


@pytest.mark.parametrize("shape, half_size", [
    ("sphere", (0.1, 0.0, 0.0)),
    ("box", (0.09, 0.03, 0.15)),
    ("capsule", (0.05, 0.12, 0.0)),
    ("capsule", (0.08, 0.02, 0.0)),
])
def test_rotated_offset_shape_inertia_by_monte_carlo(shape, half_size):
    """The link's centre of mass and inertia for a shape placed off-centre and rotated in the
    link, against samples of the solid (statistical error ≈ 0.2 %, so a 1.5 % tolerance)."""
    m, offset = 1.7, np.array([0.03, -0.2, 0.05])
    rot = rotation((1.0, 2.0, -0.5), 0.9)
    model = single_link(shape, half_size, m, shape_pos=offset, shape_rot=rot)
    com, inertia = monte_carlo_inertia(shape, half_size, m, rot, offset)
    np.testing.assert_allclose(model.com[0], offset, rtol=0, atol=1e-15)
    np.testing.assert_allclose(com, offset, atol=5e-3 * max(half_size))
    scale = float(np.abs(inertia).max())
    np.testing.assert_allclose(model.inertia[0], inertia, rtol=0, atol=0.015 * scale)
    # The mass is the link's, whatever the shape's volume.
    assert float(model.mass[0]) == m
