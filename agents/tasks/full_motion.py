"""The full motion of a jump (thesis §3.3, §3.6.1): the run-up policy from the start of its clip,
then, at the take-off time, the jump policy, as one rollout.

`make_full_motion(runup_env, jump_env, runup_apply, jump_apply)` gives a pure, jittable
function of the two policies' parameters and observation statistics that scans the control steps
of both phases (`lax.scan`; each step runs one phase's policy and environment under `lax.switch`):

  run-up   `runup_env.begin` at the earliest start on its grid (K steps before the take-off
           time t₀: the clip's first frame, or within one control step of it), the run-up
           policy's mean action at each of its control steps. Nothing ends the run-up early: a
           character that falls runs on to t₀ (it is reported).
  switch   after the run-up's K-th step, at t₀ exactly. The run-up's state is handed to the
           jump task (`handover`): the jump task's world (bar or obstacle, landing block) is laid
           out about its own take-off state, and its policy sees world-frame observations, so
           the character is moved, with everything it carries, by the turn about the vertical
           and the horizontal shift that take its heading and root onto the take-off state's
           (the physics does not change under them: flat ground, vertical gravity). The same
           turn and shift place the bar and block in the run-up's world.
  jump     the jump policy's mean action at the jump's control rate (the curriculum's, from its
           run) until its episode ends (success, failure or time limit); the steps after that
           hold the state and are marked as no policy's.

The poses come back in the run-up's world frame. The jump may act at a lower rate than the
run-up (10–30 Hz under the curriculum); `resample` makes frames at one rate from the control
steps' states, interpolating (slerp) between them where the jump's steps are longer.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from agents.tasks.observations import body_observation, heading_rotation
from jaxsim import contact, kinematics, motion, rotations
from jaxsim.model import State

RUNUP, JUMP, OVER = 0, 1, 2          # which policy acts in a step (OVER: none, the jump ended)
_FLAT = (1.0, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class Policy:
    """A trained policy as the rollout uses it: its network parameters and the observation
    statistics it was trained with (`agents.rl.ppo.RunningNorm`)."""

    params: object
    norm: object


jax.tree_util.register_dataclass(Policy, data_fields=["params", "norm"], meta_fields=[])


@dataclasses.dataclass(frozen=True)
class Handover:
    """The rigid motion from the run-up's world to the jump task's: p ↦ turn (p − shift_from) +
    shift_to, a turn about the vertical and horizontal shifts."""

    turn: jax.Array          # (3, 3)
    shift_from: jax.Array    # (3,)
    shift_to: jax.Array      # (3,)

    def pose_to_jump(self, q):
        """A pose of the run-up's world in the jump task's frame."""
        position = self.turn @ (q[:3] - self.shift_from) + self.shift_to
        orientation = rotations.quat_multiply(rotations.matrix_to_quat(self.turn), q[3:7])
        return q.at[:3].set(position).at[3:7].set(orientation)

    def pose_to_runup(self, q):
        """A pose of the jump task's frame in the run-up's world."""
        position = self.turn.T @ (q[:3] - self.shift_to) + self.shift_from
        orientation = rotations.quat_multiply(rotations.matrix_to_quat(self.turn.T), q[3:7])
        return q.at[:3].set(position).at[3:7].set(orientation)

    def world_to_runup(self, world):
        """The jump task's static boxes (bar or obstacle, block) moved into the run-up's world."""
        centres = (world.box_center - self.shift_to) @ self.turn + self.shift_from
        return world.replace(box_center=centres, box_rotation=self.turn.T @ world.box_rotation)


jax.tree_util.register_dataclass(Handover, data_fields=["turn", "shift_from", "shift_to"],
                                 meta_fields=[])


@dataclasses.dataclass(frozen=True)
class FullMotion:
    """What the rollout gives, per control step (S = K + the jump's episode steps): `policy`
    (S,) which policy acted (RUNUP, JUMP, OVER), `dt` (S,) the step's length (0 for OVER), `q`
    (S, nq) the pose after it in the run-up's world; `start_q` (nq,) the pose before the first
    step and `start_time` its clip time; `runup_fell` (S,) whether a link other than the feet
    touched the ground in a run-up step, `tracking_degrees` (S,) the run-up's mean joint-angle
    error to its reference; the run-up's state at the switch (`takeoff_physics`, its task
    `runup_task`), the `handover`, and the jump's last state (`jump`)."""

    policy: jax.Array
    dt: jax.Array
    q: jax.Array
    start_q: jax.Array
    start_time: jax.Array
    runup_fell: jax.Array
    tracking_degrees: jax.Array
    takeoff_physics: State
    runup_task: dict
    handover: Handover
    jump: object


