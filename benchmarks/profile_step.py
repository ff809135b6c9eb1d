"""Where a batched simulation step spends its time: the compiled kernels, longest first, each with
the source line it came from.

Runs the contact benchmark's rollout (`tracking.contact_scene`: the humanoid dropped on the
ground, maba, contacts and joint limits, 600 Hz, float32) or, with --solve-only, one MABA solve
as `spd.py` times it, at the given batch, compiled as `simulate` compiles maba
(`jaxsim.xla_options`); records a `jax.profiler` trace of a few calls and sums each kernel's
duration.
Kernels are named by XLA (`add_add_fusion.2`, `wrapped_scatter.9`, …); the optimised HLO's
metadata gives the innermost Python line that produced each one.

Run:  python benchmarks/profile_step.py                 (contact step, batch 4096, top 25)
      python benchmarks/profile_step.py --solve-only --batch 4096 --top 10
"""

import argparse
import collections
import gzip
import json
import re
import sys
import tempfile
from pathlib import Path

import jax

from jaxsim import allocator, characters, xla_options
from spd import batched_solver, random_inputs, solver_args
from tracking import batched_states, contact_scene


def contact_rollout(batch, steps):
    _, state, rollout = contact_scene(steps)
    return (jax.jit(rollout, compiler_options=xla_options.options_for("maba")),
            (batched_states(state, batch),))


def maba_solve(batch):
    model = characters.humanoid()
    args = solver_args(model, random_inputs(model, batch, 0), "maba")
    return jax.jit(batched_solver("maba"), compiler_options=xla_options.options_for("maba")), args


def source_lines(hlo_text):
    """Kernel name → 'file:line (function)' of the innermost frame in its metadata."""
    lines = hlo_text.split("\n")

    def table(title, pattern):
        start = lines.index(title) + 1
        out = {}
        for line in lines[start:]:
            match = re.match(pattern, line)
            if not match:
                break
            out[int(match.group(1))] = match.groups()[1:]
        return out
    files = table("FileNames", r'\s*(\d+) "(.*)"')
    functions = table("FunctionNames", r'\s*(\d+) "(.*)"')
    locations = table("FileLocations", r"\s*(\d+) \{file_name_id=(\d+) function_name_id=(\d+) "
                      r"line=(\d+)")
    frames = table("StackFrames", r"\s*(\d+) \{file_location_id=(\d+)")
    where = {name: "no source recorded" for name in re.findall(r"%([\w.\-]+) = ", hlo_text)}
    for match in re.finditer(r"%([\w.\-]+) = .*?stack_frame_id=(\d+)", hlo_text):
        file_id, function_id, line = locations[int(frames[int(match.group(2))][0])]
        path = files[int(file_id)][0]
        path = "jaxsim/" + path.split("/jaxsim/")[-1] if "/jaxsim/" in path else path
        where[match.group(1)] = f"{path}:{line} ({functions[int(function_id)][0]})"
    return where


def profile(fn, args, calls):
    """Per-kernel total microseconds over `calls` calls, and the wall time of those calls."""
    jax.block_until_ready(fn(*args))                           # compile and warm up
    with tempfile.TemporaryDirectory() as folder:
        jax.profiler.start_trace(folder, create_perfetto_trace=True)
        for _ in range(calls):
            jax.block_until_ready(fn(*args))
        jax.profiler.stop_trace()
        trace = next(Path(folder).rglob("*.trace.json.gz"))
        events = json.load(gzip.open(trace))["traceEvents"]
    totals = collections.Counter()
    for event in events:
        if event.get("ph") == "X":
            totals[event["name"]] += event["dur"]
    wall = totals.pop("ThunkExecutor::Execute (wait for completion)", None)
    return totals, wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=10, help="steps per rollout call")
    parser.add_argument("--calls", type=int, default=3)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--solve-only", action="store_true", help="profile one MABA solve")
    args = parser.parse_args()
    fn, fn_args = (maba_solve(args.batch) if args.solve_only
                   else contact_rollout(args.batch, args.steps))
    where = source_lines(fn.lower(*fn_args).compile().as_text())
    totals, wall = profile(fn, fn_args, args.calls)
    kernels = [(name, us) for name, us in totals.most_common() if name in where]
    print(f"wall time per call: {wall / args.calls / 1e3:.1f} ms" if wall else
          "wall time per call: not in the trace")
    print(f"{'ms/call':>9}  {'share':>6}  kernel  (source)")
    for name, us in kernels[:args.top]:
        share = f"{100 * us / wall:5.1f}%" if wall else "   –  "
        print(f"{us / args.calls / 1e3:9.2f}  {share}  {name}  ({where[name]})")


if __name__ == "__main__":
    allocator.restart_with_tunables()
    sys.exit(main())
