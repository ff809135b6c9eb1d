"""Imitation of DeepMimic's walk with PPO on this machine: throughput, its split, and a timed run.

    python benchmarks/imitation.py speed            # samples/s of the whole iteration, and the
                                                    # time in the rollout (simulation) vs the update
    python benchmarks/imitation.py train [--minutes 60]
                                                    # train configs/imitate_walk.toml for that long,
                                                    # then `report`
    python benchmarks/imitation.py report           # evaluate that run (16 episodes, mean action),
                                                    # figures into docs/, summary into results/
    python benchmarks/imitation.py to-target [--settings NAME …] [--cap-minutes 30]
                                                    # minutes to the walk target for each network /
                                                    # epoch setting (SETTINGS), one after another

The walk target (`walk_target_reached`): in the last `WALK_TARGET_ITERATIONS` iterations in a row
(40,960 control steps, about 137 ten-second episodes) the training episodes fell at most once
(the env's `fell` metric counts falls per sample); the exploring policy's noise still trips it
now and then long after it walks. The run is then stopped with Ctrl-C (it checkpoints) and its
deterministic policy evaluated on 16 episodes, which must all reach the 10 s time limit.

Needs the reference data (TAKEOFF_DATA, default ../shared/data).
"""

import argparse
import json
import shutil
import signal
import subprocess
import sys
import time
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


WALK_TARGET_ITERATIONS = 10
# The network and PPO settings timed to the walk target: the thesis's, and cheaper ones.
SETTINGS = {
    "thesis": [],                                            # 1024-512, 5 epochs of 256
    "1024-512, 2 epochs": ["ppo.epochs=2"],
    "256-256, 5 epochs": ["ppo.hidden=[256, 256]"],
    "1024-512, 5 epochs of 1024": ["ppo.minibatch_size=1024"],
}


def walk_target_reached(records, samples_per_iteration=4096) -> dict | None:
    """The metrics record of the first iteration that completes the walk target (see the
    module docstring), or None."""
    falls = [round(r.get("env/fell", 1.0) * samples_per_iteration) for r in records]
    for end in range(WALK_TARGET_ITERATIONS, len(records) + 1):
        if sum(falls[end - WALK_TARGET_ITERATIONS:end]) <= 1:
            return records[end - 1]
    return None


def to_target(args):
    """Train each setting until the walk target or `--cap-minutes`, one after another."""
    names = args.settings or list(SETTINGS)
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        raise SystemExit(f"unknown setting(s) {unknown}; known: {list(SETTINGS)}")
    rows = []
    for name in names:
        out = RESULTS / "walk_to_target" / name.replace(" ", "_").replace(",", "")
        if out.exists():
            shutil.rmtree(out)
        overrides = [f"run.time_limit_minutes={args.cap_minutes}", "run.iterations=100000",
                     *SETTINGS[name], *args.set]
        command = [str(Path(sys.executable).parent / "takeoff"), "train", str(CONFIG),
                   "--out", str(out), "--data-dir", str(reference_data("deepmimic"))]
        for override in overrides:
            command += ["--set", override]
        print(f"{name}: {' '.join(command)}", flush=True)
        start = time.perf_counter()
        process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL)
        reached = None
        while process.poll() is None:
            time.sleep(5)
            metrics = out / "metrics.jsonl"
            records = ([json.loads(line) for line in metrics.read_text().splitlines()
                        if line.endswith("}")] if metrics.exists() else [])
            reached = walk_target_reached(records)
            if reached is not None:
                process.send_signal(signal.SIGINT)         # the run checkpoints and stops
                break
        process.wait()
        wall_s = time.perf_counter() - start
        records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
        reached = walk_target_reached(records)
        summary = train_commands.evaluate(out, episodes=16, data_dir=reference_data("deepmimic"),
                                          echo=lambda *_: None)[0]
        last = records[-1]
        rows.append({"setting": name, "overrides": SETTINGS[name],
                     "target_minutes": reached["seconds"] / 60 if reached else None,
                     "target_samples": reached["samples"] if reached else None,
                     "target_iteration": reached["iteration"] if reached else None,
                     "samples_per_second": last["samples"] / last["seconds"],
                     "process_wall_minutes": wall_s / 60,
                     "evaluation_full_length": summary["episode_length"],
                     "evaluation_fell": summary.get("fell"),
                     "evaluation_pose_error_degrees": summary.get("pose_error_degrees")})
        print(json.dumps(rows[-1]), flush=True)
        write_text_atomic(RESULTS / "walk_to_target.json",
                          json.dumps({"machine": machine_info(), "cap_minutes": args.cap_minutes,
                                      "rows": rows}, indent=2) + "\n")


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
    p = sub.add_parser("to-target")
    p.add_argument("--settings", nargs="+", metavar="NAME", help=f"of {list(SETTINGS)}")
    p.add_argument("--cap-minutes", type=float, default=30.0)
    p.set_defaults(run=to_target)
    for p in sub.choices.values():
        p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
