"""Sweeps (issue 21): a vmapped evaluation sweep against separate evaluations of the same
members, and trainings of several seeds in one program against the same trainings in a row.

    python benchmarks/sweep.py evaluate RUN_DIR [--members 256] [--separate 4]
    python benchmarks/sweep.py train [--config configs/reach.toml] [--seeds 4]

RUN_DIR is a trained high-jump run. Three ways to evaluate the same members (leg-length ×
gravity pairs of `[physics]` factors, as configs/sweep_highjump_body.toml), one deterministic
episode each, compile included in all three, in this order:

- the sweep: every member in one call, `agents.sweep`'s way;
- one program, called per member: one environment's evaluation compiled once, then called with
  each member's parameters in a Python loop (what a careful user writes by hand), every member;
- separate runs: each member's own config evaluated (`train_commands.run_episodes` with the
  member's overrides, what `takeoff eval` of that member's config does: a new config is a new
  program, so each compiles), `--separate` of them timed, their median scaled to all members.

Wall times from `time.perf_counter`; the largest difference of the apex between the ways is
printed. Writes benchmarks/results/sweep.json.

`train`: the config's training for `--seeds` seeds as `takeoff sweep` runs it, once in one
program (the members vmapped) and once member after member in this process (`vmap = false`,
each seed's config a new program), compile included in both; each member's final return
printed. Writes benchmarks/results/sweep_train.json.
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from agents import sweep
from agents.commands import train_commands

RESULTS = Path(__file__).resolve().parent / "results"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("evaluate")
    p.add_argument("run_dir")
    p.add_argument("--members", type=int, default=256)
    p.add_argument("--separate", type=int, default=4)
    p.add_argument("--data-dir")
    p.set_defaults(run=evaluate)
    p = sub.add_parser("train")
    p.add_argument("--config", default="configs/reach.toml")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--data-dir")
    p.set_defaults(run=train)
    args = parser.parse_args()
    args.run(args)


def train(args):
    table = f"\n[sweep]\nrun.seed = {list(range(args.seeds))}\n"
    text = Path(args.config).read_text()
    result = {"config": args.config, "seeds": args.seeds}
    with tempfile.TemporaryDirectory() as folder:
        for way, extra in (("one_program", ""), ("in_a_row", "vmap = false\n")):
            config = Path(folder) / f"{way}.toml"
            config.write_text(text + table + extra)
            started = time.perf_counter()
            out = sweep.run(config, Path(folder) / way, data_dir=args.data_dir,
                            echo=lambda *_: None)
            seconds = time.perf_counter() - started
            rows = sorted(sweep.rows_of(out), key=lambda r: r["member"])
            result[way] = {"seconds": seconds, "returns": [r["return"] for r in rows]}
            print(f"{way}: {seconds:.1f} s, returns {[round(r['return'], 4) for r in rows]}")
    result["speedup"] = result["in_a_row"]["seconds"] / result["one_program"]["seconds"]
    print(json.dumps(result, indent=1))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sweep_train.json").write_text(json.dumps(result, indent=1) + "\n")


def evaluate(args):
    gravities = [0.5, 0.75, 1.0, 1.25]
    legs = np.linspace(0.8, 1.2, args.members // len(gravities))
    members = [{"physics.leg_length_scale": float(leg), "physics.gravity_scale": g}
               for leg in legs for g in gravities]
    plan = sweep.Sweep("benchmark", members, ("physics.leg_length_scale",
                                              "physics.gravity_scale"), evaluate=args.run_dir)
    columns = {k: np.asarray([m[k] for m in members]) for k in plan.keys}
    quiet = lambda *_: None
    started = time.perf_counter()
    together = train_commands.run_episodes(
        args.run_dir, len(members), args.data_dir, echo=quiet,
        overrides=["physics.length_scale=1.0"],
        vary=lambda params: sweep.member_params(plan, columns, params))
    sweep_seconds = time.perf_counter() - started
    started = time.perf_counter()
    looped = []
    for i in range(len(members)):
        one = {k: v[i:i + 1] for k, v in columns.items()}
        alone = train_commands.run_episodes(
            args.run_dir, 1, args.data_dir, echo=quiet, overrides=["physics.length_scale=1.0"],
            vary=lambda params: sweep.member_params(plan, one, params))
        looped.append(float(alone.outcomes["episode/peak_com"][0]))
    loop_seconds = time.perf_counter() - started
    loop_difference = float(np.max(np.abs(np.asarray(looped)
                                          - together.outcomes["episode/peak_com"])))
    picks = np.linspace(0, len(members) - 1, args.separate).round().astype(int)
    separate, worst = [], 0.0
    for i in picks:
        started = time.perf_counter()
        alone = train_commands.run_episodes(
            args.run_dir, 1, args.data_dir, echo=quiet,
            overrides=[f"{k}={v}" for k, v in members[i].items()])
        separate.append(time.perf_counter() - started)
        worst = max(worst, abs(float(alone.outcomes["episode/peak_com"][0])
                               - float(together.outcomes["episode/peak_com"][i])))
    per_member = statistics.median(separate)
    result = {"members": len(members), "sweep_seconds": sweep_seconds,
              "one_program_loop_seconds": loop_seconds,
              "loop_over_sweep": loop_seconds / sweep_seconds,
              "loop_largest_peak_com_difference": loop_difference,
              "separate_seconds_each": separate, "separate_median": per_member,
              "separate_total_estimate": per_member * len(members),
              "speedup": per_member * len(members) / sweep_seconds,
              "largest_peak_com_difference": worst}
    print(json.dumps(result, indent=1))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sweep.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
