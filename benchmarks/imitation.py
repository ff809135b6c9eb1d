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
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.commands import train_commands
from jaxsim import allocator, render, xla_options
from jaxsim.atomic import write_text_atomic
from spd import machine_info, reference_data

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "imitate_walk.toml"
DOCS, RESULTS = ROOT / "docs", ROOT / "benchmarks" / "results"


def _timed(fn, *args, repeats):
    """Median seconds of `repeats` calls after a first (compiling) call; and that first call."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times), first


def update_floor(update, args, steps, size=2048):
    """The floating-point operations of one PPO update (`update` jitted, on `args`) and this
    machine's float32 matmul rate (a size × size product, median of 10): the update cannot run
    faster than their ratio, however fast the simulation. XLA's cost analysis of the compiled
    update counts the body of a loop once, so it gives one minibatch step (plus the advantages);
    times `steps` minibatch steps."""
    flop = update.lower(*args).compile().cost_analysis()["flops"] * steps
    a = jnp.ones((size, size), jnp.float32)
    matmul_s, _ = _timed(jax.jit(jnp.matmul), a, a, repeats=10)
    return flop, 2 * size ** 3 / matmul_s


def speed(args):
    config = train_commands.load_config(CONFIG, args.set)
    trainer = train_commands.make_trainer(config, reference_data("deepmimic"))
    state = trainer.init()
    p = state.ppo
    sigma = trainer.sigma(p.samples)
    # The parts are timed as the iteration compiles them: with the simulator's XLA options.
    options = xla_options.simulation_options()
    rollout = jax.jit(trainer.rollout, compiler_options=options)
    rollout_args = (trainer.env_params_for(state.curriculum), state.runner, p.policy_params, p.value_params,
                    state.norm, sigma, state.key)
    rollout_s, rollout_compile = _timed(rollout, *rollout_args, repeats=args.repeats)
    batch = rollout(*rollout_args)[1]
    update = jax.jit(trainer.ppo.update, compiler_options=options)
    update_s, update_compile = _timed(update, p, batch, state.key, repeats=args.repeats)
    iteration_s, iteration_compile = _timed(lambda s: trainer.iteration(s)[1], state,
                                            repeats=args.repeats)
    samples = config.run.samples_per_iteration
    update_flop, matmul_rate = update_floor(
        update, (p, batch, state.key),
        config.ppo.epochs * (samples // config.ppo.minibatch_size))
    result = {"machine": machine_info(), "envs": config.run.envs,
              "steps_per_iteration": config.run.steps_per_iteration,
              "samples_per_iteration": samples,
              "iteration_seconds": iteration_s, "samples_per_second": samples / iteration_s,
              "rollout_seconds": rollout_s, "update_seconds": update_s,
              "rollout_share": rollout_s / (rollout_s + update_s),
              "update_gflop": update_flop / 1e9, "matmul_gflop_per_s": matmul_rate / 1e9,
              "update_floor_seconds": update_flop / matmul_rate, "xla_options": options,
              "compile_seconds": {"rollout": rollout_compile, "update": update_compile,
                                  "iteration": iteration_compile}}
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
