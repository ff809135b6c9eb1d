"""`vmap` that computes with the batch as the innermost (last) axis.

`jax.vmap` puts the batch axis first, so a batch of 4096 characters is held as (4096, 6, 6)
arrays and XLA's fused loops on CPU run over minor dimensions of 3 and 6, which do not fill the
vector lanes. With the batch last, (6, 6, 4096), the same loops run along the batch, and a
chain of small matrix products runs 2–3× faster (docs/benchmarks.md, "The batch innermost: a
closer look").

`batch_last.vmap(fun)` has the meaning of `jax.vmap(fun)` (batch on axis 0 of the inputs and
outputs), but evaluates the per-example program itself: it traces `fun` for one example to a
jaxpr and evaluates it equation by equation on arrays that carry the batch as one extra trailing
axis. Each primitive is re-issued with its parameters adjusted for that axis. A primitive without
such a rule here goes through `jax.vmap` on its own, with the batch moved to the front and back
(correct, only slower). So the dynamics stay written for one character, as docs/design.md
asks ("Principles").

Values that do not depend on the batch (the model, constants) stay unbatched, as in `jax.vmap`.
The result is an ordinary JAX computation: it jits, differentiates and nests like any other.
"""

import os

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax._src import source_info_util
from jax.extend.core import ClosedJaxpr, Literal

ELEMENTWISE = frozenset("""
    abs acos acosh add and asin asinh atan atan2 atanh cbrt ceil clamp conj convert_element_type
    copy cos cosh digamma div eq erf erf_inv erfc exp exp2 expm1 floor ge gt imag integer_pow
    is_finite le le_to lgamma log log1p logistic lt lt_to max min mul ne neg nextafter not or
    pow real reduce_precision rem round rsqrt select_n sign sin sinh sqrt square stop_gradient
    sub tan tanh xor
""".split())

# Primitives whose parameters name axes of the operand (all below its rank, so unchanged when a
# trailing axis is added); the output is batched like the operand.
SAME_AXES = frozenset("""
    argmax argmin cumlogsumexp cummax cummin cumprod cumsum reduce_and reduce_max reduce_min
    reduce_or reduce_prod reduce_sum reduce_xor squeeze
""".split())


# The largest contracted size of a matrix product that is written out as elementwise products.
SMALL_CONTRACTION = 64


def _batched_shape(aval, size):
    return tuple(aval.shape) + (size,)


def _broadcast(value, aval, size):
    """An unbatched value → the same value repeated along a trailing batch axis."""
    shape = tuple(aval.shape)
    return lax.broadcast_in_dim(value, shape + (size,), tuple(range(len(shape))))


class _Evaluator:
    """Evaluates a jaxpr on values each either unbatched or carrying a trailing batch axis."""

    def __init__(self, size):
        self.size = size

    def run(self, closed: ClosedJaxpr, values, batched):
        """Returns (output values, output batched flags)."""
        jaxpr = closed.jaxpr
        env = {}

        def read(atom):
            if isinstance(atom, Literal):
                return atom.val, False
            return env[atom]

        for var, const in zip(jaxpr.constvars, closed.consts):
            env[var] = (const, False)
        for var, value, flag in zip(jaxpr.invars, values, batched):
            env[var] = (value, flag)
        for eqn in jaxpr.eqns:
            ins = [read(v) for v in eqn.invars]
            in_values = [v for v, _ in ins]
            in_flags = [f for _, f in ins]
            # The operations issued here carry the source line of the traced function's own
            # operation, so profiles and errors point at the dynamics, not at this module.
            with source_info_util.user_context(
                    eqn.source_info.traceback, name_stack=source_info_util.current_name_stack()):
                if not any(in_flags):
                    outs = _bind(eqn, in_values)
                    out_flags = None
                else:
                    outs, out_flags = self.apply(eqn, in_values, in_flags)
            if not eqn.primitive.multiple_results:
                outs = [outs]
                out_flags = None if out_flags is None else [out_flags]
            if out_flags is None:
                out_flags = [False] * len(outs)
            for var, value, flag in zip(eqn.outvars, outs, out_flags):
                env[var] = (value, flag)
        results = [read(v) for v in jaxpr.outvars]
        return [v for v, _ in results], [f for _, f in results]

    def apply(self, eqn, values, flags):
        """One equation with at least one batched input → (outputs, flags)."""
        name = eqn.primitive.name
        rule = _RULES.get(name)
        if rule is None and name in ELEMENTWISE:
            rule = _elementwise
        elif rule is None and name in SAME_AXES:
            rule = _same_axes
        if rule is not None:
            result = rule(self, eqn, values, flags)
            if result is not None:
                return result
        return self.fallback(eqn, values, flags)

    def fallback(self, eqn, values, flags):
        """`jax.vmap` of the primitive alone, the batch moved to the front and back again."""
        outs = jax.vmap(lambda *args: _bind(eqn, args),
                        in_axes=[-1 if f else None for f in flags], out_axes=-1,
                        axis_size=self.size)(*values)
        if eqn.primitive.multiple_results:
            return outs, [True] * len(outs)
        return outs, True

    def widen(self, values, flags, avals, wanted=None):
        """The values with a batch axis wherever `wanted` asks for one (everywhere when None):
        unbatched ones there are repeated along it."""
        wanted = [True] * len(values) if wanted is None else wanted
        return [_broadcast(v, a, self.size) if want and not f else v
                for v, f, a, want in zip(values, flags, avals, wanted)]

    def abstract_flags(self, closed: ClosedJaxpr, batched):
        """Which outputs of `closed` come out batched for these input flags (traces, no FLOPs)."""
        found = []

        def trace(*args):
            outs, out_flags = self.run(closed, args, batched)
            found.append(out_flags)
            return outs

        structs = [jax.ShapeDtypeStruct(_batched_shape(a, self.size) if f else a.shape, a.dtype)
                   for a, f in zip(closed.in_avals, batched)]
        jax.eval_shape(trace, *structs)
        return found[0]


