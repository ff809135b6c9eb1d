"""`jaxsim.batch_last.vmap` against `jax.vmap`: the same numbers from every rule, the simulator's
step included, its gradients too, and clear errors."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import dropped_humanoids
from jaxsim import batch_last, simulation
from jaxsim.dynamics.common import cholesky_solve

RNG = np.random.default_rng(0)
BATCH = 5


def batched(*shape):
    return jnp.asarray(RNG.normal(size=(BATCH,) + shape))


def assert_same(fun, *args, in_axes=0, tol=1e-13):
    """batch_last.vmap(fun) against jax.vmap(fun); `tol` leaves room for XLA fusing the two
    programs differently (a multiply-add contracted in one and not the other)."""
    expected = jax.vmap(fun, in_axes=in_axes)(*args)
    got = batch_last.vmap(fun, in_axes=in_axes)(*args)
    jax.tree.map(lambda e, g: np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=tol,
                                                         atol=tol), expected, got)
    assert jax.tree.structure(expected) == jax.tree.structure(got)


CONSTANT = jnp.asarray(RNG.normal(size=(3, 4)))


FALLS_BACK = "falls back"        # cases that go through jax.vmap on purpose (or a set: which)


@pytest.fixture
def fallbacks(monkeypatch):
    """The primitives that `batch_last` evaluated through `jax.vmap` (no rule of its own)."""
    seen = []
    real_fallback = batch_last._Evaluator.fallback

    def counting(self, eqn, values, flags):
        seen.append(eqn.primitive.name)
        return real_fallback(self, eqn, values, flags)
    monkeypatch.setattr(batch_last._Evaluator, "fallback", counting)
    return seen


@pytest.mark.parametrize("fun, expect", [
    (lambda x: jnp.sin(x) * CONSTANT + 2.0, None),                    # elementwise, constants
    (lambda x: jnp.clip(x, -0.5, CONSTANT), None),                    # clamp, select
    (lambda x: jnp.where(x > 0, x, CONSTANT), None),
    (lambda x: x[..., None] * jnp.ones(5), None),                     # broadcast_in_dim
    (lambda x: x.reshape(2, 6).T[1:, ::2], None),                     # reshape, transpose, slice
    (lambda x: jnp.concatenate([x, CONSTANT, x[:1]], 0), None),
    (lambda x: jnp.stack([x, CONSTANT], -1), None),
    (lambda x: jnp.pad(x, ((1, 0), (2, 1))), None),
    (lambda x: (x.sum(0), x.max(1), jnp.argmax(x, 1), jnp.cumsum(x, 1)), None),
    (lambda x: x[jnp.array([2, 0, 0])][:, jnp.array([3, 1])], None),  # gather
    (lambda x: CONSTANT.at[jnp.array([1, 2])].set(x[:2]), None),      # scatter into a constant
    (lambda x: x.at[:, jnp.array([0, 0, 3])].add(1.0), None),         # scatter-add
    # lt_to and le_to; the binary search gathers at per-example indices, which falls back
    (lambda x: jnp.searchsorted(jnp.sort(CONSTANT.ravel()), x, side="right"), {"gather"}),
    (lambda x: jax.lax.dynamic_slice(x, (1, 2), (2, 2)), None),
    (lambda x: jax.lax.dynamic_update_slice(CONSTANT, x[:1, :2], (2, 1)), None),
    (lambda x: jax.jit(lambda y: jnp.exp(y).sum())(x), None),         # nested jit
    (lambda x: jax.nn.relu(x) + jax.nn.softplus(x), {"custom_jvp_call"}),    # custom derivatives
    (lambda x: x * jax.nn.relu(CONSTANT), None),                      # … on shared values
    (lambda x: (x @ CONSTANT.T, CONSTANT.T @ x, x @ x.T, x[0] @ x[1]), None),   # small dots
    (lambda x: jnp.einsum("ij,kj->ik", x, CONSTANT), None),
    (lambda x: jnp.einsum("ijk,ikl->ijl", x.reshape(2, 2, 3), x.reshape(2, 3, 2)), None),
    (lambda x: x.ravel() @ jnp.ones((12, 70)) @ jnp.ones((70, 2)), FALLS_BACK),  # large dot
    (lambda x: jnp.linalg.solve(x[:, :3] + 4 * jnp.eye(3), x[:, 3]), FALLS_BACK),   # LAPACK
])
def test_each_rule_matches_vmap(fun, expect, fallbacks):
    assert_same(fun, batched(3, 4))
    if isinstance(expect, set):        # exactly these primitives fall back
        assert set(fallbacks) == expect, fallbacks
    else:
        assert bool(fallbacks) == (expect == FALLS_BACK), fallbacks


def test_a_scan_whose_carry_becomes_batched_and_unbatched_inputs(fallbacks):
    def fun(x, shared):
        def body(carry, row):
            total, count = carry                  # total starts unbatched, becomes batched
            return (total * 0.5 + row, count + 1), total.sum()
        return jax.lax.scan(body, (jnp.zeros(4), 0), x * shared)
    assert_same(fun, batched(6, 4), jnp.asarray(RNG.normal(size=4)), in_axes=(0, None))
    assert fallbacks == []


@pytest.mark.parametrize("index_batched", [False, True])
def test_cond_with_a_shared_or_a_per_example_predicate(index_batched, fallbacks):
    def fun(x, flag):
        return jax.lax.cond(flag > 0, lambda: (x * 2.0, 1.0), lambda: (-x, x.sum()))
    flags = jnp.asarray([1.0, -1.0, 1.0, -1.0, 1.0]) if index_batched else jnp.asarray(1.0)
    assert_same(fun, batched(3), flags, in_axes=(0, 0 if index_batched else None))
    assert fallbacks == []


def test_unbatched_outputs_are_repeated_along_the_batch():
    assert_same(lambda x, c: (x + 1, c * 2), batched(2), jnp.ones(3), in_axes=(0, None))


def test_cholesky_solve_matches_lapack():
    a = RNG.normal(size=(4, 6, 6))
    spd = jnp.asarray(a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(6))
    b = jnp.asarray(RNG.normal(size=(4, 6)))
    np.testing.assert_allclose(np.asarray(cholesky_solve(spd, b)),
                               np.asarray(jnp.linalg.solve(spd, b[..., None])[..., 0]),
                               rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("method, falls_back", [
    ("maba", set()),                                    # every primitive of the step has a rule
    ("dense", {"cholesky", "triangular_solve"}),        # LAPACK, per example
])
def test_the_contact_step_matches_vmap(method, falls_back, fallbacks):
    model, world, states, targets = dropped_humanoids(40, 4, height=0.03, jitter=True)
    def run(state):
        return simulation.simulate(model, world, state, targets, 1 / 600, method)[0]
    expected = jax.jit(jax.vmap(run))(states)
    got = jax.jit(batch_last.vmap(run))(states)
    assert bool(jnp.any(got.touching))            # the rollout reached the ground
    assert set(fallbacks) == falls_back
    for e, g in zip(jax.tree.leaves(expected), jax.tree.leaves(got)):
        np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=0, atol=1e-10)


def test_gradients_through_the_step_match_vmap():
    model, world, states, targets = dropped_humanoids(10, 3, height=0.03, jitter=True)
    model = model.with_traversal(False)        # the same gradient, compiled in half the time

    def final_height(vmap, lift):
        moved = states.replace(q=states.q.at[:, 1].add(lift))
        final = vmap(lambda s: simulation.simulate(model, world, s, targets, 1 / 600)[0])(moved)
        return jnp.sum(final.q[:, 1] * jnp.arange(1.0, 4.0))
    expected = jax.jit(jax.grad(lambda lift: final_height(jax.vmap, lift)))(0.01)
    got = jax.jit(jax.grad(lambda lift: final_height(batch_last.vmap, lift)))(0.01)
    assert np.isfinite(float(expected))
    np.testing.assert_allclose(float(got), float(expected), rtol=1e-9)


@jax.custom_jvp
def doubled_slope(x):
    return x


doubled_slope.defjvp(lambda primals, tangents: (primals[0], 2.0 * tangents[0]))


@jax.custom_vjp
def tripled_cotangent(x):
    return x


tripled_cotangent.defvjp(lambda x: (x, None), lambda _, cotangent: (3.0 * cotangent,))


def test_custom_derivative_rules_are_kept():
    """A function's own derivative rules survive, as under jax.vmap (here they differ from the
    derivative of what the function computes, 1, so a lost rule would show)."""
    xs = batched(3)
    for fun in (lambda x: doubled_slope(x) * x, lambda x: tripled_cotangent(x) * x):
        def total(vmap, xs):
            return vmap(fun)(xs).sum()
        expected = jax.grad(lambda v: total(jax.vmap, v))(xs)
        np.testing.assert_allclose(np.asarray(jax.grad(lambda v: total(batch_last.vmap, v))(xs)),
                                   np.asarray(expected), rtol=1e-13)
        assert not np.allclose(np.asarray(expected), 2 * np.asarray(xs))


def test_bad_arguments_are_refused_clearly():
    with pytest.raises(ValueError, match="in_axes 0 or None"):
        batch_last.vmap(jnp.sin, in_axes=1)(batched(2))
    with pytest.raises(ValueError, match="one batch size"):
        batch_last.vmap(jnp.add)(batched(2), jnp.ones((3, 2)))
    with pytest.raises(ValueError, match="2 entries for 1 arguments"):
        batch_last.vmap(jnp.sin, in_axes=(0, None))(batched(2))


@pytest.mark.parametrize("chunk", [1, 3, 4, 7, 40])     # pieces with padding, exact, one piece
def test_a_batch_computed_in_chunks_gives_the_same_states(chunk):
    """The contact rollout of 7 dropped humanoids, in pieces of `chunk` (the last padded when
    they do not divide 7) against the whole batch at once and against jax.vmap, in float64."""
    model, world, states, targets = dropped_humanoids(10, 7, height=0.0005, jitter=True)
    whole = simulation.simulate_batch(model, world, states, targets, 1 / 600, chunk=7)
    pieces = simulation.simulate_batch(model, world, states, targets, 1 / 600, chunk=chunk)
    by_vmap = simulation.simulate_batch(model, world, states, targets, 1 / 600, batch_last=False)
    assert bool(jnp.any(whole[1].touching))
    for w, p, v in zip(jax.tree.leaves(whole), jax.tree.leaves(pieces),
                       jax.tree.leaves(by_vmap)):
        assert p.shape == w.shape
        np.testing.assert_allclose(np.asarray(p), np.asarray(w), rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(p), np.asarray(v), rtol=0, atol=1e-10)


def test_chunks_keep_unbatched_outputs_gradients_and_the_default():
    xs = batched(3)
    for chunk in (2, 5):
        got = batch_last.vmap(lambda x, c: (jnp.sin(x) * c, c), in_axes=(0, None),
                              chunk=chunk)(xs, 2.0)
        np.testing.assert_allclose(np.asarray(got[0]), np.sin(np.asarray(xs)) * 2, rtol=1e-15)
        np.testing.assert_array_equal(np.asarray(got[1]), np.full(BATCH, 2.0))
        grad = jax.grad(lambda v: batch_last.vmap(lambda x: jnp.sum(x**3), chunk=chunk)(v).sum())
        np.testing.assert_allclose(np.asarray(grad(xs)), 3 * np.asarray(xs) ** 2, rtol=1e-14)
    assert batch_last.default_chunk() == batch_last.DEFAULT_CHUNK


def test_a_bad_chunk_is_refused_clearly(monkeypatch):
    for chunk in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="chunk must be a positive whole number"):
            batch_last.vmap(jnp.sin, chunk=chunk)(batched(2))
    monkeypatch.setenv(batch_last.CHUNK_VARIABLE, "many")
    with pytest.raises(ValueError, match="TAKEOFF_BATCH_CHUNK must be .* got 'many'"):
        batch_last.default_chunk()
    monkeypatch.setenv(batch_last.CHUNK_VARIABLE, "64")
    assert batch_last.default_chunk() == 64


TWO_DEVICES = r"""
import jax
import numpy as np
from conftest import dropped_humanoids     # (float64; one CPU device, overridden here)
jax.config.update("jax_num_cpu_devices", 2)
from jaxsim import simulation
assert jax.device_count() == 2
model, world, states, targets = dropped_humanoids(10, 6, height=0.0005, jitter=True)
one = simulation.simulate_batch(model, world, states, targets, 1 / 600, chunk=2)
two = simulation.simulate_batch(model, world, states, targets, 1 / 600, chunk=2, devices=2)
assert len(two[0].q.sharding.device_set) == 2
assert bool(np.any(np.asarray(one[1].touching)))
for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(two)):
    np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-12)
try:
    simulation.simulate_batch(model, world, jax.tree.map(lambda x: x[:5], states), targets,
                              1 / 600, devices=2)
except ValueError as error:
    assert "a batch of 5 cannot be split evenly over devices = 2" in str(error), error
else:
    raise AssertionError("an uneven split was accepted")
print("ok")
"""


def test_a_batch_split_over_two_devices_gives_the_same_states():
    """simulate_batch with the batch over two host devices (each chunking its own share) against
    one device, in float64, in a process started with two CPU devices."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    tests = Path(__file__).resolve().parent
    result = subprocess.run([sys.executable, "-c", TWO_DEVICES], cwd=tests, env=env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-3000:]