jax.tree_util.register_dataclass(
    FullMotion, data_fields=[f.name for f in dataclasses.fields(FullMotion)], meta_fields=[])


def check_pair(runup_env, jump_env, runup_params, jump_params):
    """A ValueError saying why a run-up cannot hand over to a jump: another kind of jump,
    another reference clip or take-off frame, another character, another x or take-off
    vertical velocity."""
    if runup_env.kind != jump_env.kind:
        raise ValueError(f"the run-up leads into a {runup_env.kind} jump, the jump policy is "
                         f"for the {jump_env.kind}")
    if runup_env.clip_path.name != jump_env.clip_path.name or \
            runup_env.takeoff != jump_env.takeoff:
        raise ValueError(f"the run-up imitates {runup_env.clip_path.name} (take-off at "
                         f"{runup_env.takeoff.time:.3f} s), the jump starts from "
                         f"{jump_env.clip_path.name} (take-off at {jump_env.takeoff.time:.3f} s)")
    if runup_env.model.topology.names != jump_env.model.topology.names:
        raise ValueError("the run-up and the jump are not the same character")
    x_runup, x_jump = (np.asarray(p["takeoff"], float) for p in (runup_params, jump_params))
    if x_runup.shape != x_jump.shape or not np.allclose(x_runup, x_jump, atol=1e-6):
        raise ValueError(f"the run-up was trained for the take-off state x = "
                         f"{np.round(x_runup, 4).tolist()}, the jump for x = "
                         f"{np.round(x_jump, 4).tolist()}: a run-up hands over to the jump of "
                         f"its own x")
    clip_vertical = float(runup_env.vertical_velocity)
    jump_vertical = float(jump_params["vertical_velocity"])
    if abs(jump_vertical - clip_vertical) > 1e-6:
        raise ValueError(f"the jump was trained from a take-off vertical velocity of "
                         f"{jump_vertical:.3f} m/s, the run-up's take-off state has the clip's "
                         f"{clip_vertical:.3f} m/s")


def handover(runup_env, jump_env, physics, fresh):
    """The jump task's episode state from the run-up's physics state at the take-off time, and
    the `Handover` that moved it: the character turned about the vertical and shifted
    horizontally so that its heading and root are the take-off state's (where the jump task's
    world is laid out); its velocities are in body frames and do not change; the friction
    springs of its ground contacts turn with it (the jump's world also has box contacts, which
    start unstretched). The rest of the episode state is `fresh`'s, a `jump_env.reset` of the
    jump's task parameters, with the peak height of the centre of mass restarted from the new
    pose."""
    q, qd = physics.q, physics.qd
    heading = heading_rotation(rotations.quat_to_matrix(q[3:7]))
    turn = jump_env.heading @ heading.T
    flat = jnp.asarray(_FLAT, q.dtype)
    move = Handover(turn, q[:3] * flat, jump_env.q0[:3] * flat)
    moved = move.pose_to_jump(q)
    ground = len(contact.contact_layout(runup_env.model, runup_env.world))
    stretch = fresh.physics.contact_stretch.at[:ground].set(physics.contact_stretch @ turn.T)
    touching = fresh.physics.touching.at[:, 0].set(physics.touching[:, 0])
    jump_physics = State(moved, qd, stretch, touching)
    task = {**fresh.task, "peak_com": kinematics.center_of_mass(jump_env.model, moved)[1]}
    return fresh.replace(physics=jump_physics, task=task,
                         obs=body_observation(jump_env.model, moved, qd)), move


