"""Imitation of DeepMimic's walk with PPO on this machine: throughput, its split, and a timed run.

    python benchmarks/imitation.py speed            # samples/s of the whole iteration, and the
                                                    # time in the rollout (simulation) vs the update
    python benchmarks/imitation.py train [--minutes 60]
                                                    # train configs/imitate_walk.toml for that long,
                                                    # then `report`
    python benchmarks/imitation.py report           # evaluate that run (16 episodes, mean action),
                                                    # figures into docs/, summary into results/

Needs the reference data (TAKEOFF_DATA, default ../shared/data).
"""

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

import training_speed
from agents.commands import train_commands
from jaxsim import allocator, render
from jaxsim.atomic import write_text_atomic
from spd import machine_info, reference_data

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "imitate_walk.toml"
DOCS, RESULTS = ROOT / "docs", ROOT / "benchmarks" / "results"


def speed(args):
    result = {"machine": machine_info(),
              **training_speed.measure(CONFIG, reference_data("deepmimic"), args.set,
                                       args.repeats)}
    write_text_atomic(RESULTS / "imitation_speed.json", json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "machine"}, indent=2))


def train(args):
    out = RESULTS / "imitate_walk"
    if out.exists():
        shutil.rmtree(out)
    overrides = [f"run.time_limit_minutes={args.minutes}", "run.iterations=100000", *args.set]
    train_commands.train(CONFIG, out, overrides, data_dir=reference_data("deepmimic"))
    report(args)


def report(args):
    """Evaluate the run in results/imitate_walk and write its figures and summary."""
    out = RESULTS / "imitate_walk"
    summary, env, poses = train_commands.evaluate(out, episodes=16,
                                                  data_dir=reference_data("deepmimic"))
    shutil.copyfile(out / train_commands.CURVE, DOCS / "imitate_walk_curve.png")
    shown = poses[: int(3.0 / env.control_dt)]
    render.filmstrip(env.model, shown, DOCS / "imitate_walk_eval.png", world=env.world,
                     n_panels=10, times=np.arange(len(shown)) * env.control_dt,
                     title="deterministic policy after training (first 3 s of an evaluation "
                           "episode)")
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    last = records[-1]
    result = {"machine": machine_info(), "iterations": last["iteration"],
              "samples": last["samples"], "training_seconds": last["seconds"],
              "mean_samples_per_second": last["samples"] / last["seconds"],
              "last_return": last["return"], "last_episode_length": last["episode_length"],
              "evaluation": summary}
    write_text_atomic(RESULTS / "imitate_walk.json", json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "machine"}, indent=2))


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("speed")
    p.add_argument("--repeats", type=int, default=5)
    p.set_defaults(run=speed)
    p = sub.add_parser("train")
    p.add_argument("--minutes", type=float, default=60.0)
    p.set_defaults(run=train)
    sub.add_parser("report").set_defaults(run=report)
    for p in sub.choices.values():
        p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
