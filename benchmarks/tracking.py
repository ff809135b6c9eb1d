"""The thesis's chapter-2 experiments on our simulator: SPD tracking stability and speed.

Subcommands (each prints a markdown table and writes JSON to benchmarks/results/):

  stability  Figures 2.4/2.5 analogue. Hand-of-God SPD tracking (jaxsim.tracking) of the humanoid
             *run* and the dog *canter* for --seconds, at Δt ∈ {1/600 … 1/30}, with `dense` and
             `maba`, in float32 and float64. Error: mean end-effector-to-root vector error (right
             ankle; the dog's right front toe, `right_finger`); "diverged" when it is not finite
             or above 1 m. No ground: the root is held by its SPD. Writes a PNG plot per character.
  speed      Tables 2.2/2.3 analogue. Simulated steps per second of the tracking task (one
             `simulate` call of --steps steps, median of repeats, compile time apart) for each
             method, character and batch size, and two shares of the step: the solve's,
             1 − (the same scan with the solve taken out) / (the rollout), and what SPD adds to
             plain forward dynamics, 1 − (the rollout with ABA in place of SPD) / (the rollout).
  contacts   Humanoid standing on the ground at 600 Hz (contacts, joint limits, maba; with
             --torque-limits also the two-pass torque limits): character-steps per second and
             compile time at each batch size; with --mujoco also MuJoCo stepping the same
             humanoid, for scale (`mujoco_scene`).
  filmstrip  The humanoid tracking the cartwheel clip, drawn as a filmstrip PNG.
  plot       Redraw the stability plots from the last stability JSON.

Every rollout is compiled as `simulation.simulate` compiles it: `maba` (and the ABA references)
with the XLA options of `jaxsim.xla_options`, `dense` and `sparse` with XLA's defaults. Set
TAKEOFF_XLA_DEFAULTS=1 to compile everything with XLA's defaults.

Run:  python benchmarks/tracking.py stability
      python benchmarks/tracking.py speed --batch 1 --methods dense sparse maba
      python benchmarks/tracking.py contacts --batch 1 256 4096 --mujoco
      python benchmarks/tracking.py filmstrip --out docs/cartwheel_tracking.png
"""

import argparse
import functools
import json
import os
import shlex
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)      # float64 runs; every model/world is cast explicitly

from jaxsim import (allocator, batch_last, characters, kinematics, motion, simulation,  # noqa: E402
                    tracking, xla_options)
from jaxsim.model import rest_pose  # noqa: E402
from jaxsim.world import make_world  # noqa: E402
from jaxsim.atomic import write_text_atomic  # noqa: E402
from spd import compile_and_time, machine_info, markdown_table, reference_data  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
STEPS = {"600": 1 / 600, "300": 1 / 300, "240": 1 / 240, "120": 1 / 120, "60": 1 / 60,
         "30": 1 / 30}
DIVERGED_M = 1.0


def deepmimic_dir() -> Path:
    return reference_data("deepmimic") / "deepmimic"


def deepmimic(name, dtype):
    dm = deepmimic_dir()
    model = characters.load_deepmimic(dm / f"characters/{name}.txt",
                                      dm / f"controllers/{name}_ctrl.txt", dtype=dtype)
    return tracking.tracking_model(model)


# Rows of the speed table: name → (character, clip, Δt). Snakes 1–3 are snake(10/22/63).
ROWS = {
    "humanoid walk": ("humanoid3d", "humanoid3d_walk", 1 / 30),
    "humanoid run": ("humanoid3d", "humanoid3d_run", 1 / 30),
    "humanoid cartwheel": ("humanoid3d", "humanoid3d_cartwheel", 1 / 30),
    "humanoid backflip": ("humanoid3d", "humanoid3d_backflip", 1 / 30),
    "dog pace": ("dog3d", "dog3d_pace", 1 / 240),
    "dog trot": ("dog3d", "dog3d_trot", 1 / 240),
    "dog canter": ("dog3d", "dog3d_canter", 1 / 240),
    "snake1 slither": (10, None, 1 / 30),
    "snake2 slither": (22, None, 1 / 30),
    "snake3 slither": (63, None, 1 / 30),
}


