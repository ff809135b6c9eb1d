"""Does the nearly untrained policy foretell a jump training's outcome? (`jump.probe_samples`)

For each evaluation of each given strategy search, this trains the evaluation's first few PPO
iterations again: its search's `[jump]` settings, its x, seeded as the search's training was,
so they are the search's own first iterations where the simulator and the training config
(`[jump].train`, read from disk) have not changed since. Over those iterations it takes each
iteration's share of the episodes that succeeded, crossed the bar's plane and hit the bar, and
the peak centre of mass, and averages them. It prints them as
a markdown table beside the evaluation's logged outcome, sorted by the crossing share. A gap in
that share between every success and every failure is what the black box's probe give-up point
(`agents/discovery/jump_black_box.py`) relies on.

Run:  python benchmarks/probe_outcomes.py SEARCH_DIR [SEARCH_DIR ...] --out runs/probe
      [--iterations 10] [--data-dir ../shared/data]

About a minute per evaluation on 2 cores (most of it compiling). A probe already trained in
OUT is read, not trained again, so a killed run resumes where it stopped.
"""

import argparse
import dataclasses
import json
from pathlib import Path

from agents.commands import strategy_search, train_commands
from agents.datadir import data_dir_from
from agents.discovery.jump_black_box import JumpBlackBox, early_share
from agents.rl import trainer as trainer_lib
from bds.search import SEARCH_LOG, logged_evaluations
from jaxsim.atomic import write_text_atomic

SHARES = {"success": "env/episode/success", "crossed": "env/episode/crossed",
          "hit the bar": "env/episode/hit_bar"}


def probe(search_dir: Path, out: Path, iterations: int, data_dir) -> list[dict]:
    """One row per logged evaluation of the search in `search_dir`: its index, x, outcome and
    the averages over its first `iterations` training iterations (trained in `out`)."""
    config = strategy_search.load_search_config(search_dir)
    base = train_commands.load_config(config.jump.train, config.jump.set)
    settings = dataclasses.replace(config.jump, samples=iterations * base.run.samples_per_iteration,
                                   probe_samples=0, give_up_samples=0, minutes=0.0)
    box = JumpBlackBox(settings, out, data_dir_from(data_dir))
    actions = base.sections()[base.run.task].get("actions")
    prefix = f"{search_dir.resolve().parent.name}_{search_dir.name}"   # e.g. discovery_pd
    rows = []
    for record in logged_evaluations(search_dir / SEARCH_LOG):
        run_dir = out / f"{prefix}_{record['index']:03d}"
        box.train(run_dir, record["x"])
        records = trainer_lib.read_metrics(run_dir)
        mean = lambda key: early_share(records, key, iterations)
        rows.append({"search": search_dir.name, "index": record["index"], "x": record["x"],
                     "actions": actions, "succeeded": record["feature"] is not None,
                     **{name: mean(key) for name, key in SHARES.items()},
                     "peak_com": mean("env/episode/peak_com")})
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("searches", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--data-dir", default=None)
    args = parser.parse_args()
    rows = [row for search_dir in args.searches
            for row in probe(search_dir, args.out, args.iterations, args.data_dir)]
    rows.sort(key=lambda row: -row["crossed"])
    point = lambda x: "(" + ", ".join(f"{v:.2f}" for v in x) + ")"
    print(f"| search | evaluation | x = (α, ω_x, ω_z, v_z) | actions | outcome | over the first "
          f"{args.iterations} iterations: succeeded | crossed | hit the bar | peak CoM (m) |")
    print("|---|---:|---|---|---|---:|---:|---:|---:|")
    for row in rows:
        print(f"| {row['search']} | {row['index']:03d} | {point(row['x'])} | {row['actions']} | "
              f"{'success' if row['succeeded'] else 'failure'} | {row['success']:.3%} | "
              f"{row['crossed']:.1%} | {row['hit the bar']:.1%} | {row['peak_com']:.3f} |")
    write_text_atomic(args.out / "probe_outcomes.json", json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
