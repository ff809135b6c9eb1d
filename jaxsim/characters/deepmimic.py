"""Reading DeepMimic's JSON character files (and their PD controller files).

Format (see the data README): `Skeleton.Joints[]` with ID, Name, Type (none = free root,
spherical, revolute, fixed), Parent, AttachX/Y/Z and AttachThetaX/Y/Z (joint frame in the parent),
LimLow0-2/LimHigh0-2, TorqueLim; `BodyDefs[]` with Shape, Mass, Attach* (body frame in the joint
frame) and Param0-2 (sphere: diameter; capsule: diameter and cylinder length along Y; box: full
extents). Revolute joints turn about their local Z axis. Controller files list `PDControllers[]`
with Name, Kp and Kd per joint.

DeepMimic's conventions for "no limit" become the builder's (see `LinkSpec`): TorqueLim 0, or no
TorqueLim field (DeepMimic's default is 0; the thesis's 60 kg jumper leaves it out on its hips,
ankles and shoulders), is no torque limit (np.inf), and a DoF with LimLow > LimHigh has no position limit (∓np.inf). The
root's limits and torque limit are not read: a free root takes none.
"""

import json
import os

import numpy as np

from jaxsim import rotations
from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.common import half_sizes
from jaxsim.files import read_text
from jaxsim.model import ModelError

_JOINT_TYPES = {"none": "free", "spherical": "spherical", "revolute": "revolute",
                "fixed": "fixed"}
_LIMIT_SLOTS = {"free": 0, "spherical": 3, "revolute": 1, "fixed": 0}


def _read_json(path):
    try:
        return json.loads(read_text(path, ModelError))
    except json.JSONDecodeError as e:
        raise ModelError(f"{path}: not valid JSON at line {e.lineno}, column {e.colno}: {e.msg}")


def _field(record, key, where, kind=float):
    if key not in record:
        raise ModelError(f"{where}: missing field {key!r}")
    try:
        return kind(record[key])
    except (TypeError, ValueError):
        raise ModelError(f"{where}: field {key!r} has a bad value {record[key]!r}")


def _vec(record, prefix, where):
    return np.array([_finite(record, prefix + axis, where) for axis in "XYZ"])


def _shape_size(shape, body, where):
    used = {"sphere": 1, "capsule": 2, "box": 3}
    if shape not in used:
        raise ModelError(f"{where}: field 'Shape' must be sphere, capsule or box, got {shape!r}")
    p = [_field(body, f"Param{k}", where) for k in range(3)]
    for k in range(used[shape]):
        if not (np.isfinite(p[k]) and p[k] > 0):
            raise ModelError(f"{where}: field 'Param{k}' must be positive for a {shape}, "
                             f"got {p[k]}")
    return half_sizes(shape, p)


def _checked(record, key, where, accepts, requirement):
    """A number field that must pass `accepts` (named in the error by `requirement`)."""
    value = _field(record, key, where)
    if not accepts(value):
        raise ModelError(f"{where}: field {key!r} must be {requirement}, got {value}")
    return value


def _finite(record, key, where):
    return _checked(record, key, where, np.isfinite, "finite")


def _gain(record, key, where):
    return _checked(record, key, where, lambda v: np.isfinite(v) and v >= 0,
                    "finite and non-negative")


def _limits(joint, n_dof, where):
    """Per-DoF (lower, upper) position limits. DeepMimic marks a DoF without limits by
    LimLow > LimHigh (its default is 1 > 0); such a DoF gets −inf and inf."""
    if n_dof == 0:
        return -np.inf, np.inf
    low, high = (np.array([_finite(joint, f"{side}{i}", where) for i in range(n_dof)])
                 for side in ("LimLow", "LimHigh"))
    unlimited = low > high
    return np.where(unlimited, -np.inf, low), np.where(unlimited, np.inf, high)


def _torque_limit(joint, where):
    """TorqueLim, where 0 (what DeepMimic writes for the unactuated root) or no such field
    means no limit."""
    if "TorqueLim" not in joint:
        return np.inf
    limit = _checked(joint, "TorqueLim", where, lambda v: v >= 0,
                     "non-negative (0 for no limit)")
    return limit if limit > 0 else np.inf