def task(row, dtype):
    """(tracking model, clip, Δt) of a speed-table row."""
    character, clip_name, dt = ROWS[row]
    if isinstance(character, int):
        model = tracking.tracking_model(characters.snake(character, dtype=dtype))
        return model, motion.slither_clip(model), dt
    model = deepmimic(character, dtype)
    return model, motion.load_motion(deepmimic_dir() / f"motions/{clip_name}.txt", model), dt


# ---------------------------------------------------------------------------------------------
# stability


def stability(args):
    world64 = make_world(ground=False, joint_limits=False, dtype=jnp.float64)
    cases = [("humanoid run", "humanoid3d", "humanoid3d_run", "right_ankle"),
             ("dog canter", "dog3d", "dog3d_canter", "right_finger")]
    rows = []
    for label, character, clip_name, effector in cases:
        for dtype in (jnp.float32, jnp.float64):
            model = deepmimic(character, dtype)
            clip = motion.load_motion(deepmimic_dir() / f"motions/{clip_name}.txt", model)
            world = world64.astype(dtype)
            for rate, dt in STEPS.items():
                n = int(round(args.seconds / dt))
                for method in ("dense", "maba"):
                    start = time.perf_counter()
                    traj = tracking.track(model, world, clip, dt, n, method,
                                          check_result=False)
                    error = np.asarray(tracking.end_effector_error(model, clip, traj.q, dt,
                                                                   effector))
                    finite = bool(np.isfinite(error).all())
                    mean = float(error.mean()) if finite else float("nan")
                    diverged = not finite or mean > DIVERGED_M
                    rows.append({"case": label, "dtype": jnp.dtype(dtype).name, "rate_hz": rate,
                                 "dt": dt, "method": method, "mean_error_m": mean,
                                 "max_error_m": float(error.max()) if finite else float("nan"),
                                 "diverged": diverged})
                    print(f"{label} {jnp.dtype(dtype).name} 1/{rate} {method}: "
                          f"{'diverged' if diverged else f'{mean * 100:.2f} cm'} "
                          f"({time.perf_counter() - start:.1f} s)", file=sys.stderr, flush=True)
    for label, *_ in cases:
        plot_stability(rows, label, args.plots / f"stability_{label.replace(' ', '_')}.png")
    table = markdown_table(
        ["case", "dtype", "method", *[f"1/{r} s" for r in STEPS]],
        [[c, d, m, *(_error_cell(rows, c, d, m, r) for r in STEPS)]
         for c in dict.fromkeys(r["case"] for r in rows) for d in ("float32", "float64")
         for m in ("dense", "maba")])
    return rows, f"Mean end-effector-to-root error (cm) over {args.seconds} s\n\n{table}\n"


def _error_cell(rows, case, dtype, method, rate):
    row = next(r for r in rows if (r["case"], r["dtype"], r["method"], r["rate_hz"]) ==
               (case, dtype, method, rate))
    return "diverged" if row["diverged"] else f"{100 * row['mean_error_m']:.2f}"


def replot(args):
    rows = json.loads((RESULTS / "tracking_stability.json").read_text())["results"]
    for case in dict.fromkeys(r["case"] for r in rows):
        plot_stability(rows, case, args.plots / f"stability_{case.replace(' ', '_')}.png")
    sys.exit(0)