def _bind(eqn, values):
    """The equation's primitive applied to `values`, its parameters turned back into what
    `bind` takes, as `jax.core.eval_jaxpr` does (custom_jvp_call, for one, is recorded with a
    jaxpr but bound with a function; older JAX also returns functions to pass first)."""
    bind_params = eqn.primitive.get_bind_params(eqn.params)
    subfuns, params = bind_params if isinstance(bind_params, tuple) else ((), bind_params)
    return eqn.primitive.bind(*subfuns, *values, **params)


def _avals(eqn):
    return [v.aval for v in eqn.invars]


def _elementwise(ev, eqn, values, flags):
    """Operands of one shape (or scalars, for clamp and select_n): bring every operand to the
    output's batched shape."""
    out_shape = tuple(eqn.outvars[0].aval.shape)
    full = []
    for value, flag, aval in zip(values, flags, _avals(eqn)):
        rank = len(aval.shape)
        dims = tuple(range(rank)) if rank == len(out_shape) else ()
        if flag:
            dims = dims + (len(out_shape),)
        if flag and rank == len(out_shape):
            full.append(value)
        else:
            full.append(lax.broadcast_in_dim(value, out_shape + (ev.size,), dims))
    return eqn.primitive.bind(*full, **eqn.params), True


def _same_axes(ev, eqn, values, flags):
    return eqn.primitive.bind(*values, **eqn.params), True


def _broadcast_in_dim(ev, eqn, values, flags):
    if len(values) > 1:
        return None
    params = dict(eqn.params)
    shape = tuple(params["shape"])
    params["shape"] = shape + (ev.size,)
    params["broadcast_dimensions"] = tuple(params["broadcast_dimensions"]) + (len(shape),)
    return lax.broadcast_in_dim_p.bind(values[0], **params), True


def _reshape(ev, eqn, values, flags):
    params = dict(eqn.params)
    if len(values) > 1 or params.get("dimensions") is not None:
        return None
    params["new_sizes"] = tuple(params["new_sizes"]) + (ev.size,)
    return eqn.primitive.bind(values[0], **params), True


def _slice(ev, eqn, values, flags):
    params = dict(eqn.params)
    params["start_indices"] = tuple(params["start_indices"]) + (0,)
    params["limit_indices"] = tuple(params["limit_indices"]) + (ev.size,)
    if params.get("strides") is not None:
        params["strides"] = tuple(params["strides"]) + (1,)
    return eqn.primitive.bind(values[0], **params), True


def _transpose(ev, eqn, values, flags):
    permutation = tuple(eqn.params["permutation"])
    return eqn.primitive.bind(values[0], permutation=permutation + (len(permutation),)), True


