"""Time the dynamics solvers for one batch of characters: ABA and the four stable-PD solvers.

Measures, per character and batch size, `jax.jit(batched(solver))` over (q, qd, target or τ),
batched as `simulation.simulate_batch` batches (`batched_solver`):

    aba      jaxsim.dynamics.aba with random joint torques
    pd       solve_spd(..., "pd"): explicit PD torques, then ABA
    maba     solve_spd(..., "maba"): SPD inside the Articulated-Body Algorithm, O(n)
    sparse   solve_spd(..., "sparse"): branch-induced sparse LTDL of M + Kd Δt
    dense    solve_spd(..., "dense"): CRBA + RNEA + Cholesky, O(n³)

Compile time is the time of `jitted.lower(*args).compile()`. Run time is the median of R calls
(after one warm-up call), each ended with `jax.block_until_ready`; it is reported per call and per
character, with the ratios maba/aba, dense/maba, sparse/maba and pd/aba from the same run. The model
is passed as a (non-batched) argument, as in a rollout, so its parameters are not compile-time
constants. Inputs are random valid states: unit quaternions for the root and spherical joints, small
joint angles, velocities with standard deviation 0.5.

Run:  python benchmarks/spd.py
      python benchmarks/spd.py --characters humanoid snake10 --methods aba maba --batch 1 64
Prints a markdown table; writes JSON (default benchmarks/results/spd.json) with the machine's
description and the command line.
"""

import argparse
import json
import os
import platform
import resource
import shlex
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import allocator, characters, dynamics, rotations, simulation, xla_options
from jaxsim.atomic import write_text_atomic

CHARACTERS = {
    "humanoid": characters.humanoid,
    "quadruped": characters.quadruped,
    "snake10": lambda: characters.snake(10),
    "snake22": lambda: characters.snake(22),
    "snake63": lambda: characters.snake(63),
}
METHODS = ("aba", "pd", "maba", "sparse", "dense")
RATIOS = (("maba", "aba"), ("dense", "maba"), ("sparse", "maba"), ("pd", "aba"))
DT = 1 / 600                     # the paper's simulation rate
ANGLE_STD = 0.3                  # radians, joint angles and spherical-joint rotation vectors
VELOCITY_STD = 0.5
TORQUE_STD = 1.0
LARGE_BATCH = 1024               # default repeats: 20 below this batch size, 5 from it up
DEFAULT_JSON = Path(__file__).resolve().parent / "results" / "spd.json"


# ---------------------------------------------------------------------------------------------
# inputs


def reference_data(needed: str) -> Path:
    """The reference data directory (TAKEOFF_DATA, default ../shared/data beside the checkout);
    exits with a message when its folder `needed` is missing."""
    default = Path(__file__).resolve().parents[2] / "shared" / "data"
    path = Path(os.environ.get("TAKEOFF_DATA", default))
    if not (path / needed).is_dir():
        sys.exit(f"reference data not found in {path} (no {needed}/); set TAKEOFF_DATA")
    return path


def random_pose(topology, rng, batch):
    """(batch, nq) valid poses: random root position and orientation, small joint rotations."""
    q = np.zeros((batch, topology.nq))
    offsets = topology.q_offsets

    def set_quats(links, rotvecs):
        index = offsets[links][:, None] + np.arange(4)
        q[:, index] = np.asarray(rotations.rotvec_to_quat(rotvecs))

    spherical = topology.links_of_type("spherical")
    set_quats(spherical, ANGLE_STD * rng.standard_normal((batch, len(spherical), 3)))
    revolute = topology.links_of_type("revolute")
    q[:, offsets[revolute]] = ANGLE_STD * rng.standard_normal((batch, len(revolute)))
    if topology.floating:
        q[:, 0:3] = [0.0, 1.0, 0.0] + 0.1 * rng.standard_normal((batch, 3))
        root = rng.standard_normal((batch, 4))
        q[:, 3:7] = root / np.linalg.norm(root, axis=-1, keepdims=True)
    return q


