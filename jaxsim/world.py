"""The world a character lives in: gravity, the ground, static boxes and the contact model.

`World` is a pytree like `Model`: every physical number is an array (so Mars gravity, a softer
ground or a higher bar is a parameter change that can be vmapped and differentiated), and the
switches that change the shape of the computation (ground on/off, joint limits, torque limits,
the names of the static boxes) are static metadata.

Objects a character can touch are numbered: 0 is the ground plane, 1..K the static boxes in
order; `World.object_names` gives their names, so a task can find "bar" or "mat".
"""

import dataclasses
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import rotations
from jaxsim.dynamics.common import DEFAULT_GRAVITY

MARS_GRAVITY = (0.0, -3.711, 0.0)


@dataclasses.dataclass(frozen=True)
class Box:
    """A static box: centre, rotation (a 3×3 matrix or XYZ Euler angles) and half-extents."""

    name: str
    center: Sequence[float]
    half_size: Sequence[float]
    rotation: Sequence = (0.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class World:
    """Gravity, ground plane n·x = ground_offset, static boxes and contact/limit parameters.

    Contact (per contact point; thesis-free, a standard compliant model):
      contact_stiffness, contact_damping   normal spring k [N/m] and damper c [N·s/m]
      friction                              Coulomb coefficient μ: one for every object, or
                                            one per object (ground, then the boxes in order)
      tangent_stiffness, tangent_damping    the stick spring that holds a contact in place until
                                            its force exceeds μ·f_n (then it slides)
    Joint limits: limit_stiffness [N·m/rad], limit_damping [N·m·s/rad] of the penalty torques
    (the damper is solved implicitly, `jaxsim.limits`).

    Contact forces and the limit spring are explicit, so they bound the time step: roughly
    Δt² k / m < 1 and Δt c / m < 1 for the effective mass m at a contact point. The defaults
    suit the characters at 600 Hz; a free light body with corner contacts (a 1 kg box of
    20×10×40 cm has 0.16 kg at a corner) needs a softer contact or a smaller Δt.
    """

    gravity: jax.Array
    ground_normal: jax.Array
    ground_offset: jax.Array
    box_center: jax.Array
    box_rotation: jax.Array
    box_half_size: jax.Array
    contact_stiffness: jax.Array
    contact_damping: jax.Array
    friction: jax.Array
    tangent_stiffness: jax.Array
    tangent_damping: jax.Array
    limit_stiffness: jax.Array
    limit_damping: jax.Array
    box_names: tuple[str, ...] = ()
    ground: bool = True
    joint_limits: bool = True
    torque_limits: bool = False

    @property
    def object_names(self) -> tuple[str, ...]:
        return ("ground",) + self.box_names

    def object_index(self, name: str) -> int:
        if name not in self.object_names:
            raise ValueError(f"world has no object {name!r}; objects: "
                             f"{', '.join(self.object_names)}")
        return self.object_names.index(name)

    @property
    def has_contacts(self) -> bool:
        return self.ground or bool(self.box_names)

    def replace(self, **changes) -> "World":
        return dataclasses.replace(self, **changes)

    def astype(self, dtype) -> "World":
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), self)


_STATIC = ["box_names", "ground", "joint_limits", "torque_limits"]
jax.tree_util.register_dataclass(
    World, data_fields=[f.name for f in dataclasses.fields(World) if f.name not in _STATIC],
    meta_fields=_STATIC)


def _box_rotation(box: Box) -> np.ndarray:
    rot = np.asarray(box.rotation, float)
    if rot.shape == (3,) and np.all(np.isfinite(rot)):
        return np.asarray(rotations.euler_xyz_to_matrix(rot), float)
    if rotations.is_rotation_matrix(rot):
        return rot
    raise ValueError(f"box {box.name!r}: rotation must be 3 Euler angles or a 3×3 rotation "
                     f"matrix (orthogonal, determinant +1), got {rot.tolist()}")


def make_world(gravity=DEFAULT_GRAVITY, ground: bool = True, ground_normal=(0.0, 1.0, 0.0),
               ground_offset: float = 0.0, boxes: Sequence[Box] = (),
               contact_stiffness: float = 5e4, contact_damping: float = 150.0,
               friction: float = 0.9, tangent_stiffness: float = 5e4,
               tangent_damping: float = 50.0, joint_limits: bool = True,
               limit_stiffness: float = 2000.0, limit_damping: float = 50.0,
               torque_limits: bool = False, dtype=jnp.float32) -> World:
    """A validated `World`. The defaults are tuned for 600 Hz simulation of the characters here.

    `ground_normal` need not be vertical: a tilted plane is an incline.
    """
    normal = np.asarray(ground_normal, float)
    if normal.shape != (3,) or not np.linalg.norm(normal) > 0:
        raise ValueError(f"ground_normal must be a non-zero 3-vector, got {ground_normal!r}")
    if np.shape(gravity) != (3,) or not np.all(np.isfinite(gravity)):
        raise ValueError(f"gravity must be 3 finite numbers, got {gravity!r}")
    names = tuple(box.name for box in boxes)
    if len(set(names)) != len(names) or "ground" in names:
        raise ValueError(f"box names must be unique and not 'ground', got {names}")
    for box in boxes:
        half = np.asarray(box.half_size, float)
        if half.shape != (3,) or not np.all(half > 0):
            raise ValueError(f"box {box.name!r}: half_size must be 3 positive numbers, "
                             f"got {box.half_size!r}")
        if np.shape(box.center) != (3,):
            raise ValueError(f"box {box.name!r}: center must be 3 numbers, got {box.center!r}")
    friction = np.asarray(friction, float)
    if friction.ndim and friction.shape != (len(boxes) + 1,):
        raise ValueError(f"friction must be one number or one per object (ground and "
                         f"{len(boxes)} boxes); got {friction.tolist()}")
    scalars = dict(contact_stiffness=contact_stiffness, contact_damping=contact_damping,
                   friction=friction, tangent_stiffness=tangent_stiffness,
                   tangent_damping=tangent_damping, limit_stiffness=limit_stiffness,
                   limit_damping=limit_damping)
    for key, value in scalars.items():
        if not np.all(np.isfinite(value) & (np.asarray(value) >= 0)):
            raise ValueError(f"{key} must be a finite non-negative number, got {value!r}")
    if not tangent_stiffness > 0:
        raise ValueError(f"tangent_stiffness must be positive, got {tangent_stiffness!r}")

    def arr(x, shape=None):
        a = np.asarray(x, float)
        return jnp.asarray(a.reshape(shape) if shape else a, dtype)

    return World(
        gravity=arr(gravity), ground_normal=arr(normal / np.linalg.norm(normal)),
        ground_offset=arr(ground_offset),
        box_center=arr([b.center for b in boxes], (len(boxes), 3)),
        box_rotation=arr([_box_rotation(b) for b in boxes], (len(boxes), 3, 3)),
        box_half_size=arr([b.half_size for b in boxes], (len(boxes), 3)),
        **{k: arr(v) for k, v in scalars.items()},
        box_names=names, ground=ground, joint_limits=joint_limits, torque_limits=torque_limits)