def _joined(ev, eqn, values, flags):
    """concatenate and stack: the joined axis lies before the trailing batch axis."""
    return eqn.primitive.bind(*ev.widen(values, flags, _avals(eqn)), **eqn.params), True


def _pad(ev, eqn, values, flags):
    if flags[1]:
        return None
    config = tuple(eqn.params["padding_config"]) + ((0, 0, 0),)
    return eqn.primitive.bind(values[0], values[1], padding_config=config), True


def _dynamic_slice(ev, eqn, values, flags):
    if any(flags[1:]):
        return None
    params = dict(eqn.params)
    params["slice_sizes"] = tuple(params["slice_sizes"]) + (ev.size,)
    zero = jnp.zeros((), values[1].dtype) if len(values) > 1 else 0
    return eqn.primitive.bind(values[0], *values[1:], zero, **params), True


def _dynamic_update_slice(ev, eqn, values, flags):
    if any(flags[2:]):
        return None
    operand, update = ev.widen(values[:2], flags[:2], _avals(eqn)[:2])
    zero = jnp.zeros((), values[2].dtype) if len(values) > 2 else 0
    return eqn.primitive.bind(operand, update, *values[2:], zero, **eqn.params), True


def _gather(ev, eqn, values, flags):
    """Unbatched indices into a batched operand: the batch becomes one more offset (slice) axis,
    taken whole and placed last in the output."""
    if flags[1]:
        return None
    params = dict(eqn.params)
    numbers = params["dimension_numbers"]
    out_rank = len(eqn.outvars[0].aval.shape)
    params["dimension_numbers"] = numbers._replace(
        offset_dims=tuple(numbers.offset_dims) + (out_rank,))
    params["slice_sizes"] = tuple(params["slice_sizes"]) + (ev.size,)
    return eqn.primitive.bind(values[0], values[1], **params), True


def _scatter(ev, eqn, values, flags):
    """Unbatched indices: operand and updates both batched, the batch one more window axis."""
    if flags[1]:
        return None
    avals = _avals(eqn)
    operand, updates = ev.widen([values[0], values[2]], [flags[0], flags[2]],
                               [avals[0], avals[2]])
    params = dict(eqn.params)
    numbers = params["dimension_numbers"]
    params["dimension_numbers"] = numbers._replace(
        update_window_dims=tuple(numbers.update_window_dims) + (len(avals[2].shape),))
    return eqn.primitive.bind(operand, values[1], updates, **params), True


def _dot_general(ev, eqn, values, flags):
    """A small matrix product (contracted size ≤ SMALL_CONTRACTION) as a sum of elementwise
    products, so that it fuses and runs along the batch like `spatial.mat_mat`. Larger ones (a
    network layer) go through `jax.vmap`, which folds the batch into one big product."""
    (lhs_c, rhs_c), (lhs_b, rhs_b) = eqn.params["dimension_numbers"]
    lhs_aval, rhs_aval = _avals(eqn)
    contracted = [lhs_aval.shape[d] for d in lhs_c]
    if int(np.prod(contracted, dtype=int)) > SMALL_CONTRACTION:
        return None

    def arrange(value, flag, aval, batch_dims, contract_dims):
        """value → (batch dims, free dims, contracted dims, batch-of-examples axis), and the
        number of its free dims."""
        rank = len(aval.shape)
        free = [d for d in range(rank) if d not in batch_dims and d not in contract_dims]
        value = value if flag else value[..., None]
        order = list(batch_dims) + free + list(contract_dims) + [rank]
        return jnp.transpose(value, order), len(free)

    def ones_at(value, at, count):
        """`count` size-1 axes inserted before axis `at`."""
        return value.reshape(value.shape[:at] + (1,) * count + value.shape[at:])

    lhs, lhs_free = arrange(values[0], flags[0], lhs_aval, lhs_b, lhs_c)
    rhs, rhs_free = arrange(values[1], flags[1], rhs_aval, rhs_b, rhs_c)
    # Both as (batch dims, lhs free, rhs free, contracted, examples), size 1 where absent.
    lhs = ones_at(lhs, len(lhs_b) + lhs_free, rhs_free)
    rhs = ones_at(rhs, len(rhs_b), lhs_free)
    out_dtype = eqn.outvars[0].aval.dtype
    lhs, rhs = lhs.astype(out_dtype), rhs.astype(out_dtype)
    n_contracted, rank = len(contracted), lhs.ndim
    product = lhs * rhs
    if n_contracted == 0:
        return product, True
    axes = tuple(range(rank - 1 - n_contracted, rank - 1))
    return jnp.sum(product, axis=axes), True


