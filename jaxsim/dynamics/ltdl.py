"""Featherstone's branch-induced sparse LTDL factorisation (RBDA §6.5, Table 6.3).

For a tree, H[i, j] ≠ 0 only when DoF j is DoF i or one of its ancestors λ*(i). Factorising
H = Lᵀ D L from the last DoF to the first touches only those entries: eliminating DoF k is a
rank-one update of the block of its ancestors, H[A, A] −= h hᵀ / H_kk with h = H[k, A], A = λ*(k).
That costs O(n d²) for n DoFs and paths of at most d DoFs, instead of O(n³). Both the
factorisation and the two triangular solves are `lax.scan`s over DoFs with the padded ancestor
table `Topology.dof_ancestors` (padding points at a dummy row/column n).
"""

import jax.numpy as jnp
from jax import lax

from jaxsim.model import Topology


def ltdl_factor(topology: Topology, h):
    """Factor the symmetric positive-definite (nv, nv) matrix H in place of its sparsity pattern.

    Returns an (nv+1, nv+1) array whose diagonal is D and whose entries [k, λ*(k)] are L's
    (L has a unit diagonal); other entries are meaningless.
    """
    nv = topology.nv
    ancestors = jnp.asarray(topology.dof_ancestors)
    work = jnp.zeros((nv + 1, nv + 1), h.dtype).at[:nv, :nv].set(h)

    def eliminate(work, k):
        anc = ancestors[k]
        row = work[k, anc] * (anc < nv)
        pivot = work[k, k]
        work = work.at[anc[:, None], anc[None, :]].add(-jnp.outer(row, row) / pivot)
        return work.at[k, anc].set(row / pivot), None

    work, _ = lax.scan(eliminate, work, jnp.arange(nv), reverse=True)
    return work


def ltdl_solve(topology: Topology, factor, b):
    """Solve Lᵀ D L x = b with a factor from `ltdl_factor`, in O(n d)."""
    nv = topology.nv
    ancestors = jnp.asarray(topology.dof_ancestors)
    padded = jnp.concatenate([b, jnp.zeros((1,), b.dtype)])

    def apply_lt_inverse(x, k):               # x ← L⁻ᵀ x, descendants first
        anc = ancestors[k]
        return x.at[anc].add(-factor[k, anc] * (anc < nv) * x[k]), None

    def apply_l_inverse(x, k):                # x ← L⁻¹ x, ancestors first
        anc = ancestors[k]
        return x.at[k].add(-jnp.sum(factor[k, anc] * (anc < nv) * x[anc])), None

    x, _ = lax.scan(apply_lt_inverse, padded, jnp.arange(nv), reverse=True)
    x = x.at[:nv].divide(jnp.diagonal(factor)[:nv])
    x, _ = lax.scan(apply_l_inverse, x, jnp.arange(nv))
    return x[:nv]
