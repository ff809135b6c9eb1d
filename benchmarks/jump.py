"""The jump tasks on this machine: training throughput, control-rate variants, a run's figures.

    python benchmarks/jump.py speed [--task highjump|obstacle] [--rates 10 30]
        samples/s of the training iteration at each control rate, split into the rollout and
        the PPO update, with the simulation steps/s inside the rollout
    python benchmarks/jump.py substeps [--envs 256]
        one control step of the batch at each rate as the task runs it (a static number of
        substeps: one compiled variant per rate) against a traced number of substeps (a
        `fori_loop` with the count as an argument: one program for every rate), the count the
        same for the whole batch and one per environment
    python benchmarks/jump.py explore [--task obstacle] [--episodes 512] [--sigma 0.8]
        how often random open-loop plain-PD targets (the take-off pose plus Gaussian noise,
        one draw per control step at 10 Hz) clear the curriculum's first difficulty from each
        row of Table 3.3/3.4, as printed and with ω_z negated: whether a sparse-reward
        training from that take-off state has any first success to learn from, and how many
        of those exploratory episodes the simulation blew up in
    python benchmarks/jump.py report RUN_DIR --name highjump_fosbury [--out docs]
        the figures of a training run into --out (default docs/): its curriculum curve
        (`takeoff plot`), the deterministic jump as a filmstrip with bar and mat, the peak pose
        from two views (along the bar and facing it) and, as the gallery draws it, along the
        bar and from above and below (Fig. 3.4), and its summary with the crossing feature as
        NAME.json (into --out, default benchmarks/results/)

Learning runs are `takeoff train configs/highjump.toml` (docs/benchmarks.md gives the commands
and the figures). Needs the reference data (TAKEOFF_DATA, default ../shared/data) and a trained
P-VAE (`--pvae`, default runs/pvae; `--set highjump.actions=pd` times plain-PD actions).
"""

import argparse
import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import training_speed
from agents.commands import train_commands
from agents.rl import trainer as trainer_lib
from agents.pose import pose_features
from agents.commands.cli import run_errors
from agents.discovery import pictures
from agents.tasks import jump, registry, takeoff_state
from jaxsim import allocator, batch_last, render, simulation, xla_options
from jaxsim.atomic import write_text_atomic
from spd import machine_info, reference_data

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DOCS = ROOT / "docs"


def speed(args):
    config = ROOT / "configs" / f"{args.task}.toml"
    results = []
    for rate in args.rates:
        overrides = [f"{args.task}.pvae={args.pvae}", f"{args.task}.control_schedule=false",
                     f"{args.task}.control_hz={rate}", *args.set]
        figures = training_speed.measure(config, reference_data("jump"), overrides,
                                         args.repeats)
        results.append({"control_hz": rate, **figures})
        print(f"{rate:>5g} Hz  {figures['samples_per_second']:8.0f} samples/s  "
              f"rollout {figures['rollout_seconds']:.2f} s  update "
              f"{figures['update_seconds']:.2f} s (floor {figures['update_floor_seconds']:.2f})"
              f"  iteration {figures['iteration_seconds']:.2f} s (one program "
              f"{figures['one_program_iteration_seconds']:.2f} s)"
              f"  {figures['simulation_steps_per_second']:9.0f} simulation steps/s  compile "
              f"{figures['compile_seconds']['iteration']:.1f} s")
    out = RESULTS / f"{args.task}_speed.json"
    write_text_atomic(out, json.dumps({"machine": machine_info(), "results": results},
                                      indent=2) + "\n")
    print(f"→ {out}")


def _traced_control_step(model, world, physics, target, dt, substeps, method):
    """`substeps` (a traced count) simulation steps towards `target`, with touch bookkeeping."""
    def substep(_, carry):
        state, touched = carry
        state = simulation.step(model, world, state, target, dt, method)
        return state, touched | state.touching

    touched = jnp.zeros(physics.touching.shape, bool)
    return jax.lax.fori_loop(0, substeps, substep, (physics, touched))