def plot_stability(rows, case, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for dtype, style in (("float32", "--"), ("float64", "-")):
        for method, marker in (("dense", "s"), ("maba", "o")):
            picked = [r for r in rows if (r["case"], r["dtype"], r["method"]) ==
                      (case, dtype, method)]
            dts = [r["dt"] for r in picked]
            errors = [DIVERGED_M * 2 if r["diverged"] else r["mean_error_m"] for r in picked]
            ax.plot(dts, errors, style, marker=marker, label=f"{method} {dtype}")
    ax.axhline(DIVERGED_M, color="grey", lw=0.8)
    ax.text(1 / 600, DIVERGED_M * 1.1, "diverged (plotted at 2 m)", fontsize=7)
    ax.set_xscale("log"), ax.set_yscale("log")
    ax.set_xticks([1 / float(r) for r in STEPS], [f"1/{r}" for r in STEPS])
    ax.minorticks_off()
    ax.tick_params(axis="x", labelrotation=45)
    ax.set_xlabel("time step Δt (s)"), ax.set_ylabel("mean end-effector error (m)")
    ax.set_title(f"SPD tracking: {case}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"wrote {path}", file=sys.stderr)


# ---------------------------------------------------------------------------------------------
# speed


def batched_states(state, batch):
    """`batch` copies of a state, split over the host devices when there are several (run with
    XLA_FLAGS=--xla_force_host_platform_device_count=2 to use both cores; docs/design.md,
    "Performance notes")."""
    states = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), state)
    n = jax.device_count()
    if n == 1 or batch % n:
        return states
    mesh = jax.make_mesh((n,), ("batch",), axis_types=(jax.sharding.AxisType.Auto,))
    return jax.device_put(states, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(
        "batch")))


def _timed(fn, args, repeats, method):
    """Compile seconds and the median of `repeats` run times of jit(fn)(*args), compiled as
    `simulation.simulate` compiles `method` (see `jaxsim.xla_options`)."""
    compile_s, _, times, _ = compile_and_time(fn, args, repeats, method)
    return compile_s, statistics.median(times)


def speed(args):
    world = make_world(ground=False, joint_limits=False, dtype=jnp.float32)
    rows = []
    for row in args.rows:
        model, clip, dt = task(row, jnp.float32)
        poses, velocities = tracking.reference_targets(clip, dt, args.steps)
        # Plain forward dynamics in place of SPD: ABA with the gains zeroed (so that explicit PD
        # at these Δt cannot blow up and time NaNs), the rest of the step unchanged.
        passive = tracking.tracking_model(model, (0.0, 0.0), (0.0, 0.0))

        def rollout(states, poses, velocities, model, method):
            return simulation.simulate_batch(model, world, states, poses, dt, method,
                                             target_velocities=velocities,
                                             batch_last=args.batch_layout)[0]

        def without_solve(states):
            # The same scan with the solve taken out (zero acceleration): what is left of a
            # tracking step is the integration.
            def body(s, _):
                return s.replace(q=kinematics.integrate(model, s.q, s.qd, dt)), None
            run = lambda s: jax.lax.scan(body, s, poses)[0]  # noqa: E731
            return simulation.batched(run, "maba", args.batch_layout)(states)

        for batch in args.batch:
            states = batched_states(tracking.initial_state(model, world, clip), batch)
            # The two references are compiled as `simulate` compiles maba (XLA options and all).
            _, aba_s = _timed(functools.partial(rollout, model=passive, method="pd"),
                              (states, poses, velocities), args.repeats, "pd")
            _, other_s = _timed(without_solve, (states,), args.repeats, "maba")
            for method in args.methods:
                if batch > 1 and method == "sparse" and not args.sparse_batched:
                    continue
                compile_s, run_s = _timed(functools.partial(rollout, model=model, method=method),
                                          (states, poses, velocities), args.repeats, method)
                rows.append({"row": row, "dof": model.nv, "dt": dt, "batch": batch,
                             "method": method, "layout": layout(method, args.batch_layout),
                             "steps": args.steps, "compile_s": compile_s,
                             "seconds": run_s, "steps_per_s": batch * args.steps / run_s,
                             "solve_share": 1.0 - other_s / run_s,
                             "spd_over_aba_share": 1.0 - aba_s / run_s,
                             "aba_steps_per_s": batch * args.steps / aba_s})
                print(f"{row} batch {batch} {method}: {rows[-1]['steps_per_s']:.0f} steps/s, "
                      f"solve {100 * rows[-1]['solve_share']:.0f}% of a step, SPD over ABA "
                      f"{100 * rows[-1]['spd_over_aba_share']:.0f}%, compile {compile_s:.1f} s",
                      file=sys.stderr, flush=True)
    table = markdown_table(
        ["task", "DoF", "Δt", "batch", "method", "layout", "steps/s", "solve share",
         "SPD over ABA", "compile s"],
        [[r["row"], r["dof"], f"1/{round(1 / r['dt'])}", r["batch"], r["method"], r["layout"],
          f"{r['steps_per_s']:,.0f}", f"{100 * r['solve_share']:.0f}%",
          f"{100 * r['spd_over_aba_share']:.0f}%", f"{r['compile_s']:.1f}"] for r in rows])
    return rows, (f"Tracking steps per second (all characters together), float32. Solve share: "
                  f"1 − (the scan with the solve taken out) / (the rollout). SPD over ABA: "
                  f"1 − (the rollout with plain ABA in place of SPD) / (the rollout).\n\n"
                  f"{table}\n")


