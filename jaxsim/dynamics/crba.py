"""Composite-rigid-body mass matrix, computed in world coordinates.

With every link's inertia I_i and motion subspace S_i expressed in world coordinates, the
composite inertia of link j is the sum of the inertias of its subtree, I^c_j = Σ_{i ∈ ν(j)} I_i,
and the mass matrix block of joints i, j (j an ancestor of i, or i itself) is
H_ij = S_iᵀ I^c_i S_j (RBDA §6.2, eq. 6.10–6.11). The subtree sums and the block products use the
static ancestor table, so the whole computation is a handful of batched products.
"""

import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, spatial
from jaxsim.model import Model


def _world_subspaces(model: Model, rot_w, pos_w):
    """(n, 6, 6) each joint's motion subspace in world coordinates, padded to 6 columns."""
    topo = model.topology
    s = jnp.zeros((topo.n_links, 6, 6), rot_w.dtype)
    s = s.at[:, :, :3].set(kinematics.motion_subspaces(model))
    if topo.floating:
        s = s.at[0].set(jnp.eye(6, dtype=rot_w.dtype))
    # Link → world motion transform: [R ω; R v + p × R ω].
    ang = rot_w @ s[:, :3, :]
    lin = rot_w @ s[:, 3:, :] + jnp.cross(pos_w[:, :, None], ang, axis=1)
    return jnp.concatenate([ang, lin], 1)


def _dof_table(model: Model) -> np.ndarray:
    """(n, 6) index into qd of each padded column of `_world_subspaces`, nv where unused."""
    topo = model.topology
    table = np.full((topo.n_links, 6), topo.nv, np.int32)
    table[:, :3] = topo.slot_dof_index[:-1]
    if topo.floating:
        table[0] = np.arange(6)
    return table


def mass_matrix(model: Model, q):
    """Joint-space inertia matrix H(q) (nv, nv)."""
    topo = model.topology
    rot_w, pos_w = kinematics.forward_kinematics(model, q)
    x_world_to_link = spatial.plucker(jnp.swapaxes(rot_w, -1, -2), pos_w)
    inertia_link = spatial.inertia_matrix(model.mass, model.com, model.inertia)
    inertia_world = jnp.swapaxes(x_world_to_link, -1, -2) @ inertia_link @ x_world_to_link
    related = jnp.asarray(topo.ancestor_or_self, rot_w.dtype)   # [i, j]: j ∈ ancestors(i) ∪ {i}
    composite = jnp.einsum("ij,iab->jab", related, inertia_world)
    s_w = _world_subspaces(model, rot_w, pos_w)
    f = composite @ s_w                                            # I^c_i S_i
    blocks = jnp.einsum("iak,jal->ikjl", f, s_w) * related[:, None, :, None]
    diagonal = jnp.eye(topo.n_links, dtype=rot_w.dtype)[:, None, :, None] * blocks
    blocks = blocks + jnp.transpose(blocks, (2, 3, 0, 1)) - diagonal
    idx = _dof_table(model).reshape(-1)
    size = topo.n_links * 6
    h = jnp.zeros((topo.nv + 1, topo.nv + 1), rot_w.dtype)
    h = h.at[idx[:, None], idx[None, :]].add(blocks.reshape(size, size))
    return h[:-1, :-1]