def random_inputs(model, batch, seed):
    """Batched float inputs shared by every method: q, qd, a target pose and torques."""
    rng = np.random.default_rng(seed)
    topo = model.topology
    arrays = {
        "q": random_pose(topo, rng, batch),
        "qd": VELOCITY_STD * rng.standard_normal((batch, topo.nv)),
        "target": random_pose(topo, rng, batch),
        "tau": TORQUE_STD * rng.standard_normal((batch, topo.nv)),
    }
    return {name: jnp.asarray(a, model.mass.dtype) for name, a in arrays.items()}


# ---------------------------------------------------------------------------------------------
# solvers and timing


def solver(method):
    """(model, q, qd, target or τ) -> outputs of one character, for `method`."""
    if method == "aba":
        return dynamics.aba
    return lambda model, q, qd, target: dynamics.solve_spd(model, q, qd, target, DT, method)


def solver_args(model, inputs, method):
    return (model, inputs["q"], inputs["qd"], inputs["tau" if method == "aba" else "target"])


def compile_and_time(fn, args, repeats, method):
    """Compile seconds of jit(fn) on `args`, the outputs of one warm-up call, the seconds of
    `repeats` further calls, each ended with `jax.block_until_ready`, and the process's minor page
    faults per call over those calls (see jaxsim.allocator). Compiled with the XLA options that
    `simulation.simulate` uses for `method` (`jaxsim.xla_options.options_for`;
    TAKEOFF_XLA_DEFAULTS=1 compiles every method with XLA's defaults)."""
    start = time.perf_counter()
    compiled = jax.jit(fn, compiler_options=xla_options.options_for(method)).lower(
        *args).compile()
    compile_s = time.perf_counter() - start
    outputs = jax.block_until_ready(compiled(*args))
    times = []
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - start)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / repeats
    return compile_s, outputs, times, faults


def batched_solver(method):
    """The solver over a batch, laid out as `simulate_batch` lays out `method`."""
    return simulation.batched(solver(method), method, in_axes=(None, 0, 0, 0))


def measure(method, args, repeats):
    """Compile seconds, per-call seconds, page faults per call, and whether the outputs of
    the jitted batched solver on `args` are all finite (a solver that returns NaN is not worth
    timing, so the caller warns)."""
    compile_s, outputs, times, faults = compile_and_time(batched_solver(method), args, repeats,
                                                         method)
    finite = all(bool(jnp.isfinite(x).all()) for x in jax.tree.leaves(outputs))
    return compile_s, times, faults, finite


def default_repeats(batch):
    return 20 if batch < LARGE_BATCH else 5


def run(args):
    """One result row per (character, batch, method)."""
    rows = []
    for name in args.characters:
        model = CHARACTERS[name]()
        for batch in args.batch:
            inputs = random_inputs(model, batch, args.seed)
            repeats = args.repeats or default_repeats(batch)
            for method in args.methods:
                compile_s, times, faults, finite = measure(
                    method, solver_args(model, inputs, method), repeats)
                median_us = 1e6 * statistics.median(times)
                rows.append({
                    "character": name, "dof": model.nv, "dtype": str(model.mass.dtype),
                    "batch": batch, "method": method,
                    "compile_s": compile_s, "repeats": repeats, "median_us": median_us,
                    "min_us": 1e6 * min(times), "us_per_character": median_us / batch,
                    "times_us": [1e6 * t for t in times], "page_faults_per_call": faults,
                    "finite": finite,
                })
                warning = "" if finite else "  WARNING: non-finite output"
                print(f"{name:9s} batch {batch:5d} {method:6s} compile {compile_s:7.2f} s  "
                      f"{median_us:12.1f} us/call  {faults:8.0f} page faults/call{warning}",
                      file=sys.stderr, flush=True)
    return rows