# ---------------------------------------------------------------------------------------------
# contacts


def contact_scene(steps, torque_limits=False, batch_last=None, chunk=None):
    """The contact benchmark's setup: the humanoid (joints held by SPD, root free) dropped from
    5 cm onto the ground, maba, contacts and joint limits, 600 Hz, float32. Returns the model, its
    initial state and `rollout(states)`, `steps` steps of a batch of such states
    (`simulation.simulate_batch`, its `batch_last` and `chunk` as given, the batch split over
    every device there is: run with XLA_FLAGS=--xla_force_host_platform_device_count=2 for
    both cores)."""
    model = tracking.tracking_model(characters.humanoid(), root_gains=(0.0, 0.0))
    world = make_world(torque_limits=torque_limits)
    low, _ = characters.vertical_extent(model)
    q0 = rest_pose(model, -low + 0.05)
    targets = jnp.tile(q0, (steps, 1))

    def rollout(states):
        return simulation.simulate_batch(model, world, states, targets, 1 / 600,
                                         batch_last=batch_last, chunk=chunk,
                                         devices=jax.device_count())[0]
    return model, simulation.init_state(model, world, q0), rollout


def mujoco_scene(model, q0, dt, settle_s=1 / 3):
    """MuJoCo's counterpart of `contact_scene`, for scale: the same humanoid exported with
    `jaxsim.mjcf.to_mjcf`, contacts between the bodies and the ground only (as ours), every joint
    pulled to the rest pose by MuJoCo's joint springs with the tracking gains (its implicitfast
    integrator), dropped from the same pose. It lands, hops once, and from about 1/3 s stands on
    both feet (4 contacts) while slowly tipping forward; it is down within a second, as joint
    springs are not SPD. So the timed steps start `settle_s` after the drop. Returns the MjModel,
    that state (mjSTATE_FULLPHYSICS) and its number of contacts."""
    import xml.etree.ElementTree as ET

    import mujoco          # in the test extra

    from jaxsim.mjcf import to_mjcf
    stiffness, damping = tracking.JOINT_GAINS
    root = ET.fromstring(to_mjcf(model, "humanoid"))
    root.find("option").attrib.update(timestep=repr(dt), integrator="implicitfast")
    for geom in root.iter("geom"):
        ground = geom.get("name") == "ground"
        geom.attrib.update(contype="1" if ground else "0", conaffinity="0" if ground else "1")
    for joint in root.iter("joint"):
        joint.attrib.update(stiffness=repr(stiffness), damping=repr(damping))
    mj_model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    data = mujoco.MjData(mj_model)
    data.qpos[:] = np.asarray(q0, float)
    for _ in range(round(settle_s / dt)):      # setup, not timed
        mujoco.mj_step(mj_model, data)
    kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(mj_model, kind))
    mujoco.mj_getState(mj_model, data, state, kind)
    return mj_model, state, data.ncon