def make_full_motion(runup_env, jump_env, runup_apply, jump_apply):
    """motion(runup_params, jump_params, runup_policy, jump_policy, key) -> FullMotion (see the
    module docstring): `*_params` are the environments' task parameters (one set each, the
    jump's at the bar it is to clear), `*_policy` a `Policy` each, `*_apply` the networks'
    apply functions (`agents.rl.ppo.make_ppo(...).policy_apply`); actions are the policies'
    means."""
    K = runup_env.runup_steps
    n_steps = K + jump_env.episode_steps
    runup_dt, jump_dt = runup_env.control_dt, jump_env.control_dt

    def act(apply, policy, obs):
        return apply(policy.params, policy.norm.normalize(obs))

    def motion(runup_params, jump_params, runup_policy, jump_policy, key):
        runup_key, jump_key = jax.random.split(key)
        runup = runup_env.begin(runup_params, K, runup_key)
        fresh = jump_env.reset(jump_params, jump_key)     # (outside the scan: reset once)
        jump, move = handover(runup_env, jump_env, runup.physics, fresh)
        dtype = runup.physics.q.dtype

        def record(phase, dt, q, fell=False, tracking=0.0):
            return (jnp.asarray(phase, jnp.int32), jnp.asarray(dt, dtype), q,
                    jnp.asarray(fell, bool), jnp.asarray(tracking, dtype))

        def run_up(carry):
            runup, jump, move, phase = carry
            stepped = runup_env.step(runup_params, runup,
                                     act(runup_apply, runup_policy, runup.obs))
            switch = stepped.steps >= K
            handed, handed_move = handover(runup_env, jump_env, stepped.physics, fresh)
            pick = lambda new, old: jax.tree_util.tree_map(
                lambda a, b: jnp.where(switch, a, b), new, old)
            carry = (stepped, pick(handed, jump), pick(handed_move, move),
                     jnp.asarray(jnp.where(switch, JUMP, RUNUP), jnp.int32))
            return carry, record(RUNUP, runup_dt, stepped.physics.q,
                                 stepped.metrics["fell"] > 0,
                                 stepped.metrics["pose_error_degrees"])

        def jump_phase(carry):
            runup, jump, move, phase = carry
            stepped = jump_env.step(jump_params, jump, act(jump_apply, jump_policy, jump.obs))
            over = stepped.terminated | stepped.truncated
            carry = (runup, stepped, move, jnp.asarray(jnp.where(over, OVER, JUMP), jnp.int32))
            return carry, record(JUMP, jump_dt, move.pose_to_runup(stepped.physics.q))

        def held(carry):
            runup, jump, move, phase = carry
            return carry, record(OVER, 0.0, move.pose_to_runup(jump.physics.q))

        def control_step(carry, _):
            return jax.lax.switch(carry[3], (run_up, jump_phase, held), carry)

        carry = (runup, jump, move, jnp.asarray(RUNUP, jnp.int32))
        (runup_end, jump_end, move, _), (policy, dt, q, fell, tracking) = jax.lax.scan(
            control_step, carry, None, length=n_steps)
        return FullMotion(policy, dt, q, runup.physics.q, runup.task["start"], fell, tracking,
                          runup_end.physics, runup_end.task, move, jump_end)

    return motion


def step_times(full: FullMotion) -> np.ndarray:
    """The time at the end of each step (S,), on the run-up clip's clock."""
    return float(full.start_time) + np.cumsum(np.asarray(full.dt, float))


def switch_step(full: FullMotion) -> int:
    """The index of the first step the jump policy acted in (−1 when none did)."""
    jumps = np.flatnonzero(np.asarray(full.policy) == JUMP)
    return int(jumps[0]) if len(jumps) else -1


def keyframes(full: FullMotion):
    """(times (F,), poses (F, nq)) of the motion: its start and the end of every step in
    which a policy acted."""
    acted = np.asarray(full.policy) != OVER
    times = np.concatenate([[float(full.start_time)], step_times(full)[acted]])
    poses = np.concatenate([np.asarray(full.start_q, float)[None],
                            np.asarray(full.q, float)[acted]])
    return times, poses


def resample(model, full: FullMotion, fps: float):
    """The motion as a `jaxsim.motion.Clip` of its keyframes, and its poses sampled every 1/fps
    s from the start ((n, nq), slerp between keyframes; the keyframes themselves where the
    control rate is fps), with their times on the run-up clip's clock."""
    times, poses = keyframes(full)
    durations = np.append(np.diff(times), 1.0)
    clip = motion.make_clip(model, durations, poses, loop=False, source="full motion")
    n = int(np.floor((times[-1] - times[0]) * fps + 1e-9)) + 1    # as `from_model_clip`
    local = np.arange(n) / fps
    sampled = jax.jit(jax.vmap(motion.sample_pose, (None, 0)))(
        clip, jnp.asarray(local, clip.poses.dtype))
    return clip, np.asarray(sampled), times[0] + local
