"""Tree traversals as `lax.scan` over the levels of a static tree (DESIGN.md, "Dynamics").

Per-link arrays carry a leading axis of n_links + 1: rows 0..n-1 are the links and row n is a
dummy that absorbs the padding of the level table (`Topology.levels`). One scan step processes all
links of one depth at once (vmapped), so the number of sequential steps is the tree's depth, and
the compiled program does not grow with the number of links.
"""

import jax
import jax.numpy as jnp
from jax import lax

from jaxsim.model import Topology

_map = jax.tree_util.tree_map


def pad_links(x):
    """Append the dummy row (a copy of row 0, so that padded work stays finite)."""
    return _map(lambda a: jnp.concatenate([a, a[:1]], 0), x)


def scan_outward(topology: Topology, step, root_value, link_data, level_data=None):
    """Visit non-root links parents-first: value_i = step(value_parent(i), data_i[, level_i]).

    `root_value` is the root's value (no link axis); `link_data` has the n+1 link axis;
    `level_data`, if given, is indexed like the level table, (n_levels, width, ...), as returned by
    `scan_inward`. Returns the values of all links, with the n+1 link axis.
    """
    n = topology.n_links
    parents = jnp.asarray(topology.padded_parents)
    values = _map(lambda r: jnp.zeros((n + 1,) + r.shape, r.dtype).at[0].set(r), root_value)

    def body(values, xs):
        idx, extra = xs
        parent_values = _map(lambda v: v[parents[idx]], values)
        data = _map(lambda d: d[idx], link_data)
        args = (parent_values, data) if extra is None else (parent_values, data, extra)
        new = jax.vmap(step)(*args)
        return _map(lambda v, x: v.at[idx].set(x), values, new), None

    values, _ = lax.scan(body, values, (jnp.asarray(topology.levels), level_data))
    return values


def scan_inward(topology: Topology, step, accumulators, link_data):
    """Visit non-root links children-first, accumulating into parents.

    `step(acc_i, data_i) -> (output_i, contribution)`; the contribution is added to the parent's
    accumulator before the parent is visited. Returns the final accumulators (n+1 link axis; the
    root's row holds everything its subtree sent) and the outputs per level, (n_levels, width, ...).
    """
    parents = jnp.asarray(topology.padded_parents)

    def body(acc, idx):
        mine = _map(lambda a: a[idx], acc)
        data = _map(lambda d: d[idx], link_data)
        output, contribution = jax.vmap(step)(mine, data)
        acc = _map(lambda a, c: a.at[parents[idx]].add(c), acc, contribution)
        return acc, output

    return lax.scan(body, accumulators, jnp.asarray(topology.levels), reverse=True)


def gather_slots(topology: Topology, generalized):
    """(nv,) generalised vector → (n+1, 3) per-joint velocity slots (zeros where unused)."""
    padded = jnp.concatenate([generalized, jnp.zeros((1,), generalized.dtype)])
    return padded[jnp.asarray(topology.slot_dof_index)]


def scatter_slots(topology: Topology, slots, root_part):
    """Per-joint slots (n+1, 3) and the root's DoFs → a generalised vector (nv,)."""
    out = jnp.zeros((topology.nv + 1,), slots.dtype)
    out = out.at[jnp.asarray(topology.slot_dof_index)].add(slots)
    if topology.floating:
        out = out.at[:6].set(root_part)
    return out[:-1]