def time_mujoco(mj_model, state, batch, steps, repeats):
    """Median seconds of `steps` MuJoCo steps of `batch` copies of `state` (mujoco.rollout, one
    thread per core, one thread at batch 1), and the largest change of a root height."""
    import mujoco
    from mujoco import rollout

    threads = 1 if batch == 1 else os.cpu_count()
    datas = [mujoco.MjData(mj_model) for _ in range(threads)]
    states = np.tile(state, (batch, 1))
    times = []
    for _ in range(repeats + 1):                  # the first call is a warm-up
        start = time.perf_counter()
        out, _ = rollout.rollout(mj_model, datas, states, nstep=steps)
        times.append(time.perf_counter() - start)
    sink = float(np.max(np.abs(out[:, -1, 2] - state[2])))     # qpos[1], after the time entry
    return statistics.median(times[1:]), threads, sink


def contacts(args):
    """Each batch size: the rollout compiled for each --chunk, then timed in `repeats` rounds
    that call each once in turn (and MuJoCo once, with --mujoco), so that the VM's changes of
    speed during the measurement fall on all of them alike; medians of the rounds."""
    model, state, _ = contact_scene(args.steps, args.torque_limits, args.batch_layout)
    if args.mujoco:
        import mujoco
        mj_model, mj_state, mj_contacts = mujoco_scene(model, state.q, 1 / 600)
    rows = []
    for batch in args.batch:
        states = batched_states(state, batch)
        variants = []
        for chunk in args.chunk:
            piece = batch if chunk == "whole" else (chunk or None)
            rollout = contact_scene(args.steps, args.torque_limits, args.batch_layout, piece)[2]
            start = time.perf_counter()
            compiled = jax.jit(rollout, compiler_options=xla_options.options_for(
                "maba")).lower(states).compile()
            compile_s = time.perf_counter() - start
            jax.block_until_ready(compiled(states))
            variants.append((chunk if chunk else batch_last.default_chunk(), compiled, compile_s))
        times = [[] for _ in variants]
        mujoco_times, threads, sink = [], None, None
        for _ in range(args.repeats):
            for (_, compiled, _), spent in zip(variants, times):
                start = time.perf_counter()
                jax.block_until_ready(compiled(states))
                spent.append(time.perf_counter() - start)
            if args.mujoco:
                run_s, threads, sink = time_mujoco(mj_model, mj_state, batch, args.steps, 1)
                mujoco_times.append(run_s)
        for (chunk, _, compile_s), spent in zip(variants, times):
            run_s = statistics.median(spent)
            rows.append({"engine": "takeoff maba", "layout": layout("maba", args.batch_layout),
                         "batch": batch, "chunk": chunk, "devices": jax.device_count(),
                         "steps": args.steps, "compile_s": compile_s,
                         "seconds": run_s, "steps_per_s": batch * args.steps / run_s})
            print(f"contacts batch {batch} chunk {chunk} takeoff maba: "
                  f"{rows[-1]['steps_per_s']:.0f} steps/s", file=sys.stderr, flush=True)
        if args.mujoco:
            run_s = statistics.median(mujoco_times)
            rows.append({"engine": f"MuJoCo {mujoco.__version__}", "batch": batch,
                         "threads": threads, "steps": args.steps, "seconds": run_s,
                         "steps_per_s": batch * args.steps / run_s,
                         "contacts_at_start": mj_contacts, "root_height_change_m": sink})
            print(f"contacts batch {batch} {rows[-1]['engine']}: "
                  f"{rows[-1]['steps_per_s']:.0f} steps/s", file=sys.stderr, flush=True)
    table = markdown_table(
        ["engine", "layout", "batch", "chunk", "devices / threads", "character-steps/s",
         "compile s"],
        [[r["engine"], r.get("layout", "–"), r["batch"], r.get("chunk", "–"),
          r.get("devices", r.get("threads")), f"{r['steps_per_s']:,.0f}",
          f"{r['compile_s']:.1f}" if "compile_s" in r else "–"] for r in rows])
    limits = ", torque limits (two-pass)" if args.torque_limits else ""
    return rows, (f"Humanoid on the ground, 600 Hz, maba, contacts and joint limits{limits}, "
                  f"float32\n\n{table}\n")


# ---------------------------------------------------------------------------------------------
# filmstrip


