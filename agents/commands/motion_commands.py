"""`takeoff motion RUNUP_DIR JUMP_DIR --out DIR`: a run-up policy and a jump policy as one full
motion (thesis §3.6.1), rendered and exported.

`full_motion(runup_dir, jump_dir, out_dir)` loads the two training runs (a `runup` run and a
`highjump`/`obstacle` run of the same x; the jump at its run's difficulty, or at the bar height
(obstacle width) `bar`, and at its run's control rate),
runs `agents.tasks.full_motion` once with their deterministic policies, and writes to out_dir:

  motion.gif       the whole motion with the jump's bar (or obstacle) and landing block
  filmstrip.png    ten evenly spaced frames of it
  motion.bvh       the whole motion as BVH (lengths in metres, Y up; Blender: File › Import ›
                   Motion Capture (.bvh), scale 1), read back with `jaxsim.motion.load_bvh` and
                   checked against the simulated joint positions before it is kept
  summary.json     the switch (its step and time, and the clip's take-off time), the run-up's
                   tracking error and falls, the state at the switch against the desired
                   take-off state of x (root velocities in the facing frame, r_G of eq. 3.13 or
                   3.14 with the run-up's own terms, joint angles and their velocities), and how
                   the jump ended (at its bar)

Frames are at the run-up's control rate unless `fps` says otherwise (see `full_motion.resample`).
"""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents import config as config_io
from agents.commands import train_commands
from agents.rl import trainer as trainer_lib
from agents.tasks import full_motion as fm
from agents.tasks import jump as jump_lib
from agents.tasks import takeoff_state
from agents.tasks.runup import joint_velocities, joint_velocity_error, takeoff_reward
from jaxsim import kinematics, motion, xla_options
from jaxsim.atomic import check_writable, write_text_atomic

GIF, FILMSTRIP, BVH, SUMMARY = "motion.gif", "filmstrip.png", "motion.bvh", "summary.json"
BVH_TOLERANCE = 1e-3        # m: the joints read back from the BVH against the simulated ones


@dataclasses.dataclass(frozen=True)
class LoadedRun:
    """A training run ready to act: its config, trainer (networks), environment at the run's
    difficulty, task parameters (one set), deterministic policy and iterations done."""

    run_dir: Path
    config: object
    trainer: object
    env: object
    params: dict
    policy: fm.Policy
    iterations: int


def load_run(run_dir, data_dir=None, echo=print) -> LoadedRun:
    """A run directory of `takeoff train` with its newest intact checkpoint (on one device,
    however it was trained)."""
    run_dir = Path(run_dir)
    config = train_commands.load_run_config(run_dir)
    config = dataclasses.replace(config, run=dataclasses.replace(config.run, devices=1))
    try:
        trainer = train_commands.make_trainer(config, data_dir)
    except config_io.ConfigError as error:
        raise config_io.ConfigError(f"{run_dir / train_commands.CONFIG}: "
                                    f"[{config.run.task}]: {error}") from None
    template = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype),
                                      jax.eval_shape(trainer.init))
    state = trainer_lib.load_checkpoint(template, run_dir, echo)
    params = trainer.curriculum.params(trainer.env_params, state.curriculum)
    return LoadedRun(run_dir, config, trainer, trainer.env_for(state.curriculum), params,
                     fm.Policy(state.ppo.policy_params, state.norm),
                     trainer_lib.completed_iterations(state))


def check_runs(runup: LoadedRun, jump: LoadedRun):
    """A ConfigError naming the run directories unless the first is a run-up and the second a
    jump it can hand over to (`full_motion.check_pair`)."""
    if runup.config.run.task != "runup":
        raise config_io.ConfigError(f"{runup.run_dir}: a run of the task "
                                    f"{runup.config.run.task!r}; RUNUP_DIR must be a runup run")
    if jump.config.run.task not in jump_lib.KINDS:
        raise config_io.ConfigError(f"{jump.run_dir}: a run of the task {jump.config.run.task!r};"
                                    f" JUMP_DIR must be a {' or '.join(jump_lib.KINDS)} run")
    try:
        fm.check_pair(runup.env, jump.env, runup.params, jump.params)
    except ValueError as error:
        raise config_io.ConfigError(f"{runup.run_dir} and {jump.run_dir}: {error}") from None


def run_full_motion(runup: LoadedRun, jump: LoadedRun, seed: int = 0) -> fm.FullMotion:
    """The full motion of two loaded runs (`full_motion.make_full_motion`, jitted), on the
    host."""
    check_runs(runup, jump)
    rollout = jax.jit(fm.make_full_motion(runup.env, jump.env, runup.trainer.policy_apply,
                                          jump.trainer.policy_apply),
                      compiler_options=xla_options.simulation_options())
    return jax.device_get(rollout(runup.params, jump.params, runup.policy, jump.policy,
                                  jax.random.PRNGKey(seed)))


