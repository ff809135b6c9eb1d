"""Building a validated `Model` from per-link descriptions.

Characters (built-in or loaded from files) describe each link with a `LinkSpec`; `build_model`
checks the description and packs it into arrays. Errors name the source, the link and the field.
"""

import dataclasses
from typing import Sequence

import jax.numpy as jnp
import numpy as np

from jaxsim import rotations
from jaxsim.model import (DOF_SIZE, JOINT_TYPES, ROOT_JOINT_TYPES, SHAPE_TYPES, Model, ModelError,
                          Topology)


@dataclasses.dataclass
class LinkSpec:
    """One link and the joint that attaches it to its parent (None for the root).

    Sizes of shapes are half-sizes (see `Model`). If `inertia` is None it is computed from the
    shape with uniform density; `com` defaults to the shape's centre. Gains and limits are scalars
    (the same for every DoF of the joint) or one value per DoF: gains finite and non-negative,
    torque limits positive, and q_lower ≤ q_upper. The defaults, torque_limit = np.inf and
    q_lower, q_upper = −np.inf, np.inf, mean no limit. A free root takes no limits: its
    coordinates are its pose in the world, and the hand-of-God force on it is not capped.
    """

    name: str
    parent: str | None
    joint: str
    mass: float
    joint_pos: Sequence[float] = (0.0, 0.0, 0.0)
    joint_rot: np.ndarray | None = None
    axis: Sequence[float] = (0.0, 0.0, 1.0)
    shape: str = "none"
    shape_pos: Sequence[float] = (0.0, 0.0, 0.0)
    shape_rot: np.ndarray | None = None
    shape_size: Sequence[float] = (0.0, 0.0, 0.0)
    com: Sequence[float] | None = None
    inertia: np.ndarray | None = None
    kp: float | Sequence[float] = 0.0
    kd: float | Sequence[float] = 0.0
    torque_limit: float | Sequence[float] = np.inf
    q_lower: float | Sequence[float] = -np.inf
    q_upper: float | Sequence[float] = np.inf


def shape_inertia(shape: str, half_size, mass: float) -> np.ndarray:
    """Rotational inertia about the centre of a uniform solid, in the shape's own frame."""
    r = half_size[0]
    if shape == "sphere":
        return np.eye(3) * 0.4 * mass * r * r
    if shape == "box":
        a, b, c = np.square(half_size)
        return np.diag([b + c, a + c, a + b]) * mass / 3.0
    if shape == "capsule":
        # Cylinder of half-length h along Y plus two hemispherical caps, mass split by volume.
        h = half_size[1]
        v_cyl, v_caps = np.pi * r * r * 2 * h, 4.0 / 3.0 * np.pi * r**3
        m_cyl = mass * v_cyl / (v_cyl + v_caps)
        m_caps = mass - m_cyl
        axial = m_cyl * r * r / 2 + m_caps * 0.4 * r * r
        transverse = (m_cyl * (r * r / 4 + (2 * h) ** 2 / 12)
                      + m_caps * (0.4 * r * r + h * h + 0.75 * h * r))
        return np.diag([transverse, axial, transverse])
    raise ModelError(f"cannot compute the inertia of shape {shape!r}")


# What each per-DoF field accepts: (test, the requirement in words).
_PER_DOF_RULES = {
    "kp": (lambda v: np.isfinite(v) & (v >= 0), "finite and non-negative"),
    "kd": (lambda v: np.isfinite(v) & (v >= 0), "finite and non-negative"),
    "torque_limit": (lambda v: v > 0, "positive (inf for no limit)"),
    "q_lower": (lambda v: v < np.inf, "a number or -inf (no limit)"),
    "q_upper": (lambda v: v > -np.inf, "a number or inf (no limit)"),
}


def _per_dof(value, n_dof, what, where):
    arr = np.broadcast_to(np.asarray(value, float), (n_dof,)) if np.ndim(value) == 0 else \
        np.asarray(value, float)
    if arr.shape != (n_dof,):
        raise ModelError(f"{where}: field {what!r} needs 1 or {n_dof} values, got {arr.shape[0]}")
    accepts, requirement = _PER_DOF_RULES[what]
    bad = np.flatnonzero(~accepts(arr))
    if len(bad):
        raise ModelError(f"{where}: field {what!r} must be {requirement}, got {arr[bad[0]]} "
                         f"(DoF {bad[0]} of the joint)")
    return arr


def _check_limits(values, joint, where):
    """Limits that contradict each other, or any limit on a free root."""
    lower, upper = values["q_lower"], values["q_upper"]
    crossed = np.flatnonzero(lower > upper)
    if len(crossed):
        k = crossed[0]
        raise ModelError(f"{where}: field 'q_lower' is above field 'q_upper' at DoF {k} of the "
                         f"joint ({lower[k]} > {upper[k]})")
    if joint == "free":
        for key in ("q_lower", "q_upper", "torque_limit"):
            if np.any(np.isfinite(values[key])):
                raise ModelError(f"{where}: field {key!r} must be left unlimited on a free root "
                                 f"(its coordinates are its world pose), got {values[key]}")


