"""Tree traversals as `lax.scan` over the depth levels of a static tree (DESIGN.md, "Dynamics").

Non-root links are grouped by depth into a level table (`Topology.levels`, n_levels × width,
padded). One scan step handles one whole level, vmapped over its width, so the number of
sequential steps is the tree's depth and the compiled program does not grow with the number of
links. The scan carries only one level's values: a link finds its parent's value in the previous
level through a static one-hot table, which is a fusible multiply-and-sum rather than a gather or
scatter over all links (XLA on CPU runs many small gathers/scatters slowly).

Per-link arrays passed in carry a leading axis of n_links + 1: rows 0..n-1 are the links and row n
is a dummy that the level table's padding points to (see `pad_links`).
"""

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsim.model import Topology

_map = jax.tree_util.tree_map


def pad_links(x):
    """Append the dummy row (a copy of row 0, so that padded work stays finite)."""
    return _map(lambda a: jnp.concatenate([a, a[:1]], 0), x)


def parent_selectors(topology: Topology) -> np.ndarray:
    """(n_levels, width, width) one-hot: [k, w, v] = 1 when the link in slot w of level k is the
    child of the link in slot v of level k − 1 (of the root, in slot 0, for the first level).
    Padding slots have all-zero rows, so they neither read real parents nor send to them."""
    levels, parents = topology.levels, topology.padded_parents
    n = topology.n_links
    selectors = np.zeros(levels.shape + (levels.shape[1],))
    for k, row in enumerate(levels):
        previous = levels[k - 1] if k > 0 else np.array([0])
        for w, link in enumerate(row):
            if link < n:
                selectors[k, w, list(previous).index(parents[link])] = 1.0
    return selectors


def _select(selector, values):
    """selector (W, V) applied to values (V, ...): Σ_v selector[:, v] values[v], written as a
    short sum of elementwise products so that it fuses with the scan step (see `mat_vec`)."""
    extra = (1,) * (values.ndim - 1)
    column = selector.astype(values.dtype).reshape(selector.shape + extra)
    return sum(column[:, v] * values[v] for v in range(values.shape[0]))


def _to_levels(topology: Topology, link_data):
    """Per-link arrays (n+1, ...) → the level table's layout (n_levels, width, ...)."""
    return _map(lambda d: d[jnp.asarray(topology.levels)], link_data)


def from_levels(topology: Topology, root, per_level):
    """Values in the level table's layout (n_levels, width, ...) back to per-link rows: the root's
    value, each link's value from its slot, and a zero dummy row → (n+1, ...). One gather with a
    static index, as a scatter runs slowly over a batch on CPU."""
    levels = topology.levels
    index = np.full(topology.n_links + 1, levels.size + 1)        # the dummy: the zero row
    index[0] = 0                                                   # the root
    real = levels < topology.n_links
    index[levels[real]] = 1 + np.flatnonzero(real.ravel())
    index = jnp.asarray(index)

    def gather(r, v):
        rows = v.reshape((levels.size,) + v.shape[2:])
        zero = jnp.zeros((1,) + r.shape, v.dtype)
        return jnp.concatenate([r.astype(v.dtype)[None], rows, zero])[index]
    return _map(gather, root, per_level)


def scan_outward(topology: Topology, step, root_value, link_data, level_data=None):
    """Visit non-root links parents-first: value_i = step(value_parent(i), data_i[, level_i]).

    `root_value` is the root's value (no link axis); `link_data` has the n+1 link axis;
    `level_data`, if given, is indexed like the level table, (n_levels, width, ...), as returned by
    `scan_inward`. Returns the values of all links with the n+1 link axis (the root's row is
    `root_value`, the dummy row is zero).
    """
    width = topology.levels.shape[1]
    first = _map(lambda r: jnp.zeros((width,) + r.shape, r.dtype).at[0].set(r), root_value)
    selectors = jnp.asarray(parent_selectors(topology))

    def body(previous, xs):
        selector, data, extra = xs
        parent_values = _map(lambda p: _select(selector, p), previous)
        args = (parent_values, data) if extra is None else (parent_values, data, extra)
        values = jax.vmap(step)(*args)
        return values, values

    _, per_level = lax.scan(body, first, (selectors, _to_levels(topology, link_data), level_data))
    return from_levels(topology, root_value, per_level)


def scan_inward(topology: Topology, step, own, link_data):
    """Visit non-root links children-first, accumulating into parents.

    Each link's accumulator starts as its `own` value (n+1 link axis) and receives what its
    children send; then `step(acc_i, data_i) -> (output_i, contribution)` and the contribution
    goes to the parent. Returns the root's accumulator (its own value plus what its children sent)
    and the outputs per level, (n_levels, width, ...).
    """
    width = topology.levels.shape[1]
    selectors = jnp.asarray(parent_selectors(topology))

    def body(incoming, xs):
        selector, mine, data = xs
        acc = _map(jnp.add, mine, incoming)
        output, contribution = jax.vmap(step)(acc, data)
        to_parents = _map(lambda c: _select(selector.T, c), contribution)
        return to_parents, output

    zeros = _map(lambda a: jnp.zeros((width,) + a.shape[1:], a.dtype), own)
    into_root, outputs = lax.scan(
        body, zeros, (selectors, _to_levels(topology, own), _to_levels(topology, link_data)),
        reverse=True)
    return _map(lambda a, i: a[0] + i[0], own, into_root), outputs


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
