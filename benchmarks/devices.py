"""Does splitting a training iteration over devices or processes make it faster on this machine?

    python benchmarks/devices.py [--config configs/imitate_walk.toml] [--set KEY=VALUE …]
                                 [--layouts 1,2,2p,2pp] [--repeats 5]

Layouts: `1` one XLA device (the trainer's default), `2` two host devices in one process
(`run.devices = 2`: the CPU backend started with two devices, the batch sharded over them), `2p`
two processes of one `jax.distributed` run on localhost (one device each, as `takeoff train
--processes 2` runs them: pinned to their own cores only with two or more each), `2pp` the same
with each process pinned to one core. Each layout runs in fresh processes, which
build the config's trainer split that way and time, as the median of `repeats` calls after a
first (compiling) call: the rollout (the trainer's `_collect`: simulation and policy), the
update (`_learn`: observation statistics, PPO, curriculum) and the whole iteration; the first
iteration (compilation included) is reported apart. Prints a markdown table (speed-up against
layout `1`) and writes benchmarks/results/devices.json. The default config needs the reference
data (TAKEOFF_DATA, default ../shared/data); `--config configs/reach.toml` does not.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
LAYOUTS = {"1": "1 device", "2": "2 devices, 1 process", "2p": "2 processes × 1 device",
           "2pp": "2 processes × 1 device, each pinned to 1 core"}


def measure(args):
    """In a measuring process: the figures of one layout, as one JSON line (process 0)."""
    import jax

    import training_speed
    from agents.commands import train_commands
    from agents.rl import parallel

    cluster = (parallel.Cluster(args.coordinator, args.num_processes, args.process_id)
               if args.coordinator else None)
    parallel.start(args.devices, cluster)
    config = train_commands.load_config(args.config, [*args.set, f"run.devices={args.devices}"])
    trainer = train_commands.make_trainer(config)
    state = trainer.place(trainer.init())
    start = time.perf_counter()
    jax.block_until_ready(trainer.iteration(state))
    first = time.perf_counter() - start
    rollout_s, _ = training_speed.timed(trainer.collect, state, repeats=args.repeats)
    collected = trainer.collect(state)
    update_s, _ = training_speed.timed(trainer.learn, state, collected, repeats=args.repeats)
    iteration_s, _ = training_speed.timed(trainer.iteration, state, repeats=args.repeats)
    samples = config.run.samples_per_iteration
    if parallel.is_writer():
        print(json.dumps({"devices": trainer.layout.size, "processes": jax.process_count(),
                          "rollout_seconds": rollout_s, "update_seconds": update_s,
                          "iteration_seconds": iteration_s,
                          "samples_per_second": samples / iteration_s,
                          "first_iteration_seconds": first,
                          "samples_per_iteration": samples}), flush=True)


def run_layout(layout, args) -> dict:
    """The figures of a layout, from its fresh measuring process(es)."""
    from agents.commands import launch

    base = [sys.executable, str(Path(__file__).resolve()), "--config", args.config,
            "--repeats", str(args.repeats), *[w for s in args.set for w in ("--set", s)],
            "measure"]
    if layout in ("1", "2"):
        commands, shares = [[*base, "--devices", layout]], [None]
    else:                 # as `takeoff train --processes 2` runs them (2pp: pinned however few)
        port = launch.free_port()
        commands = [[*base, "--devices", "1", "--coordinator", f"127.0.0.1:{port}",
                     "--num-processes", "2", "--process-id", str(i)] for i in range(2)]
        shares = launch.core_shares(2, **({"minimum": 1} if layout == "2pp" else {}))
    children = [subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, text=True,
                                 preexec_fn=lambda c=cores: launch._child_setup(c))
                for command, cores in zip(commands, shares)]
    outputs = [child.communicate()[0] for child in children]
    if any(child.returncode for child in children):
        sys.exit(f"layout {layout}: a measuring process failed "
                 f"({[child.returncode for child in children]})")
    lines = [line for line in outputs[0].splitlines() if line.startswith("{")]
    return {"layout": layout, "name": LAYOUTS[layout], **json.loads(lines[-1])}


def table(results) -> str:
    base = next((r for r in results if r["layout"] == "1"), None)
    rows = ["| layout | rollout s | update s | iteration s | samples/s | speed-up | "
            "first iteration (compiling) s |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        speedup = (f"{base['iteration_seconds'] / r['iteration_seconds']:.2f}×" if base
                   else "—")
        rows.append(f"| {r['name']} | {r['rollout_seconds']:.3f} | {r['update_seconds']:.3f} "
                    f"| {r['iteration_seconds']:.3f} | {r['samples_per_second']:,.0f} | "
                    f"{speedup} | {r['first_iteration_seconds']:.1f} |")
    return "\n".join(rows)


def compare(args):
    from jaxsim.atomic import write_text_atomic
    from spd import machine_info

    layouts = args.layouts.split(",")
    unknown = [layout for layout in layouts if layout not in LAYOUTS]
    if unknown:
        sys.exit(f"unknown layout {unknown[0]!r}: use {', '.join(LAYOUTS)}")
    results = []
    for layout in layouts:
        print(f"measuring {LAYOUTS[layout]} …", flush=True)
        results.append(run_layout(layout, args))
    text = table(results)
    print(f"\n{args.config} {' '.join(args.set)} (median of {args.repeats})\n\n{text}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_text_atomic(RESULTS / "devices.json", json.dumps(
        {"machine": machine_info(), "config": args.config, "overrides": args.set,
         "repeats": args.repeats, "results": results}, indent=2) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="configs/imitate_walk.toml")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--repeats", type=int, default=5)
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("measure", help="(internal) measure one layout in this process")
    p.add_argument("--devices", type=int, required=True)
    p.add_argument("--coordinator")
    p.add_argument("--num-processes", type=int)
    p.add_argument("--process-id", type=int)
    parser.add_argument("--layouts", default="1,2,2p,2pp",
                        help="comma-separated: 1 (one device), 2 (two host devices), "
                             "2p (two processes, as the launcher runs them), 2pp (two "
                             "processes, each pinned to one core)")
    args = parser.parse_args()
    (measure if args.command == "measure" else compare)(args)


if __name__ == "__main__":
    from jaxsim import allocator

    allocator.restart_with_tunables()
    main()