def ratios(rows):
    """Median-time ratios per (character, batch), for the method pairs in RATIOS that ran."""
    median = {(r["character"], r["batch"], r["method"]): r["median_us"] for r in rows}
    out = []
    groups = dict.fromkeys((r["character"], r["dof"], r["batch"]) for r in rows)   # run order
    for character, dof, batch in groups:
        entry = {"character": character, "dof": dof, "batch": batch}
        for num, den in RATIOS:
            if (character, batch, num) in median and (character, batch, den) in median:
                entry[f"{num}/{den}"] = (median[character, batch, num]
                                         / median[character, batch, den])
        out.append(entry)
    return out


# ---------------------------------------------------------------------------------------------
# output


def markdown_table(header, lines):
    rows = [header, ["---"] * len(header), *lines]
    return "\n".join("| " + " | ".join(str(cell) for cell in row) + " |" for row in rows)


def markdown(rows, ratio_rows):
    times = markdown_table(
        ["character", "DoF", "batch", "method", "compile s", "µs/call", "µs/character"],
        [[r["character"], r["dof"], r["batch"], r["method"], f"{r['compile_s']:.2f}",
          f"{r['median_us']:.1f}", f"{r['us_per_character']:.3f}"] for r in rows])
    names = [f"{num}/{den}" for num, den in RATIOS]
    ratio_table = markdown_table(
        ["character", "DoF", "batch", *names],
        [[r["character"], r["dof"], r["batch"],
          *(f"{r[n]:.2f}" if n in r else "–" for n in names)] for r in ratio_rows])
    dtypes = ", ".join(sorted({r["dtype"] for r in rows}))
    return (f"Time per call (median), {dtypes}, Δt = 1/600 s\n\n{times}\n\n"
            f"Ratios of median time per call (same run)\n\n{ratio_table}\n")


def cpuinfo_field(name):
    """The first value of `name` in /proc/cpuinfo ('' where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            return next((line.split(":", 1)[1].strip() for line in f
                         if line.split(":", 1)[0].strip() == name), "")
    except OSError:
        return ""


def cpu_model():
    """The CPU's model name from /proc/cpuinfo ('' where there is none; platform.processor()
    is often empty on Linux)."""
    return cpuinfo_field("model name")


def machine_info():
    """What the figures were measured on: the CPU (its model name, family and model numbers,
    which tell a VM's generation when the name is only "AMD EPYC", and its widest vectors),
    the software and the devices."""
    return {
        "processor": platform.processor(),
        "cpu_model": cpu_model(),
        "cpu_family": cpuinfo_field("cpu family"),
        "cpu_model_number": cpuinfo_field("model"),
        "vector_bits": xla_options.vector_bits(),
        "uname": platform.uname()._asdict(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--characters", nargs="+", choices=list(CHARACTERS),
                        default=list(CHARACTERS))
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--batch", nargs="+", type=int, default=[1, 4096])
    parser.add_argument("--repeats", type=int, default=None,
                        help=f"timed calls per measurement (default 20 below batch {LARGE_BATCH}, "
                             "5 from it up)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help="where to write JSON")
    parser.add_argument("--markdown", type=Path, default=None,
                        help="also write the markdown table to this file")
    args = parser.parse_args(argv)
    if any(b < 1 for b in args.batch) or (args.repeats is not None and args.repeats < 1):
        parser.error("--batch and --repeats must be positive")
    return args


def main(argv=None):
    args = parse_args(argv)
    rows = run(args)
    ratio_rows = ratios(rows)
    table = markdown(rows, ratio_rows)
    print(table)
    if args.markdown:
        write_text_atomic(args.markdown, table)
    record = {
        "command": shlex.join([sys.executable, *sys.argv]),
        "machine": machine_info(),
        "compiler_options": {m: xla_options.options_for(m) for m in METHODS},
        "settings": {"dt": DT, "seed": args.seed, "angle_std": ANGLE_STD,
                     "velocity_std": VELOCITY_STD, "torque_std": TORQUE_STD},
        "results": rows,
        "ratios": ratio_rows,
    }
    write_text_atomic(args.json, json.dumps(record, indent=2) + "\n")
    print(f"wrote {args.json}", file=sys.stderr)


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