def _read_gains(path):
    data = _read_json(path)
    if "PDControllers" not in data:
        raise ModelError(f"{path}: missing field 'PDControllers'")
    gains = {}
    for k, ctrl in enumerate(data["PDControllers"]):
        where = f"{path}: PDControllers[{k}]"
        name = _field(ctrl, "Name", where, str)
        gains[name] = (_gain(ctrl, "Kp", f"{where} ({name})"),
                       _gain(ctrl, "Kd", f"{where} ({name})"))
    return gains


def load_deepmimic(path, controller=None, dtype=None):
    """Build a `Model` from a DeepMimic character file, with gains from `controller` if given."""
    path = os.fspath(path)
    data = _read_json(path)
    try:
        joints = data["Skeleton"]["Joints"]
    except (KeyError, TypeError):
        raise ModelError(f"{path}: missing field 'Skeleton.Joints'")
    for key, value in (("Skeleton.Joints", joints), ("BodyDefs", data.get("BodyDefs"))):
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise ModelError(f"{path}: field {key!r} must be a list of objects")
    bodies = {}
    for k, body in enumerate(data["BodyDefs"]):
        body_id = _field(body, "ID", f"{path}: BodyDefs[{k}]", int)
        if body_id in bodies:
            raise ModelError(f"{path}: BodyDefs[{k}]: duplicate body ID {body_id}")
        bodies[body_id] = body
    gains = _read_gains(controller) if controller is not None else {}

    links, names_by_id = [], {}
    for k, joint in enumerate(joints):
        name = _field(joint, "Name", f"{path}: Joints[{k}]", str)
        where = f"{path}: joint {name!r}"
        joint_id = _field(joint, "ID", where, int)
        kind = _field(joint, "Type", where, str)
        if kind not in _JOINT_TYPES:
            raise ModelError(f"{where}: field 'Type' must be one of {', '.join(_JOINT_TYPES)}, "
                             f"got {kind!r}")
        kind = _JOINT_TYPES[kind]
        if joint_id in names_by_id:
            raise ModelError(f"{where}: field 'ID' is {joint_id}, already used by joint "
                             f"{names_by_id[joint_id]!r}")
        if (k == 0) != (kind == "free") and not (k == 0 and kind == "fixed"):
            raise ModelError(f"{where}: field 'Type' is {joint['Type']!r}, but only the first joint "
                             "(the root) may be 'none', and the root must be 'none' or 'fixed'")
        parent_id = _field(joint, "Parent", where, int)
        if parent_id >= 0 and parent_id not in names_by_id:
            raise ModelError(f"{where}: field 'Parent' is {parent_id}, which is not a joint listed "
                             "before this one (parents must come before their children)")
        if joint_id not in bodies:
            raise ModelError(f"{where}: no BodyDefs entry with ID {joint_id}")
        body = bodies[joint_id]
        body_where = f"{path}: body {body.get('Name', joint_id)!r}"
        shape = _field(body, "Shape", body_where, str)
        mass = _checked(body, "Mass", body_where, lambda v: v > 0, "positive")
        actuated = kind in ("spherical", "revolute")
        q_lower, q_upper = _limits(joint, _LIMIT_SLOTS[kind], where)
        kp, kd = gains.get(name, (0.0, 0.0))
        if controller is not None and actuated and name not in gains:
            raise ModelError(f"{controller}: no PD controller for joint {name!r}")
        links.append(LinkSpec(
            name=name, parent=names_by_id.get(parent_id), joint=kind, mass=mass,
            joint_pos=_vec(joint, "Attach", where),
            joint_rot=np.asarray(rotations.euler_xyz_to_matrix(_vec(joint, "AttachTheta", where))),
            axis=(0.0, 0.0, 1.0), shape=shape,
            shape_pos=_vec(body, "Attach", body_where),
            shape_rot=np.asarray(rotations.euler_xyz_to_matrix(
                _vec(body, "AttachTheta", body_where))),
            shape_size=_shape_size(shape, body, body_where), kp=kp, kd=kd,
            torque_limit=_torque_limit(joint, where) if actuated else np.inf,
            q_lower=q_lower, q_upper=q_upper))
        names_by_id[joint_id] = name
    kwargs = {} if dtype is None else {"dtype": dtype}
    return build_model(links, source=path, **kwargs)