def takeoff_error(runup_env, physics, x) -> dict:
    """The state at the switch against the desired take-off state of x: the root's angular
    and linear velocity in the facing frame minus the desired ones, r_G (eq. 3.13/3.14, with
    the run's own terms), the mean angle error of the joints and the rms error of their
    velocities, and the root's offset from the take-off pose (horizontal distance and
    height)."""
    s = runup_env.settings

    @jax.jit
    def compare(q, qd, x):
        q_goal, qd_goal = runup_env.desired_state(x)
        omega, velocity = takeoff_state.facing_velocities(q, qd)
        omega_goal, velocity_goal = takeoff_state.facing_velocities(q_goal, qd_goal)
        joints, joints_goal = (joint_velocities(runup_env.model, v) for v in (qd, qd_goal))
        reward = takeoff_reward(runup_env.kind, omega, velocity, omega_goal, velocity_goal,
                                **s.takeoff_weights, joint_velocity=joints,
                                target_joint_velocity=joints_goal)
        _, angles = runup_env.errors(q, qd, q_goal, qd_goal)       # joint 0: the root
        return (omega, omega_goal, velocity, velocity_goal, reward, angles, q[:3] - q_goal[:3],
                jnp.sqrt(joint_velocity_error(joints, joints_goal)))

    q = jnp.asarray(physics.q)
    omega, omega_goal, velocity, velocity_goal, reward, angles, offset, joints_rms = \
        jax.device_get(compare(q, jnp.asarray(physics.qd), jnp.asarray(x, q.dtype)))
    return {"omega": _floats(omega), "omega_target": _floats(omega_goal),
            "omega_l1_error": float(np.sum(np.abs(omega - omega_goal))),
            "velocity": _floats(velocity), "velocity_target": _floats(velocity_goal),
            "v_z_error": float(velocity[2] - velocity_goal[2]),
            "v_y_error": float(velocity[1] - velocity_goal[1]),
            "takeoff_reward": float(reward),
            "joint_angle_error_degrees": float(np.degrees(np.mean(angles[1:]))),
            "joint_velocity_rms_error": float(joints_rms),
            "root_horizontal_offset_m": float(np.hypot(offset[0], offset[2])),
            "root_height_offset_m": float(offset[1])}


def _floats(values):
    return [round(float(v), 6) for v in np.asarray(values)]


def summarise(runup: LoadedRun, jump: LoadedRun, full: fm.FullMotion) -> dict:
    """The summary.json of a full motion (see the module docstring)."""
    K = runup.env.runup_steps
    policy, times = np.asarray(full.policy), fm.step_times(full)
    switch = fm.switch_step(full)
    fell = np.asarray(full.runup_fell)[:K]
    jump_state = full.jump
    metrics = {k: float(v) for k, v in jump_state.metrics.items()}
    turn = np.asarray(full.handover.turn, float)
    return {
        "kind": runup.env.kind,
        "takeoff_x": _floats(runup.params["takeoff"]),
        "runup_run": str(runup.run_dir), "runup_iterations": runup.iterations,
        "jump_run": str(jump.run_dir), "jump_iterations": jump.iterations,
        "start_time": float(full.start_time),
        "takeoff_time": float(runup.env.takeoff.time),
        "runup_control_hz": float(runup.env.settings.control_hz),
        "switch_step": switch,
        "switch_time": float(times[switch - 1]) if switch > 0 else None,
        "runup": {"steps": int(np.sum(policy == fm.RUNUP)),
                  "fell": bool(fell.any()),
                  "first_fall_time": float(times[np.argmax(fell)]) if fell.any() else None,
                  "tracking_error_degrees": float(np.mean(np.asarray(full.tracking_degrees)[:K]))},
        "takeoff_state_error": takeoff_error(runup.env, full.takeoff_physics,
                                             runup.params["takeoff"]),
        "handover_turn_degrees": float(np.degrees(np.arccos(np.clip(turn[0, 0], -1, 1)))),
        "jump": {"control_hz": float(jump.env.control_hz),
                 "steps": int(np.sum(policy == fm.JUMP)),
                 "bar": float(jump_state.task["difficulty"]),
                 "success": bool(metrics["episode/success"] > 0),
                 "failure": [name for name in jump_lib.FAILURES
                             if metrics[f"episode/{name}"] > 0],
                 "reward": metrics["episode/reward"],
                 "crossed": bool(metrics["episode/crossed"] > 0),
                 "up_angle": metrics["episode/up_angle"],
                 "clearance": metrics["episode/clearance"],
                 "peak_com": metrics["episode/peak_com"]},
    }


