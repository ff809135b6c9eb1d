"""Does putting the batch innermost make XLA's fused loops over small matrices faster on CPU?

The dynamics are written per character and vmapped, so every batched array has the batch as its
leading (outermost) axis and 6×6 or 3×3 matrices as its minor axes, which do not fill the CPU's
vector lanes. This measures the alternative layout on the kernel that dominates the step's profile:
a chain of `--chain` dependent 6×6 products, y ← x_k y / 2 + x_k, each product written as
`jaxsim.spatial.mat_mat` writes it (a sum of elementwise products, so it fuses), over a batch of B
matrices stored either as (B, 6, 6) ("batch-major", as vmap gives) or as (6, 6, B) ("batch-minor").
Also timed: the same chain with `jnp.einsum` (a batched `dot`), as a reference.

Run:  python benchmarks/layout.py [--batch 512 4096 16384] [--repeats 20]
Prints a markdown table: median milliseconds per call (compile time apart) and GFlop/s.
"""

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import allocator
from jaxsim.spatial import mat_mat
from spd import machine_info, markdown_table

SIZE = 6


def mat_mat_batch_minor(a, b):
    """a @ b for matrices stored as (n, n, batch): the same sum of products as mat_mat, with the
    batch as the innermost axis."""
    return sum(a[:, k:k + 1] * b[k:k + 1, :] for k in range(a.shape[1]))


def chain(product, xs, y):
    for x in xs:                     # a fixed, short chain, unrolled on purpose: one kernel each
        y = product(x, y) * 0.5 + x
    return y


LAYOUTS = {
    "batch-major (B, 6, 6)": (mat_mat, lambda a: a),
    "batch-minor (6, 6, B)": (mat_mat_batch_minor, lambda a: jnp.moveaxis(a, 0, -1)),
    "einsum (B, 6, 6)": (lambda a, b: jnp.einsum("bij,bjk->bik", a, b), lambda a: a),
}


def time_layout(product, arrange, xs, y, repeats):
    """Compile seconds and the median seconds of `repeats` calls of the jitted chain."""
    args = ([arrange(x) for x in xs], arrange(y))
    start = time.perf_counter()
    compiled = jax.jit(lambda xs, y: chain(product, xs, y)).lower(*args).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - start)
    return compile_s, statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[512, 4096, 16384])
    parser.add_argument("--chain", type=int, default=20, help="dependent products per call")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = []
    for batch in args.batch:
        xs = [jnp.asarray(rng.standard_normal((batch, SIZE, SIZE)), jnp.float32)
              for _ in range(args.chain)]
        y = jnp.asarray(rng.standard_normal((batch, SIZE, SIZE)), jnp.float32)
        flops = args.chain * batch * (2 * SIZE ** 3 + 2 * SIZE ** 2)
        for name, (product, arrange) in LAYOUTS.items():
            compile_s, seconds = time_layout(product, arrange, xs, y, args.repeats)
            rows.append([str(batch), name, f"{1e3 * seconds:.2f}", f"{flops / seconds / 1e9:.1f}",
                         f"{compile_s:.2f}"])
    info = machine_info()
    print(f"{info['cpu_model']}, {info['cpu_count']} CPUs, JAX {info['jax']}, XLA_FLAGS="
          f"{info['xla_flags']!r}")
    print(markdown_table(["batch", "layout", "ms per call (median)", "GFlop/s", "compile s"],
                         rows))


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
