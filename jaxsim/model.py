"""Articulated models: a static, hashable topology and a pytree of physical parameters.

A model is a tree of links. Link 0 is the root; its joint connects it to the world and is `free`
(a floating base, 7 position numbers and 6 velocities) or `fixed` (a fixed base). Every other joint
is `spherical` (quaternion, 3 velocities: the angular velocity in the child frame), `revolute`
(one angle about a unit axis of the joint frame) or `fixed`.

The generalised position `q` follows DeepMimic's pose layout: root position, root quaternion
(w, x, y, z), then per joint in link order a quaternion or an angle (nothing for fixed joints); it
has 43 numbers for the humanoid. The generalised velocity `qd` has one entry per degree of freedom
(34 for the humanoid): the root's body-frame spatial velocity [ω; v], then each joint's velocity.

`Topology` is everything that decides the shape of the computation (parents, joint and shape types)
and is used as a jit-static argument. Every physical quantity is an array in `Model`, so it can be
vmapped over (body-shape sweeps) and differentiated (sensitivity studies).
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

ROOT_JOINT_TYPES = ("free", "fixed")
JOINT_TYPES = ("free", "spherical", "revolute", "fixed")
SHAPE_TYPES = ("none", "sphere", "capsule", "box")
Q_SIZE = {"free": 7, "spherical": 4, "revolute": 1, "fixed": 0}
DOF_SIZE = {"free": 6, "spherical": 3, "revolute": 1, "fixed": 0}
# Non-root joints occupy 3 padded velocity slots in the tree passes
# (docs/design.md, "Conventions").
JOINT_SLOTS = 3


class ModelError(ValueError):
    """A model description is invalid; the message names the link and the field."""


@dataclasses.dataclass(frozen=True)
class Topology:
    """The static structure of a model: hashable, used as a jit-static argument."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    joint_types: tuple[str, ...]
    shape_types: tuple[str, ...]
    # How the tree passes walk a shallow tree: in straight-line code (True, faster to run) or by
    # a scan (False, faster to compile); see `jaxsim.tree` and `Model.with_traversal`.
    unrolled_traversal: bool = True

    @property
    def n_links(self) -> int:
        return len(self.names)

    @functools.cached_property
    def q_offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([Q_SIZE[t] for t in self.joint_types])])

    @functools.cached_property
    def dof_offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([DOF_SIZE[t] for t in self.joint_types])])

    @property
    def nq(self) -> int:
        return int(self.q_offsets[-1])

    @property
    def nv(self) -> int:
        return int(self.dof_offsets[-1])

    @property
    def floating(self) -> bool:
        return self.joint_types[0] == "free"

    def link_index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ModelError(f"unknown link/joint name {name!r}; known: {', '.join(self.names)}")

    @functools.cached_property
    def depths(self) -> np.ndarray:
        depth = np.zeros(self.n_links, int)
        for i in range(1, self.n_links):
            depth[i] = depth[self.parents[i]] + 1
        return depth

    @functools.cached_property
    def levels(self) -> np.ndarray:
        """Non-root links grouped by depth: (n_levels, width), padded with the dummy index n.

        The tree scans process one level per scan step, all links of the level at once.
        """
        n = self.n_links
        groups = [np.flatnonzero(self.depths == d) for d in range(1, self.depths.max() + 1)]
        width = max((len(g) for g in groups), default=1)
        table = np.full((max(len(groups), 1), width), n, np.int32)
        for row, group in zip(table, groups):
            row[: len(group)] = group
        return table

    @functools.cached_property
    def slot_dof_index(self) -> np.ndarray:
        """(n+1, 3): index into qd of each non-root joint's velocity slot, nv where unused."""
        table = np.full((self.n_links + 1, JOINT_SLOTS), self.nv, np.int32)
        for i in range(1, self.n_links):
            size = DOF_SIZE[self.joint_types[i]]
            table[i, :size] = self.dof_offsets[i] + np.arange(size)
        return table

    @functools.cached_property
    def slot_mask(self) -> np.ndarray:
        return self.slot_dof_index < self.nv

    @functools.cached_property
    def spherical_indices(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the spherical joints' quaternions in q (k, 4) and velocities in qd (k, 3)."""
        sph = self.links_of_type("spherical")
        return (self.q_offsets[sph][:, None] + np.arange(4),
                self.dof_offsets[sph][:, None] + np.arange(3))

    def links_of_type(self, joint_type: str) -> np.ndarray:
        return np.array([i for i in range(1, self.n_links) if self.joint_types[i] == joint_type],
                        np.int32)

    @functools.cached_property
    def ancestor_or_self(self) -> np.ndarray:
        """(n, n) boolean: [i, j] is True when link j is link i or one of its ancestors."""
        n = self.n_links
        rel = np.zeros((n, n), bool)
        for i in range(n):
            j = i
            while j >= 0:
                rel[i, j] = True
                j = self.parents[j]
        return rel

    @functools.cached_property
    def dof_parents(self) -> np.ndarray:
        """λ(k) for each degree of freedom: the previous DoF on the path to the root, or -1.

        This is the DoF-level tree that gives the mass matrix its branch-induced sparsity
        (RBDA §6.5): H[i, j] ≠ 0 only when one of i, j is an ancestor of the other.
        """
        lam = np.full(self.nv, -1, int)
        last_dof = np.full(self.n_links, -1, int)
        for i in range(self.n_links):
            inherited = last_dof[self.parents[i]] if i > 0 else -1
            start, stop = self.dof_offsets[i], self.dof_offsets[i + 1]
            for k in range(start, stop):
                lam[k] = inherited if k == start else k - 1
            last_dof[i] = stop - 1 if stop > start else inherited
        return lam

    @functools.cached_property
    def dof_ancestors(self) -> np.ndarray:
        """(nv, d): the DoF ancestors of each DoF, nearest first, padded with nv."""
        chains = []
        for k in range(self.nv):
            chain, j = [], self.dof_parents[k]
            while j >= 0:
                chain.append(j)
                j = self.dof_parents[j]
            chains.append(chain)
        depth = max((len(c) for c in chains), default=0)
        table = np.full((self.nv, max(depth, 1)), self.nv, np.int32)
        for row, chain in zip(table, chains):
            row[: len(chain)] = chain
        return table

    @functools.cached_property
    def max_path_dofs(self) -> int:
        """DoFs on the deepest root-to-leaf path (the d of the O(n d²) sparse factorisation)."""
        return int((self.dof_ancestors < self.nv).sum(axis=1).max() + 1) if self.nv else 0


@dataclasses.dataclass(frozen=True)
class Model:
    """A character: static `topology` plus arrays of physical parameters (a pytree).

    Per link (leading axis n_links):
      joint_pos, joint_rot   placement of the joint frame in the parent frame (position, rotation);
                             for a fixed-base root, the base's placement in the world
      joint_axis             unit rotation axis of a revolute joint, in the joint frame
      mass, com, inertia     mass, centre of mass and 3×3 rotational inertia about the centre of
                             mass, in the link frame
      shape_pos, shape_rot, shape_size
                             collision shape placement in the link frame and its half-sizes:
                             sphere (r, ·, ·); capsule (r, half-length, ·) along the shape's Y axis;
                             box (half-extents)
    Per degree of freedom (leading axis nv):
      kp, kd                 PD gains; torque_limit; q_lower, q_upper angle limits (for spherical
                             joints, limits on the rotation-vector components)
    """

    topology: Topology
    joint_pos: jax.Array
    joint_rot: jax.Array
    joint_axis: jax.Array
    mass: jax.Array
    com: jax.Array
    inertia: jax.Array
    shape_pos: jax.Array
    shape_rot: jax.Array
    shape_size: jax.Array
    kp: jax.Array
    kd: jax.Array
    torque_limit: jax.Array
    q_lower: jax.Array
    q_upper: jax.Array

    @property
    def nq(self) -> int:
        return self.topology.nq

    @property
    def nv(self) -> int:
        return self.topology.nv

    @property
    def n_links(self) -> int:
        return self.topology.n_links

    def replace(self, **changes) -> "Model":
        return dataclasses.replace(self, **changes)

    def with_traversal(self, unrolled: bool) -> "Model":
        """The same model, its tree passes walking a shallow tree (the humanoid, the dog) in
        straight-line code (True, the default) or by a scan over its levels (False). The scan
        runs 1.5–2× slower but compiles faster: a 10-step humanoid rollout's gradient in 26 s
        against 46 s (docs/benchmarks.md, "Shallow trees in straight-line code")."""
        return self.replace(topology=dataclasses.replace(self.topology,
                                                         unrolled_traversal=unrolled))

    def astype(self, dtype) -> "Model":
        """The same model with every floating-point array cast to `dtype`."""
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), self)