def _inline(ev, eqn, values, flags):
    """A nested jit: evaluate its program in place."""
    return ev.run(eqn.params["jaxpr"], values, flags)


def _scan(ev, eqn, values, flags):
    """lax.scan: the scanned axis is the first, so per-step slices keep the batch last. A carry
    that any step makes batched is batched from the start (found by a fixed point, as vmap does).
    """
    p = eqn.params
    body, n_consts, n_carry = p["jaxpr"], p["num_consts"], p["num_carry"]
    avals = _avals(eqn)
    const_flags = list(flags[:n_consts])
    carry_flags = list(flags[n_consts:n_consts + n_carry])
    xs_flags = list(flags[n_consts + n_carry:])
    while True:
        out_flags = ev.abstract_flags(body, const_flags + carry_flags + xs_flags)
        merged = [a or b for a, b in zip(carry_flags, out_flags[:n_carry])]
        if merged == carry_flags:
            break
        carry_flags = merged
    ys_flags = out_flags[n_carry:]
    consts = values[:n_consts]
    carry_avals = avals[n_consts:n_consts + n_carry]
    init = ev.widen(values[n_consts:n_consts + n_carry], flags[n_consts:n_consts + n_carry],
                    carry_avals, carry_flags)
    xs = values[n_consts + n_carry:]

    def step(carry, x):
        outs, out = ev.run(body, list(consts) + list(carry) + list(x),
                           const_flags + carry_flags + xs_flags)
        return ev.widen(outs[:n_carry], out[:n_carry], carry_avals, carry_flags), outs[n_carry:]

    carry, ys = lax.scan(step, init, xs, length=p["length"], reverse=p["reverse"],
                         unroll=p["unroll"])
    return list(carry) + list(ys), carry_flags + ys_flags


def _cond(ev, eqn, values, flags):
    """lax.cond/switch: with an unbatched index a switch on batched branches; with a batched
    index, every branch is evaluated and the results selected per example (as vmap does)."""
    branches = eqn.params["branches"]
    index, operands = values[0], values[1:]
    index_flag, op_flags = flags[0], flags[1:]
    out_avals = [v.aval for v in eqn.outvars]
    if index_flag:
        results = [ev.run(b, operands, op_flags) for b in branches]
        outs = []
        for k, aval in enumerate(out_avals):
            cases = ev.widen([vals[k] for vals, _ in results], [fl[k] for _, fl in results],
                             [aval] * len(results))
            which = lax.broadcast_in_dim(index, _batched_shape(aval, ev.size),
                                         (len(aval.shape),))
            outs.append(lax.select_n(which, *cases))
        return outs, [True] * len(outs)
    out_flags = [any(fs) for fs in zip(*[ev.abstract_flags(b, op_flags) for b in branches])]

    def branch_fun(closed):
        def run(*ops):
            outs, fl = ev.run(closed, ops, op_flags)
            return ev.widen(outs, fl, out_avals, out_flags)
        return run
    return lax.switch(index, [branch_fun(b) for b in branches], *operands), out_flags


_RULES = {
    "broadcast_in_dim": _broadcast_in_dim, "reshape": _reshape, "slice": _slice,
    "transpose": _transpose, "concatenate": _joined, "stack": _joined, "pad": _pad,
    "dynamic_slice": _dynamic_slice, "dynamic_update_slice": _dynamic_update_slice,
    "dot_general": _dot_general, "gather": _gather, "scatter": _scatter,
    "scatter-add": _scatter, "scatter-mul": _scatter, "scatter-min": _scatter,
    "scatter-max": _scatter, "scan": _scan, "cond": _cond,
    "jit": _inline, "pjit": _inline,                     # a nested jit (named pjit in older jax)
}


