"""The simulator's XLA compiler options: they leave the results alone, they stay out of nested
programs, and they can be refused."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import dropped_humanoids
from jaxsim import simulation, xla_options

DT = 1 / 600


def test_the_options_leave_a_contact_rollout_unchanged():
    options = xla_options.simulation_options()
    if jax.default_backend() == "cpu" and not os.environ.get(xla_options.OPT_OUT_VARIABLE):
        # The comparison means something only where the options are in use. The jaxlib that
        # CI installs accepts them; one that drops them should fail here, not go unnoticed.
        assert options == xla_options.cpu_options()
    model, world, states, targets = dropped_humanoids(120, 2, height=0.05)

    def final_q(states):       # simulate inside this jit: the outer program's options apply
        return jax.vmap(lambda s: simulation.simulate(model, world, s, targets, DT)[0].q)(states)
    default = jax.jit(final_q)(states)
    tuned = jax.jit(final_q, compiler_options=options)(states)
    # simulate_batch at the top level: the options and the batch innermost together
    batch = simulation.simulate_batch(model, world, states, targets, DT)[0].q
    assert bool(jnp.all(jnp.isfinite(default)))
    np.testing.assert_allclose(np.asarray(tuned), np.asarray(default), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(batch), np.asarray(default), rtol=0, atol=1e-9)


def test_simulate_takes_the_options_only_as_the_top_level_program():
    model, world, states, targets = dropped_humanoids(3, 2, height=0.05)
    batch = simulation.simulate_batch(model, world, states, jnp.stack([targets, targets]), DT)[0]
    # Inside vmap and jit the arguments are tracers; JAX refuses compiler options there.
    nested = jax.jit(jax.vmap(lambda s: simulation.simulate(model, world, s, targets, DT)[0]))
    np.testing.assert_allclose(np.asarray(nested(states).q), np.asarray(batch.q), atol=1e-12)
    # Inside a jit whose arguments are all constants, nothing is a tracer; still nested.
    first = jax.tree.map(lambda x: x[0], states)
    constant = jax.jit(lambda: simulation.simulate(model, world, first, targets, DT)[0].q)()
    np.testing.assert_allclose(np.asarray(constant), np.asarray(batch.q[0]), atol=1e-12)


def test_methods_but_sparse_compile_with_the_options():
    seen = []
    real_jit = jax.jit

    def spy(fun, **kwargs):
        seen.append(kwargs.get("compiler_options"))
        return real_jit(fun, **kwargs)

    def scaled(x, method="maba"):
        return 2 * x

    options = xla_options.simulation_options()        # probed before the spy goes in
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(jax, "jit", spy)
        double = xla_options.jit(scaled, static_argnames=("method",))
        assert seen == [None]              # the plain jit; the tuned one waits for a first call
        assert float(double(jnp.float64(1.5), method="sparse")) == 3.0
        assert seen == [None]
        assert float(double(jnp.float64(1.5))) == 3.0
    assert seen == [None, options]
    assert float(double.lower(jnp.float64(2.0)).compile()(jnp.float64(2.0))) == 4.0
    assert xla_options.options_for("sparse") == {}
    assert xla_options.options_for("maba") == xla_options.options_for("dense") == options


def test_the_environment_can_ask_for_xla_defaults(monkeypatch):
    monkeypatch.setenv(xla_options.OPT_OUT_VARIABLE, "1")
    assert xla_options._accepted_options.__wrapped__() == {}


def test_options_this_jaxlib_refuses_are_dropped_with_a_warning(monkeypatch):
    monkeypatch.setattr(xla_options, "SIMULATION_CPU_OPTIONS",
                        {"xla_cpu_no_such_option_for_takeoff": True})
    if jax.default_backend() != "cpu":
        pytest.skip("the options are only tried on the CPU backend")
    with pytest.warns(UserWarning, match="rejects the simulator's XLA options"):
        assert xla_options._accepted_options.__wrapped__() == {}


def test_the_vector_width_follows_the_cpus_features():
    avx512 = "processor\t: 0\nflags\t\t: fpu sse2 avx avx2 avx512f avx512bw\n"
    avx2 = "processor\t: 0\nflags\t\t: fpu sse2 avx fma avx2\n"
    arm = "processor\t: 0\nFeatures\t: fp asimd evtstrm\n"
    assert xla_options.vector_bits(avx512) == 512
    assert xla_options.vector_bits(avx2) == 256
    assert xla_options.vector_bits(arm) == 128
    assert xla_options.vector_bits("processor\t: 0\n") is None
    bits = xla_options.vector_bits()
    assert xla_options.cpu_options().get("xla_cpu_prefer_vector_width") == bits