def _vector(value, what, where):
    arr = np.asarray(value, float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ModelError(f"{where}: field {what!r} must be 3 finite numbers, got {value!r}")
    return arr


def _rotation(value, what, where):
    if value is None:
        return np.eye(3)
    if not rotations.is_rotation_matrix(value):
        raise ModelError(f"{where}: field {what!r} must be a 3×3 rotation matrix (orthogonal, "
                         f"determinant +1), got {np.asarray(value).tolist()}")
    return np.asarray(value, float)


def build_model(links: Sequence[LinkSpec], source: str = "model", dtype=jnp.float32) -> Model:
    """Validate link descriptions (root first, parents before children) and pack a `Model`."""
    if not links:
        raise ModelError(f"{source}: a model needs at least one link")
    index: dict[str, int] = {}
    parents, joint_types, shape_types = [], [], []
    arrays = {k: [] for k in ("joint_pos", "joint_rot", "joint_axis", "mass", "com", "inertia",
                              "shape_pos", "shape_rot", "shape_size")}
    per_dof = {k: [] for k in ("kp", "kd", "torque_limit", "q_lower", "q_upper")}
    for i, link in enumerate(links):
        where = f"{source}: link {link.name!r}"
        if link.name in index:
            raise ModelError(f"{where}: duplicate link name")
        if i == 0:
            if link.parent is not None:
                raise ModelError(f"{where}: the first link is the root and must have no parent")
            if link.joint not in ROOT_JOINT_TYPES:
                raise ModelError(f"{where}: field 'joint' of the root must be one of "
                                 f"{ROOT_JOINT_TYPES}, got {link.joint!r}")
            parents.append(-1)
        else:
            if link.parent not in index:
                known = "it is not defined at all" if link.parent not in {l.name for l in links} \
                    else "it is listed after its child"
                raise ModelError(f"{where}: field 'parent' names {link.parent!r}, but {known}; "
                                 "list parents before children")
            if link.joint not in JOINT_TYPES or link.joint == "free":
                raise ModelError(f"{where}: field 'joint' must be one of spherical, revolute, "
                                 f"fixed, got {link.joint!r}")
            parents.append(index[link.parent])
        if link.shape not in SHAPE_TYPES:
            raise ModelError(f"{where}: field 'shape' must be one of {SHAPE_TYPES}, "
                             f"got {link.shape!r}")
        if not (np.isfinite(link.mass) and link.mass > 0):
            raise ModelError(f"{where}: field 'mass' must be positive, got {link.mass!r}")
        index[link.name] = i
        joint_types.append(link.joint)
        shape_types.append(link.shape)

        axis = _vector(link.axis, "axis", where)
        if link.joint == "revolute" and not np.isclose(np.linalg.norm(axis), 1.0, atol=1e-6):
            raise ModelError(f"{where}: field 'axis' must be a unit vector, got {link.axis!r}")
        shape_pos = _vector(link.shape_pos, "shape_pos", where)
        shape_rot = _rotation(link.shape_rot, "shape_rot", where)
        shape_size = _vector(link.shape_size, "shape_size", where)
        if link.shape != "none" and np.any(shape_size[: {"sphere": 1, "capsule": 2, "box": 3}[
                link.shape]] <= 0):
            raise ModelError(f"{where}: field 'shape_size' must be positive for a {link.shape}")
        com = shape_pos if link.com is None else _vector(link.com, "com", where)
        if link.inertia is None:
            if link.shape == "none":
                raise ModelError(f"{where}: field 'inertia' is needed when the link has no shape")
            inertia = shape_rot @ shape_inertia(link.shape, shape_size, link.mass) @ shape_rot.T
        else:
            inertia = np.asarray(link.inertia, float)
            if inertia.shape != (3, 3) or not np.allclose(inertia, inertia.T) or \
                    np.linalg.eigvalsh(inertia).min() <= 0:
                raise ModelError(f"{where}: field 'inertia' must be a symmetric positive-definite "
                                 "3×3 matrix")
        arrays["joint_pos"].append(_vector(link.joint_pos, "joint_pos", where))
        arrays["joint_rot"].append(_rotation(link.joint_rot, "joint_rot", where))
        arrays["joint_axis"].append(axis)
        arrays["mass"].append(float(link.mass))
        arrays["com"].append(com)
        arrays["inertia"].append(inertia)
        arrays["shape_pos"].append(shape_pos)
        arrays["shape_rot"].append(shape_rot)
        arrays["shape_size"].append(shape_size)
        n_dof = DOF_SIZE[link.joint]
        values = {key: _per_dof(getattr(link, key), n_dof, key, where) for key in per_dof}
        _check_limits(values, link.joint, where)
        for key, value in values.items():
            per_dof[key].append(value)

    topology = Topology(tuple(l.name for l in links), tuple(parents), tuple(joint_types),
                        tuple(shape_types))
    fields = {k: jnp.asarray(np.array(v), dtype) for k, v in arrays.items()}
    fields.update({k: jnp.asarray(np.concatenate(v), dtype) for k, v in per_dof.items()})
    return Model(topology=topology, **fields)
