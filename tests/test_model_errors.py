"""Bad model descriptions fail early with a ModelError naming the file, the joint/body and the
field (docs/design.md, "Errors a user can act on")."""

import copy
import json
import re

import numpy as np
import pytest

from jaxsim import ModelError, characters
from jaxsim.builder import LinkSpec, build_model


@pytest.fixture(scope="module")
def humanoid_json(data_dir):
    with open(data_dir / "deepmimic" / "characters" / "humanoid3d.txt") as f:
        return json.load(f)


@pytest.fixture(scope="module")
def controller_json(data_dir):
    with open(data_dir / "deepmimic" / "controllers" / "humanoid3d_ctrl.txt") as f:
        return json.load(f)


def joint(data, name):
    return next(j for j in data["Skeleton"]["Joints"] if j["Name"] == name)


def body(data, name):
    return next(b for b in data["BodyDefs"] if b["Name"] == name)


def write(tmp_path, data, name="character.txt"):
    path = tmp_path / name
    path.write_text(json.dumps(data, indent=1))
    return path


def load_error(path, controller=None) -> str:
    with pytest.raises(ModelError) as info:
        characters.load_deepmimic(path, controller)
    return str(info.value)


def assert_names(message, *parts):
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"


def test_unmodified_copy_loads(tmp_path, humanoid_json):
    """The mutations below start from a file that loads."""
    model = characters.load_deepmimic(write(tmp_path, humanoid_json))
    assert model.nv == 34


# ----------------------------------------------------------------------------------------------
# Malformed DeepMimic character files