def export_bvh(model, clip, fps: float, path) -> dict:
    """Write the motion's clip (`full_motion.resample`) as BVH at `fps`, read it back with our
    own reader and compare its joints with the model's joints over the same frames: a
    ValueError when they differ by more than `BVH_TOLERANCE`; else the frames and the largest
    difference (m)."""
    skeleton_clip = motion.from_model_clip(model, clip, fps)
    motion.save_bvh(path, skeleton_clip)
    back = motion.load_bvh(path)
    order = [back.skeleton.index(name) for name in model.topology.names]
    _, starts, _ = motion.world_pose(back)
    times = jnp.asarray(np.arange(skeleton_clip.n_frames) / fps, clip.poses.dtype)
    joints = jax.jit(jax.vmap(lambda c, t: kinematics.forward_kinematics(
        model, motion.sample_pose(c, t))[1], (None, 0)))(clip, times)
    deviation = float(np.max(np.abs(starts[:, order] - np.asarray(joints, float))))
    if back.n_frames != skeleton_clip.n_frames or not deviation <= BVH_TOLERANCE:
        raise ValueError(f"{path}: the BVH read back {back.n_frames} frames, its joints up to "
                         f"{deviation:.3g} m from the motion's")
    return {"frames": back.n_frames, "frame_time": back.frame_time,
            "max_joint_deviation_m": deviation}


def full_motion(runup_dir, jump_dir, out_dir, data_dir=None, fps: float | None = None,
                seed: int = 0, render: bool = True, echo=print, bar: float | None = None):
    """`takeoff motion`: load both runs, run the full motion (the jump at `bar`, else at its
    run's difficulty), write the GIF, filmstrip, BVH and summary in out_dir (only the BVH and
    summary with `render` false). Returns the summary and the `FullMotion`."""
    out_dir = Path(out_dir)
    if bar is not None and not (np.isfinite(bar) and bar > 0):
        raise config_io.ConfigError(f"--bar must be a bar height (obstacle width) > 0 in m; "
                                    f"got {bar}")
    runup = load_run(runup_dir, data_dir, echo)
    jump = load_run(jump_dir, data_dir, echo)
    check_runs(runup, jump)
    if bar is not None:
        difficulty = jnp.asarray(bar, jump.params["difficulty"].dtype)
        jump = dataclasses.replace(jump, params={**jump.params, "difficulty": difficulty})
    fps = float(runup.env.settings.control_hz if fps is None else fps)
    if not (np.isfinite(fps) and fps > 0):
        raise config_io.ConfigError(f"--fps must be a number > 0; got {fps}")
    out_dir.mkdir(parents=True, exist_ok=True)
    check_writable(out_dir, what="the full motion")
    echo(f"full motion: run-up {runup.run_dir} (iteration {runup.iterations}) → jump "
         f"{jump.run_dir} (iteration {jump.iterations}, bar {float(jump.params['difficulty']):.2f}"
         f" m, {jump.env.control_hz:g} Hz)")
    full = run_full_motion(runup, jump, seed)
    summary = summarise(runup, jump, full)
    model = runup.env.model
    clip, poses, times = fm.resample(model, full, fps)
    summary["fps"] = fps
    summary["bvh"] = export_bvh(model, clip, fps, out_dir / BVH)
    assert summary["bvh"]["frames"] == len(poses)          # the GIF's frames are the BVH's
    if render:
        from jaxsim import render as render_lib
        world = full.handover.world_to_runup(jump.env.world_for(full.jump.task))
        render_lib.animation(model, poses, out_dir / GIF, world=world, fps=fps, times=times)
        render_lib.filmstrip(model, poses, out_dir / FILMSTRIP, world=world, n_panels=10,
                             times=times, title=f"{runup.env.kind}: run-up → jump at "
                                                f"{summary['switch_time']:.2f} s")
    write_text_atomic(out_dir / SUMMARY, json.dumps(summary, indent=2) + "\n")
    echo(json.dumps({k: summary[k] for k in ("switch_step", "switch_time", "takeoff_time")}))
    echo(f"run-up: tracking {summary['runup']['tracking_error_degrees']:.1f}°, fell "
         f"{summary['runup']['fell']}; at the switch r_G "
         f"{summary['takeoff_state_error']['takeoff_reward']:.3f}; jump success "
         f"{summary['jump']['success']} → {out_dir}")
    return summary, full