def substeps(args):
    settings = jump.HighJumpSettings(actions="pd", control_schedule=False)
    env = jump.JumpEnv(settings, reference_data("jump"))
    params = env.default_params()
    keys = jax.random.split(jax.random.PRNGKey(0), args.envs)
    states = jax.vmap(env.reset, in_axes=(None, 0))(params, keys)
    world = env.world_for(jax.tree_util.tree_map(lambda x: x[0], states.task))   # all alike
    target = jnp.broadcast_to(env.q0, (args.envs, env.model.nq))
    dt = 1.0 / settings.sim_hz
    physics = states.physics
    compiled = lambda fn: jax.jit(fn, compiler_options=xla_options.simulation_options())
    rows = []    # batched as the rollout batches its environments
    for rate in jump.CONTROL_RATES:
        n = int(round(settings.sim_hz / rate))
        static = compiled(batch_last.vmap(lambda p, t, n=n: jump.common.simulate_control_step(
            env.model, world, p, t, dt, n, settings.method)))
        shared = compiled(batch_last.vmap(lambda p, t, k: _traced_control_step(
            env.model, world, p, t, dt, k, settings.method), in_axes=(0, 0, None)))
        each = compiled(batch_last.vmap(lambda p, t, k: _traced_control_step(
            env.model, world, p, t, dt, k, settings.method)))
        static_s, static_first = training_speed.timed(static, physics, target,
                                                      repeats=args.repeats)
        shared_s, shared_first = training_speed.timed(shared, physics, target, n,
                                                      repeats=args.repeats)
        each_s, each_first = training_speed.timed(
            each, physics, target, jnp.full(args.envs, n), repeats=args.repeats)
        rows.append({"control_hz": rate, "substeps": n, "static_seconds": static_s,
                     "traced_shared_seconds": shared_s, "traced_per_env_seconds": each_s,
                     "compile_seconds": {"static": static_first, "traced_shared": shared_first,
                                         "traced_per_env": each_first}})
        print(f"{rate:>5g} Hz ({n:2d} substeps)  static {static_s * 1e3:7.1f} ms  traced, "
              f"one count {shared_s * 1e3:7.1f} ms  traced, per env {each_s * 1e3:7.1f} ms  "
              f"(first calls {static_first:.1f} / {shared_first:.1f} / {each_first:.1f} s)")
    out = RESULTS / "jump_substeps.json"
    write_text_atomic(out, json.dumps({"machine": machine_info(), "envs": args.envs,
                                       "results": rows}, indent=2) + "\n")
    print(f"→ {out}")


def explore(args):
    settings = registry.get(args.task).settings(actions="pd", control_schedule=False,
                                                control_hz=10.0)
    env = jump.JumpEnv(settings, reference_data("jump"))
    hold = pose_features.target_to_exp(env.model, pose_features.pd_target(env.model, env.q0))
    # One outcome per episode, the first listed of those that ended it: a blow-up before any
    # other failure, for what a blown-up step touched is not physics.
    names = ("success", "blew_up", *(f for f in jump.FAILURES if f != "blew_up"))

    def episode(x, actions):
        """The outcome (index into `names`, or −1: still running) of one open-loop episode."""
        params = {**env.default_params(), "takeoff": x}
        state = env.reset(params, jax.random.PRNGKey(0))

        def control_step(carry, action):
            state, outcome = carry
            state = env.step(params, state, action)
            ended = jnp.stack([state.metrics[f"episode/{n}"] > 0 for n in names])
            now = jnp.where(ended.any(), jnp.argmax(ended), -1)
            return (state, jnp.where(outcome < 0, now, outcome)), None

        (_, outcome), _ = jax.lax.scan(control_step, (state, jnp.asarray(-1)), actions)
        return outcome

    batch = jax.jit(jax.vmap(episode, in_axes=(None, 0)))
    steps = int(round(jump.TIME_AFTER_TAKEOFF * env.control_hz))     # every episode ends
    rows, features = ((takeoff_state.HIGHJUMP_ROWS, takeoff_state.HIGHJUMP_FEATURES)
                      if args.task == "highjump" else
                      (takeoff_state.OBSTACLE_ROWS, takeoff_state.OBSTACLE_FEATURES))
    z = features.index("omega_z")
    key, results = jax.random.PRNGKey(args.seed), []
    for name, row in rows.items():
        for negated in (False, True):
            x = np.array(row, np.float32)
            x[z] = -x[z] if negated else x[z]
            key, draw = jax.random.split(key)
            actions = hold + args.sigma * jax.random.normal(
                draw, (args.episodes, steps) + hold.shape)
            outcome = np.asarray(batch(jnp.asarray(x), actions))
            shares = {n: float(np.mean(outcome == i)) for i, n in enumerate(names)}
            results.append({"row": name, "omega_z_negated": negated, "x": x.tolist(), **shares})
            print(f"{name:>28}{' (ω_z negated)' if negated else '':>15}  x {np.round(x, 2)}  "
                  f"success {int(round(shares['success'] * args.episodes)):3d}/{args.episodes}"
                  f"  hit {shares['hit_bar']:.2f}  ground {shares['on_ground']:.2f}"
                  f"  blew up {shares['blew_up']:.3f}")
    out = RESULTS / f"{args.task}_explore.json"
    write_text_atomic(out, json.dumps({"machine": machine_info(), "episodes": args.episodes,
                                       "sigma": args.sigma, "results": results}, indent=2) + "\n")
    print(f"→ {out}")