def filmstrip(args):
    from jaxsim import render

    model = deepmimic("humanoid3d", jnp.float32)
    clip = motion.load_motion(deepmimic_dir() / "motions/humanoid3d_cartwheel.txt", model)
    world = make_world(joint_limits=False)
    dt = 1 / 600
    n = int(float(clip.duration) / dt)
    traj = tracking.track(model, world, clip, dt, n, "maba")
    error = tracking.end_effector_error(model, clip, traj.q, dt, "right_ankle")
    render.filmstrip(model, traj.q, args.out, world=world, n_panels=8, azimuth=90,
                     times=dt * np.arange(1, n + 1),
                     title=f"SPD tracking of DeepMimic's cartwheel (maba, 600 Hz, on the ground; "
                           f"mean ankle error {100 * float(error.mean()):.1f} cm)")
    print(f"wrote {args.out}", file=sys.stderr)
    return [{"mean_error_m": float(error.mean())}], ""


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="experiment", required=True)
    p = sub.add_parser("stability")
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--plots", type=Path, default=Path("docs"))
    p = sub.add_parser("plot", help="redraw the stability plots from the last stability JSON")
    p.add_argument("--plots", type=Path, default=Path("docs"))
    p = sub.add_parser("speed")
    batch_layout_argument(p)
    p.add_argument("--rows", nargs="+", choices=list(ROWS), default=list(ROWS))
    p.add_argument("--methods", nargs="+", choices=("dense", "sparse", "maba"),
                   default=["dense", "sparse", "maba"])
    p.add_argument("--batch", nargs="+", type=int, default=[1, 4096])
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--sparse-batched", action="store_true",
                   help="also time `sparse` above batch 1 (very slow: a scan over DoFs)")
    p = sub.add_parser("contacts")
    batch_layout_argument(p)
    p.add_argument("--batch", nargs="+", type=int, default=[1, 256, 4096])
    p.add_argument("--torque-limits", action="store_true",
                   help="clip torques and re-solve with ABA where they bind (two-pass mode)")
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--mujoco", action="store_true",
                   help="also time MuJoCo stepping the same humanoid (mujoco_scene), for scale")
    p.add_argument("--chunk", nargs="+", type=_chunk_size, default=[0],
                   help="members simulated at once (jaxsim.batch_last.vmap): a number, 0 for "
                        "the default, or 'whole' for the batch in one piece; each is timed")
    p = sub.add_parser("filmstrip")
    p.add_argument("--out", type=Path, default=Path("docs/cartwheel_tracking.png"))
    return parser.parse_args(argv)


def _chunk_size(text):
    """--chunk N|0|whole → a chunk size, 0 for the default, or "whole"."""
    if text == "whole":
        return text
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--chunk is a whole number ≥ 0 or 'whole', not {text!r}")
    return value


def layout(method, batch_last):
    """How `simulation.simulate_batch` lays out the batch for `method` under --layout."""
    return "batch last" if simulation.uses_batch_last(method, batch_last) else "batch first"


def _batch_last_flag(name):
    """--layout first|last → simulate_batch's batch_last (False|True)."""
    if name not in ("first", "last"):
        raise argparse.ArgumentTypeError(f"--layout is first or last, not {name!r}")
    return name == "last"


def batch_layout_argument(parser):
    parser.add_argument(
        "--layout", dest="batch_layout", type=_batch_last_flag, default=None,
        metavar="{first,last}",
        help="the batch first (as jax.vmap lays it out) or last (jaxsim.batch_last) for every "
             "method; by default, as simulate_batch chooses (last for every method but sparse)")


def main(argv=None):
    args = parse_args(argv)
    rows, table = {"stability": stability, "plot": replot, "speed": speed, "contacts": contacts,
                   "filmstrip": filmstrip}[args.experiment](args)
    print(table)
    record = {"command": shlex.join([sys.executable, *sys.argv]), "machine": machine_info(),
              "compiler_options": {m: xla_options.options_for(m) for m in ("dense", "sparse",
                                                                            "maba")},
              "results": rows}
    path = RESULTS / f"tracking_{args.experiment}.json"
    write_text_atomic(path, json.dumps(record, indent=2) + "\n")
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