def vmap(fun, in_axes=0, chunk=None):
    """`jax.vmap(fun, in_axes)` computed with the batch innermost, `chunk` members at a time.

    `in_axes` is 0 or None, or a tuple with one of them per positional argument (applying to the
    whole argument). Outputs carry the batch on axis 0, as with `jax.vmap`.

    A batch larger than `chunk` is computed in pieces of `chunk` members, one after another
    under `lax.map` (the last piece padded with copies of the last member, whose results are
    dropped), so that the arrays one operation works on stay in the CPU's cache however large
    the batch (docs/benchmarks.md, "Chunked batches"). `chunk` None is `default_chunk()`; pass
    the batch size, or more, to compute it in one piece. The results are the same either way.
    """
    def batched(*args):
        axes = in_axes if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(args)
        if len(axes) != len(args):
            raise ValueError(f"in_axes has {len(axes)} entries for {len(args)} arguments")
        leaves, flags, examples = [], [], []
        for arg, axis in zip(args, axes):
            if axis not in (0, None):
                raise ValueError(f"batch_last.vmap supports in_axes 0 or None, not {axis!r}")
            for leaf in jax.tree_util.tree_leaves(arg):
                leaf = jnp.asarray(leaf)
                leaves.append(leaf)
                flags.append(axis == 0)
                examples.append(jax.ShapeDtypeStruct(leaf.shape[1:] if axis == 0 else leaf.shape,
                                                     leaf.dtype))
        sizes = {leaf.shape[0] for leaf, f in zip(leaves, flags) if f}
        if len(sizes) != 1:
            raise ValueError(f"batch_last.vmap needs one batch size, got {sorted(sizes)}")
        size = sizes.pop()
        trees = [jax.tree_util.tree_structure(arg) for arg in args]

        def one_example(*flat):
            rebuilt, start = [], 0
            for tree in trees:
                leaves_here = flat[start:start + tree.num_leaves]
                rebuilt.append(jax.tree_util.tree_unflatten(tree, leaves_here))
                start += tree.num_leaves
            return fun(*rebuilt)

        closed, out_shape = jax.make_jaxpr(one_example, return_shape=True)(*examples)
        out_tree = jax.tree_util.tree_structure(out_shape)
        piece = default_chunk() if chunk is None else _check_chunk(chunk)

        def evaluate(batched_leaves, count):
            """The outputs, batch first, for `count` members (the batched leaves' axis 0)."""
            it = iter(batched_leaves)
            values = [jnp.moveaxis(next(it), 0, -1) if f else v for v, f in zip(leaves, flags)]
            outs, out_flags = _Evaluator(count).run(closed, values, flags)
            return [jnp.moveaxis(v, -1, 0) if f else jnp.broadcast_to(v, (count,) + v.shape)
                    for v, f in zip(outs, out_flags)]

        batched_leaves = [v for v, f in zip(leaves, flags) if f]
        if size <= piece:
            return jax.tree_util.tree_unflatten(out_tree, evaluate(batched_leaves, size))
        pieces = -(-size // piece)
        padding = pieces * piece - size

        def split(v):
            if padding:
                v = jnp.concatenate([v, jnp.repeat(v[-1:], padding, axis=0)])
            return v.reshape(pieces, piece, *v.shape[1:])

        outs = lax.map(lambda part: evaluate(part, piece), [split(v) for v in batched_leaves])
        outs = [v.reshape(pieces * piece, *v.shape[2:])[:size] for v in outs]
        return jax.tree_util.tree_unflatten(out_tree, outs)
    return batched


# Members computed at once by `vmap` when its caller does not say: the humanoid's contact step at
# batch 4,096 ran 1.4–1.6× faster in pieces of 128, 256 or 512 than in one piece, the three
# within the VM's noise of each other (docs/benchmarks.md, "Chunked batches"); 256 is the middle.
# The environment variable overrides it for every caller that does not say.
DEFAULT_CHUNK = 256
CHUNK_VARIABLE = "TAKEOFF_BATCH_CHUNK"


def default_chunk() -> int:
    """The members `vmap` computes at once by default: $TAKEOFF_BATCH_CHUNK if set, otherwise
    `DEFAULT_CHUNK`."""
    text = os.environ.get(CHUNK_VARIABLE, "").strip()
    if not text:
        return DEFAULT_CHUNK
    try:
        return _check_chunk(int(text))
    except ValueError:
        raise ValueError(f"{CHUNK_VARIABLE} must be a positive whole number of batch members; "
                         f"got {text!r}") from None


def _check_chunk(chunk) -> int:
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive whole number of batch members; got {chunk!r}")
    return int(chunk)