_MODEL_DATA_FIELDS = [f.name for f in dataclasses.fields(Model) if f.name != "topology"]
jax.tree_util.register_dataclass(Model, data_fields=_MODEL_DATA_FIELDS, meta_fields=["topology"])


@dataclasses.dataclass(frozen=True)
class State:
    """Generalised position q (nq) and velocity qd (nv) of one character.

    A state that steps through a world with contacts also carries the contact memory (see
    `jaxsim.simulation.init_state`): `contact_stretch` (C, 3), the friction springs' stretch, and
    `touching` (n_links, n_objects), which link touched which object in the last step.
    """

    q: jax.Array
    qd: jax.Array
    contact_stretch: jax.Array | None = None
    touching: jax.Array | None = None

    def replace(self, **changes) -> "State":
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(State, data_fields=["q", "qd", "contact_stretch", "touching"],
                                 meta_fields=[])


def check_layout(model: Model, name: str, value, layout: str, leading: str = ""):
    """Raise ValueError unless `value` is one pose (layout "nq") or one velocity ("nv") of
    `model`, or with `leading` given (such as "T") a stack of them along one leading axis.

    Shapes are static, so this works on traced arrays too. The message names the argument, the
    expected length and the shape received: a DeepMimic frame of [dt, pose] passed as a pose, for
    one, has one number too many and would otherwise shift every joint by one slot.
    """
    size = {"nq": model.nq, "nv": model.nv}[layout]
    shape = tuple(np.shape(value))
    expected = f"({leading}, {size})" if leading else f"({size},)"
    if len(shape) != (2 if leading else 1) or shape[-1] != size:
        raise ValueError(f"{name}: expected shape {expected} with {layout} = {size} for this "
                         f"model, got shape {shape}")


def rest_pose(model: Model, root_height: float = 0.0) -> jax.Array:
    """q with every joint at zero (identity quaternions) and the root at the given height (Y)."""
    topo = model.topology
    q = np.zeros(topo.nq)
    for i, joint_type in enumerate(topo.joint_types):
        if joint_type == "free":
            q[topo.q_offsets[i] + 3] = 1.0
            q[topo.q_offsets[i] + 1] = root_height
        elif joint_type == "spherical":
            q[topo.q_offsets[i]] = 1.0
    return jnp.asarray(q, model.mass.dtype)
