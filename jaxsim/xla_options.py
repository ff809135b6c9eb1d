"""XLA compiler options under which the simulator's compiled programs run faster on CPU.

The step is a long chain of small fused loops (docs/benchmarks.md, "Where the step's time
goes"). Three of XLA's CPU code-generation options change how well they run:

- `xla_cpu_use_fusion_emitters`: XLA's newer fusion emitters. The older loop emitters run the
  step faster and compile it faster; with the batch innermost (`jaxsim.batch_last`, as
  `simulate_batch` computes) they are what makes that layout pay: under the newer emitters it
  is slower than `jax.vmap`'s.
- `xla_cpu_experimental_ynn_fusion_type`: which fusions XLA hands to the YNNPACK library. By
  default that includes elementwise fusions, which here are small and slower there; we keep
  only matrix products (`LIBRARY_FUSION_TYPE_DOT`).
- `xla_cpu_prefer_vector_width`: the widest vectors this CPU has (`vector_bits`: 512 bits
  with AVX-512, 256 with AVX2, as /proc/cpuinfo lists its features); with the batch innermost
  the loops run along the batch and fill them (512 against XLA's default 256 gave about +10%
  on the contact step at batch 4096 on an AVX-512 Xeon). Where the features cannot be read,
  the option is left out and XLA chooses.

The figures, and the commands that measure them, are in docs/benchmarks.md ("XLA's CPU code
generators" and "The batch innermost, by interpreting the program"). The options change how
loops are compiled, not which operations run; fast-math stays off, and in float64 a contact
rollout agrees with XLA's defaults to 1e-9 (tests/test_xla_options.py).

`simulation.simulate` and `simulate_batch` compile with them for every method but `sparse`,
whose LTDL factorisation runs slower under them; the training iteration's rollout too (2.4× as
fast), but not its PPO update, which runs 1.2–1.5× slower under them and is compiled as a
second program with XLA's defaults (`agents.rl.trainer.Trainer.iteration`). A caller can
pass `simulation_options()` to its own `jax.jit(..., compiler_options=...)` when its program is
mostly simulation. Inside an outer `jit` the outer program's options apply.

Set `TAKEOFF_XLA_DEFAULTS=1` in the environment to compile with XLA's defaults instead, for
comparison. On other backends, and with a jaxlib that does not know the options, they are not
used.
"""

import functools
import inspect
import os
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
from jax._src import core as jax_core

SIMULATION_CPU_OPTIONS = {          # and the vector width, by the CPU: see `cpu_options`
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_DOT",
}
# /proc/cpuinfo's feature flags, widest first, and the vector bits each gives.
VECTOR_FEATURES = (("avx512f", 512), ("avx2", 256), ("avx", 256), ("sse2", 128), ("asimd", 128))
OPT_OUT_VARIABLE = "TAKEOFF_XLA_DEFAULTS"
# The methods compiled with the options: all but sparse (MABA, explicit PD followed by ABA, ABA,
# and dense CRBA + Cholesky).
TUNED_METHODS = ("maba", "pd", "aba", "dense")


def simulation_options() -> dict:
    """The compiler options for a program that is mostly simulation: `cpu_options()` on the
    CPU backend when this jaxlib accepts them, otherwise (or when the environment sets
    TAKEOFF_XLA_DEFAULTS=1) none. Decided once per process; each call returns a fresh dict."""
    return dict(_accepted_options())


def cpu_options() -> dict:
    """`SIMULATION_CPU_OPTIONS` with the vector width this CPU prefers (`vector_bits`), where
    it is known."""
    bits = vector_bits()
    return {**SIMULATION_CPU_OPTIONS,
            **({"xla_cpu_prefer_vector_width": bits} if bits else {})}


def vector_bits(cpuinfo: str | None = None) -> int | None:
    """The width in bits of the widest vector registers this CPU has, from the feature flags
    of /proc/cpuinfo (or the text given): 512 with AVX-512, 256 with AVX2, …; None where
    they cannot be read (not Linux) or list none of `VECTOR_FEATURES`."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return None
    flags = set()
    for line in cpuinfo.splitlines():
        name, _, value = line.partition(":")
        if name.strip() in ("flags", "Features"):      # x86, ARM
            flags.update(value.split())
    return next((bits for feature, bits in VECTOR_FEATURES if feature in flags), None)


@functools.cache
def _accepted_options() -> dict:
    if os.environ.get(OPT_OUT_VARIABLE, "") not in ("", "0") or jax.default_backend() != "cpu":
        return {}
    try:
        options = cpu_options()
        jax.jit(jnp.sin, compiler_options=options).lower(jnp.zeros(2)).compile()
    except Exception as error:              # an unknown option is a runtime error from XLA
        warnings.warn(f"this jaxlib rejects the simulator's XLA options ({error}); "
                      "compiling with XLA's defaults", stacklevel=3)
        return {}
    return options


def _at_top_level(args, kwargs) -> bool:
    """Whether a call runs outside every JAX transformation (jit, vmap, grad, scan, …). JAX's
    own test for that is private, so when it is missing, tracer arguments are the sign."""
    clean = getattr(jax_core, "trace_state_clean", None)
    if clean is not None:
        return clean()
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))


def options_for(method: str) -> dict:
    """`simulation_options()` for a method in `TUNED_METHODS`, otherwise none."""
    return simulation_options() if method in TUNED_METHODS else {}


def jit(fun, **jit_kwargs):
    """`jax.jit(fun, **jit_kwargs)` for a function with a `method` argument: compiled with
    `simulation_options()` when called at the top level with a method in `TUNED_METHODS`.
    Called inside another transformation it is the plain `jax.jit`, as JAX accepts compiler
    options only on the program it compiles. The options are looked up
    at the first call, not at import, so that importing the simulator starts no backend."""
    signature = inspect.signature(fun)
    plain = jax.jit(fun, **jit_kwargs)

    @functools.cache
    def tuned():
        return jax.jit(fun, compiler_options=simulation_options(), **jit_kwargs)

    def chosen(args, kwargs):
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        use_options = (bound.arguments["method"] in TUNED_METHODS
                       and _at_top_level(args, kwargs))
        return tuned() if use_options else plain

    @functools.wraps(fun)
    def call(*args, **kwargs):
        return chosen(args, kwargs)(*args, **kwargs)

    def lower(*args, **kwargs):
        """Ahead-of-time lowering, as `jax.jit(...).lower`, with the same choice of options."""
        return chosen(args, kwargs).lower(*args, **kwargs)
    call.lower = lower
    return call
