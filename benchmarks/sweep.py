"""A vmapped evaluation sweep against separate evaluations of the same members (issue 21).

    python benchmarks/sweep.py RUN_DIR [--members 256] [--separate 4]

RUN_DIR is a trained high-jump run. The sweep: every member (a leg-length × gravity pair of
`[physics]` factors, as configs/sweep_highjump_body.toml) evaluated for one deterministic
episode in one call, `agents.sweep`'s way, compile included. Separately: each member its own
evaluation (`train_commands.run_episodes` with the member's overrides, what `takeoff eval` of
that member's config does, compile included: a new config is a new program), `--separate` of
them timed and the median scaled to all members. Wall times from `time.perf_counter`; the two
agree member by member (printed). Writes benchmarks/results/sweep.json.
"""

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from agents import sweep
from agents.commands import train_commands

RESULTS = Path(__file__).resolve().parent / "results"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument("--members", type=int, default=256)
    parser.add_argument("--separate", type=int, default=4)
    parser.add_argument("--data-dir")
    args = parser.parse_args()
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
              "separate_seconds_each": separate, "separate_median": per_member,
              "separate_total_estimate": per_member * len(members),
              "speedup": per_member * len(members) / sweep_seconds,
              "largest_peak_com_difference": worst}
    print(json.dumps(result, indent=1))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sweep.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