def report(args):
    run = Path(args.run_dir)
    data = reference_data("jump")
    summary, env, poses = train_commands.evaluate(run, episodes=args.episodes, data_dir=data,
                                                  echo=lambda _: None)
    train_commands.plot(run, quiet=True)
    out = Path(args.out or DOCS)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run / train_commands.CURVE, out / f"{args.name}_curve.png")
    z = summary["episode/difficulty"]
    task = {"takeoff": jnp.asarray(env.settings.x, env.q0.dtype),
            "difficulty": jnp.asarray(z, env.q0.dtype)}
    _, along = pictures.bar_directions(env, task)
    world = env.world_for(task)
    times = np.arange(1, len(poses) + 1) * env.control_dt
    outcome = "cleared" if summary["episode/success"] else "failed"
    thing = "bar" if env.kind == "highjump" else "obstacle"
    render.filmstrip(env.model, poses, out / f"{args.name}_filmstrip.png", world=world,
                     n_panels=min(10, len(poses)), times=times,
                     azimuth=pictures.azimuth_looking_along(along),
                     title=f"{args.name}: the deterministic jump at z = {z:.2f} m ({outcome}), "
                           f"seen along the {thing}")
    pictures.peak_views(env, poses, task, out / f"{args.name}_peak.png")
    pictures.peak_above_below(env, poses, task, out / f"{args.name}_above_below.png")
    records = trainer_lib.read_metrics(run)
    result = {"machine": machine_info(), "run": str(run), "iterations": records[-1]["iteration"],
              "samples": records[-1]["samples"], "minutes": records[-1]["seconds"] / 60,
              "evaluation": summary}
    write_text_atomic(Path(args.out or RESULTS) / f"{args.name}.json",
                      json.dumps(result, indent=2) + "\n")
    print(json.dumps(result["evaluation"], indent=2))


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("speed")
    p.add_argument("--task", choices=("highjump", "obstacle"), default="highjump")
    p.add_argument("--rates", type=float, nargs="+", default=[10.0, 30.0])
    p.add_argument("--pvae", default="runs/pvae")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    p.set_defaults(run=speed)
    p = sub.add_parser("substeps")
    p.add_argument("--envs", type=int, default=256)
    p.add_argument("--repeats", type=int, default=5)
    p.set_defaults(run=substeps)
    p = sub.add_parser("explore")
    p.add_argument("--task", choices=("highjump", "obstacle"), default="obstacle")
    p.add_argument("--episodes", type=int, default=512)
    p.add_argument("--sigma", type=float, default=0.8)
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(run=explore)
    p = sub.add_parser("report")
    p.add_argument("run_dir")
    p.add_argument("--name", required=True)
    p.add_argument("--out", help="folder of the figures and the JSON (default: the figures "
                                 "in docs/, the JSON in benchmarks/results/)")
    p.add_argument("--episodes", type=int, default=16)
    p.set_defaults(run=report)
    args = parser.parse_args()
    try:
        args.run(args)
    except run_errors() as error:
        raise SystemExit(f"benchmarks/jump.py {args.command}: {error}")


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
