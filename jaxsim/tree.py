"""Tree traversals over the depth levels of a static tree (docs/design.md, "Dynamics").

Non-root links are grouped by depth into levels (`Topology.levels`); each traversal step handles
one whole level, vmapped over its links, so the number of sequential steps is the tree's depth.
Two ways to walk the levels, chosen per tree by `unrolled`:

- Shallow trees (the humanoid: 4 levels; the dog: 6) are walked in straight-line code, one block
  per level, each exactly as wide as its level. A link reads its parent's value from the level
  before by a gather with a static index, and a parent sums its children's contributions the same
  way. There is no padding and no loop bookkeeping: the humanoid's contact step runs 1.8× faster
  than by the scan (docs/benchmarks.md), for 1.5–3 s more compile time.
- Deeper trees (the long snakes) are walked by `lax.scan` over the padded level table
  (n_levels × width), so the compiled program does not grow with the depth. The scan carries
  only one level's values: a link finds its parent's value in the previous level through a
  static one-hot table, a fusible multiply-and-sum rather than a gather or scatter over all
  links (XLA on CPU runs many small gathers/scatters slowly).

Per-link arrays passed in carry a leading axis of n_links + 1: rows 0..n-1 are the links and row n
is a dummy that the level table's padding points to (see `pad_links`).
"""

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsim.model import Topology

_map = jax.tree_util.tree_map


# The deepest tree walked in straight-line code. Each level more adds about 0.8 s of compile
# time; a 10-level snake would gain 30% at batch 4096 for 6 s more (docs/benchmarks.md).
UNROLL_MAX_LEVELS = 8


def unrolled(topology: Topology) -> bool:
    """Whether the traversals walk this tree level by level in straight-line code (see above);
    `Model.with_traversal(False)` asks for the scan, which compiles faster."""
    return (topology.unrolled_traversal and 1 < topology.n_links
            and topology.levels.shape[0] <= UNROLL_MAX_LEVELS)


def level_links(topology: Topology) -> list[np.ndarray]:
    """The links of each level, without the table's padding."""
    return [row[row < topology.n_links] for row in topology.levels]


def parent_slots(topology: Topology) -> list[np.ndarray]:
    """For each level, the slot of each link's parent in the level before (the root is the one
    slot of the level before the first)."""
    previous, slots = [0], []
    for links in level_links(topology):
        slots.append(np.array([list(previous).index(topology.parents[i]) for i in links], int))
        previous = links
    return slots


def child_slots(topology: Topology) -> list[np.ndarray]:
    """For each level, a (width of the level before, most children) table of each parent's
    children's slots in this level, padded with the level's width (a zero row)."""
    tables, links = [], level_links(topology)
    for previous, level, parents in zip([[0]] + links, links, parent_slots(topology)):
        children = [np.flatnonzero(parents == p) for p in range(len(previous))]
        table = np.full((len(children), max(map(len, children))), len(level))
        for row, c in zip(table, children):
            row[: len(c)] = c
        tables.append(table)
    return tables


def pad_links(x):
    """Append the dummy row (a copy of row 0, so that padded work stays finite)."""
    return _map(lambda a: jnp.concatenate([a, a[:1]], 0), x)


def parent_selectors(topology: Topology) -> np.ndarray:
    """(n_levels, width, width) one-hot: [k, w, v] = 1 when the link in slot w of level k is the
    child of the link in slot v of level k − 1 (of the root, in slot 0, for the first level).
    Padding slots have all-zero rows, so they neither read real parents nor send to them."""
    levels = topology.levels
    selectors = np.zeros(levels.shape + (levels.shape[1],))
    for k, parents in enumerate(parent_slots(topology)):     # real links fill each row's start
        selectors[k, np.arange(len(parents)), parents] = 1.0
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
    """Values per level (as `scan_inward` returns them) back to per-link rows: the root's value,
    each link's value from its slot, and a zero dummy row → (n+1, ...). One gather with a
    static index, as a scatter runs slowly over a batch on CPU."""
    if unrolled(topology):
        slots = np.concatenate(level_links(topology))
        per_level = _map(lambda *rows: jnp.concatenate(rows), *per_level)
    else:
        slots = topology.levels.ravel()
        per_level = _map(lambda v: v.reshape((slots.size,) + v.shape[2:]), per_level)
    index = np.full(topology.n_links + 1, slots.size + 1)          # the dummy: the zero row
    index[0] = 0                                                   # the root
    real = slots < topology.n_links
    index[slots[real]] = 1 + np.flatnonzero(real)
    index = jnp.asarray(index)

    def gather(r, rows):
        zero = jnp.zeros((1,) + r.shape, rows.dtype)
        return jnp.concatenate([r.astype(rows.dtype)[None], rows, zero])[index]
    return _map(gather, root, per_level)


def scan_outward(topology: Topology, step, root_value, link_data, level_data=None):
    """Visit non-root links parents-first: value_i = step(value_parent(i), data_i[, level_i]).

    `root_value` is the root's value (no link axis); `link_data` has the n+1 link axis;
    `level_data`, if given, is per-level values as `scan_inward` returns them. Returns the values
    of all links with the n+1 link axis (the root's row is `root_value`, the dummy row is zero).
    """
    if unrolled(topology):
        return _outward_unrolled(topology, step, root_value, link_data, level_data)

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


def _outward_unrolled(topology: Topology, step, root_value, link_data, level_data):
    previous, per_level = _map(lambda r: r[None], root_value), []
    for k, (links, parents) in enumerate(zip(level_links(topology), parent_slots(topology))):
        args = (_map(lambda p: p[parents], previous), _map(lambda d: d[links], link_data))
        if level_data is not None:
            args += (level_data[k],)
        previous = jax.vmap(step)(*args)
        per_level.append(previous)
    return from_levels(topology, root_value, per_level)


def scan_inward(topology: Topology, step, own, link_data):
    """Visit non-root links children-first, accumulating into parents.

    Each link's accumulator starts as its `own` value (n+1 link axis) and receives what its
    children send; then `step(acc_i, data_i) -> (output_i, contribution)` and the contribution
    goes to the parent. Returns the root's accumulator (its own value plus what its children sent)
    and the outputs per level: a list of (level width, ...) values when `unrolled`, else stacked
    in the level table's layout (n_levels, width, ...). `scan_outward` and `from_levels` read
    either.
    """
    if unrolled(topology):
        return _inward_unrolled(topology, step, own, link_data)

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


def _inward_unrolled(topology: Topology, step, own, link_data):
    incoming, outputs = None, []
    for links, children in reversed(list(zip(level_links(topology), child_slots(topology)))):
        acc = _map(lambda a: a[links], own)
        if incoming is not None:
            acc = _map(jnp.add, acc, incoming)
        output, contribution = jax.vmap(step)(acc, _map(lambda d: d[links], link_data))
        outputs.insert(0, output)
        incoming = _map(lambda c: _sum_children(c, children), contribution)
    return _map(lambda a, i: a[0] + i[0], own, incoming), outputs


def _sum_children(contribution, children):
    """Each parent's sum of its children's contributions, by `children` (see `child_slots`)."""
    padded = jnp.concatenate([contribution, jnp.zeros_like(contribution[:1])])
    return sum(padded[children[:, c]] for c in range(children.shape[1]))


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