def test_missing_body_mass(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    del body(data, "right_hip")["Mass"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'right_hip'", "'Mass'", "missing")


def test_missing_joint_parent(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    del joint(data, "left_knee")["Parent"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'left_knee'", "'Parent'", "missing")


def test_missing_joint_limit(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    del joint(data, "right_elbow")["LimHigh0"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'right_elbow'", "'LimHigh0'")


def test_unknown_joint_type(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    joint(data, "right_knee")["Type"] = "prismatic"
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'right_knee'", "'Type'", "'prismatic'")


def test_unknown_shape(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    body(data, "chest")["Shape"] = "cylinder"
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'chest'", "'Shape'", "'cylinder'")


def test_non_numeric_field(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    joint(data, "neck")["AttachY"] = "high"
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'neck'", "'AttachY'", "'high'")


def test_parent_listed_after_its_child(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    joints = data["Skeleton"]["Joints"]
    hip = next(i for i, j in enumerate(joints) if j["Name"] == "right_hip")
    knee = next(i for i, j in enumerate(joints) if j["Name"] == "right_knee")
    joints[hip], joints[knee] = joints[knee], joints[hip]
    path = write(tmp_path, data)
    message = load_error(path)
    assert_names(message, str(path), "'right_knee'", "'Parent'")
    assert "before" in message


@pytest.mark.parametrize("mass", [0, -1])
def test_non_positive_mass(tmp_path, humanoid_json, mass):
    data = copy.deepcopy(humanoid_json)
    body(data, "left_ankle")["Mass"] = mass
    path = write(tmp_path, data)
    message = load_error(path)
    assert_names(message, str(path), "'left_ankle'", "'Mass'", "positive")


def test_joint_without_body(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    data["BodyDefs"] = [b for b in data["BodyDefs"] if b["Name"] != "neck"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'neck'", "BodyDefs")


def test_missing_skeleton(tmp_path, humanoid_json):
    data = copy.deepcopy(humanoid_json)
    del data["Skeleton"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "Skeleton")


def test_invalid_json_names_the_line(tmp_path, humanoid_json):
    lines = json.dumps(humanoid_json, indent=1).splitlines()
    bad_line = 25
    lines[bad_line - 1] = lines[bad_line - 1].rstrip(",") + " oops,"
    path = tmp_path / "broken.txt"
    path.write_text("\n".join(lines))
    message = load_error(path)
    assert_names(message, str(path), "JSON")
    assert re.search(rf"\bline {bad_line}\b", message), message


def test_controller_without_a_joint(tmp_path, humanoid_json, controller_json):
    ctrl = copy.deepcopy(controller_json)
    ctrl["PDControllers"] = [c for c in ctrl["PDControllers"] if c["Name"] != "left_elbow"]
    path = write(tmp_path, humanoid_json)
    ctrl_path = write(tmp_path, ctrl, "controller.txt")
    assert_names(load_error(path, ctrl_path), str(ctrl_path), "'left_elbow'")


def test_controller_missing_gain(tmp_path, humanoid_json, controller_json):
    ctrl = copy.deepcopy(controller_json)
    del next(c for c in ctrl["PDControllers"] if c["Name"] == "chest")["Kd"]
    path = write(tmp_path, humanoid_json)
    ctrl_path = write(tmp_path, ctrl, "controller.txt")
    assert_names(load_error(path, ctrl_path), str(ctrl_path), "chest", "'Kd'")


# Regression tests for errors that once escaped without naming the file's joint and key.


def test_joints_that_are_not_a_list(tmp_path, humanoid_json):
    """`"Joints": 5` gives a ModelError naming the field (it once escaped as a bare TypeError,
    'int' object is not iterable)."""
    data = copy.deepcopy(humanoid_json)
    data["Skeleton"]["Joints"] = 5
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "Joints")


def test_duplicate_joint_id(tmp_path, humanoid_json):
    """A duplicated joint ID is refused. It was once accepted silently, and the second joint
    took the first one's body (here left_wrist got right_wrist's BodyDefs entry)."""
    data = copy.deepcopy(humanoid_json)
    joint(data, "left_wrist")["ID"] = joint(data, "right_wrist")["ID"]
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), "'left_wrist'", "'ID'")


@pytest.mark.parametrize("where, name, key, value", [
    ("joint", "right_knee", "Type", "none"),          # a second free root
    ("joint", "root", "Type", "spherical"),           # a root that is not free/fixed
    ("body", "right_hip", "Param0", 0.0),             # a capsule of zero diameter
    ("joint", "neck", "AttachY", float("inf")),       # JSON's Infinity
])
def test_errors_name_the_files_field(tmp_path, humanoid_json, where, name, key, value):
    """The loader catches these itself, so the message names the file's key ('Type', 'Param0',
    'AttachY') and joint/body rather than the builder's field ('joint', 'shape_size',
    'joint_pos') and link."""
    data = copy.deepcopy(humanoid_json)
    (joint if where == "joint" else body)(data, name)[key] = value
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), f"'{name}'", f"'{key}'")


@pytest.mark.parametrize("name, key, value", [
    ("right_knee", "TorqueLim", -150),
    ("right_knee", "TorqueLim", float("nan")),
    ("left_elbow", "LimLow0", float("nan")),
    ("neck", "LimHigh2", float("nan")),
])
def test_bad_joint_limits_name_the_files_key(tmp_path, humanoid_json, name, key, value):
    data = copy.deepcopy(humanoid_json)
    joint(data, name)[key] = value
    path = write(tmp_path, data)
    assert_names(load_error(path), str(path), f"'{name}'", f"'{key}'")


@pytest.mark.parametrize("key, value", [("Kp", -1000), ("Kd", float("nan"))])
def test_bad_controller_gain_names_the_key(tmp_path, humanoid_json, controller_json, key,
                                           value):
    ctrl = copy.deepcopy(controller_json)
    next(c for c in ctrl["PDControllers"] if c["Name"] == "chest")[key] = value
    path = write(tmp_path, humanoid_json)
    ctrl_path = write(tmp_path, ctrl, "controller.txt")
    assert_names(load_error(path, ctrl_path), str(ctrl_path), "chest", f"'{key}'")


def test_deepmimic_conventions_for_no_limit(tmp_path, humanoid_json):
    """TorqueLim 0 means no torque limit, and LimLow > LimHigh no limit on that DoF (what
    DeepMimic writes for joints without limits)."""
    data = copy.deepcopy(humanoid_json)
    joint(data, "right_knee")["TorqueLim"] = 0
    joint(data, "neck")["LimLow1"], joint(data, "neck")["LimHigh1"] = 1, 0
    model = characters.load_deepmimic(write(tmp_path, data))
    topo = model.topology
    knee = topo.dof_offsets[topo.link_index("right_knee")]
    neck = topo.dof_offsets[topo.link_index("neck")] + np.arange(3)
    assert float(model.torque_limit[knee]) == np.inf
    np.testing.assert_array_equal(model.q_lower[neck], [-1, -np.inf, -1])
    np.testing.assert_array_equal(model.q_upper[neck], [1, np.inf, 1])


# ----------------------------------------------------------------------------------------------
# Builder-level errors


def link(name, parent, joint_type="spherical", **kwargs):
    kwargs.setdefault("shape", "sphere")
    kwargs.setdefault("shape_size", (0.1, 0.0, 0.0))
    return LinkSpec(name=name, parent=parent, joint=joint_type, mass=kwargs.pop("mass", 1.0),
                    **kwargs)


def build_error(links) -> str:
    with pytest.raises(ModelError) as info:
        build_model(links, source="my_robot.py")
    return str(info.value)


def test_builder_accepts_the_valid_chain():
    model = build_model([link("base", None, "free"), link("arm", "base"),
                         link("hand", "arm", "revolute", axis=(1.0, 0.0, 0.0))])
    assert model.nv == 6 + 3 + 1


def test_builder_duplicate_name():
    message = build_error([link("base", None, "free"), link("arm", "base"), link("arm", "base")])
    assert_names(message, "my_robot.py", "'arm'", "duplicate")


def test_builder_root_with_parent():
    message = build_error([link("base", "world", "free"), link("arm", "base")])
    assert_names(message, "my_robot.py", "'base'", "parent")


def test_builder_root_joint_type():
    message = build_error([link("base", None, "revolute")])
    assert_names(message, "my_robot.py", "'base'", "'joint'", "'revolute'")


def test_builder_free_joint_below_the_root():
    message = build_error([link("base", None, "free"), link("arm", "base", "free")])
    assert_names(message, "my_robot.py", "'arm'", "'joint'")


@pytest.mark.parametrize("axis", [(0.0, 0.0, 2.0), (0.0, 0.0, 0.0), (0.6, 0.6, 0.0)])
def test_builder_non_unit_revolute_axis(axis):
    message = build_error([link("base", None, "free"),
                           link("elbow", "base", "revolute", axis=axis)])
    assert_names(message, "my_robot.py", "'elbow'", "'axis'", "unit")


def test_builder_unknown_parent():
    message = build_error([link("base", None, "free"), link("arm", "base"),
                           link("hand", "forearm")])
    assert_names(message, "my_robot.py", "'hand'", "'parent'", "'forearm'")


def test_builder_parent_after_child():
    message = build_error([link("base", None, "free"), link("hand", "arm"), link("arm", "base")])
    assert_names(message, "my_robot.py", "'hand'", "'parent'", "'arm'", "after")


def test_builder_non_positive_mass():
    for mass in (0.0, -2.0, float("nan")):
        message = build_error([link("base", None, "free"), link("arm", "base", mass=mass)])
        assert_names(message, "my_robot.py", "'arm'", "'mass'")


def test_builder_wrong_number_of_per_dof_values():
    message = build_error([link("base", None, "free"), link("arm", "base", kp=[1.0, 2.0])])
    assert_names(message, "my_robot.py", "'arm'", "'kp'")


def test_builder_bad_inertia():
    message = build_error([link("base", None, "free", shape="none",
                                inertia=np.diag([1.0, -1.0, 1.0]))])
    assert_names(message, "my_robot.py", "'base'", "'inertia'")


@pytest.mark.parametrize("field, value", [
    ("kp", -1.0), ("kp", float("nan")), ("kp", float("inf")), ("kd", [5.0, -0.1, 5.0]),
    ("kd", float("nan")), ("torque_limit", 0.0), ("torque_limit", -10.0),
    ("torque_limit", float("nan")), ("q_lower", float("nan")), ("q_upper", float("nan")),
    ("q_lower", float("inf")), ("q_upper", -float("inf")),
])
def test_builder_bad_gains_and_limits(field, value):
    message = build_error([link("base", None, "free"), link("arm", "base", **{field: value})])
    assert_names(message, "my_robot.py", "'arm'", f"'{field}'")


def test_builder_lower_limit_above_upper():
    message = build_error([link("base", None, "free"),
                           link("arm", "base", q_lower=[-1.0, 0.5, -1.0], q_upper=0.2)])
    assert_names(message, "my_robot.py", "'arm'", "'q_lower'", "'q_upper'", "0.5", "0.2")


@pytest.mark.parametrize("field, value", [("q_lower", -1.0), ("q_upper", 1.0),
                                          ("torque_limit", 200.0)])
def test_builder_free_root_with_limits(field, value):
    """A free root's coordinates are its world pose: a limit would tie it to the origin."""
    message = build_error([link("base", None, "free", **{field: value}), link("arm", "base")])
    assert_names(message, "my_robot.py", "'base'", f"'{field}'", "free")


REFLECTION = np.diag([1.0, 1.0, -1.0])


@pytest.mark.parametrize("field", ["joint_rot", "shape_rot"])
def test_builder_rejects_reflections(field):
    message = build_error([link("base", None, "free"), link("arm", "base", **{field: REFLECTION})])
    assert_names(message, "my_robot.py", "'arm'", f"'{field}'")


def test_link_index_of_unknown_name_lists_the_known_names():
    topo = characters.humanoid().topology
    assert topo.link_index("left_knee") == 10
    with pytest.raises(ModelError) as info:
        topo.link_index("tail")
    message = str(info.value)
    assert "'tail'" in message
    for name in topo.names:
        assert name in message
