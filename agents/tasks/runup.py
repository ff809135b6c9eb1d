"""The run-up controller (thesis §3.6.1, "Run-up Learning"): imitate the jump's reference run up to
its take-off time, and arrive there in the take-off state of a strategy's x.

A jump policy (`agents.tasks.jump`) starts from a take-off state: the reference run-up clip's pose
at its take-off frame, put down on the take-off foot, with a few root velocities set from x
(`agents.tasks.takeoff_state`). The run-up policy brings the character to that state from the
start of the run: the curved sprint (`VC5_sprint__curves_03.txt`) for the high jump, the straight
run of the box jump (`VC5_Run_jumpToBox_01.txt`) for the obstacle jump.

Imitation. This is the DeepMimic imitation of `agents.tasks.imitation` (its reward, PD targets,
observation and early termination, by inheritance: there is one copy of that code), with three
changes:

- the character is the jump's athlete (`humanoid3d_jumper60kg.txt` with DeepMimic's gains and its
  torque limits), in a world with torque limits, as the jump policy sees it;
- the reference is the clip moved down by the same height as the take-off state (`grounded`), so
  that at the take-off time it *is* the take-off pose: the release's clips float ~0.1 m above
  our ground;
- episodes run on the grid of control times that ends at the take-off time t₀: an episode starts
  at t₀ − k/f_control, k drawn uniformly from 1 … K (reference state initialisation on that
  grid; K = ⌊t₀ f_control⌋, the earliest start the clip allows) or always k = K
  (`start = "clip_start"`), and it ends after its k-th step, at t₀ exactly, where the jump policy
  takes over. It is a terminal state for the run-up (nothing of its task follows). The phase
  the policy sees is t / t₀.

Task reward, paid once, at the take-off step, on top of that step's imitation reward (weight
`w_takeoff`), unless the character fell. With ω the root's angular velocity and v the velocity of
its origin in the facing-direction-invariant frame (`takeoff_state.facing_velocities`) and the bars
the same features of the desired take-off state built from x:

    high jump (eq. 3.13)   r_G = exp(−k_ω ‖ω − ω̄‖₁ − k_v (v_z − v̄_z)²)
    obstacle  (eq. 3.14)   r_G = exp(−k_ω ‖ω − ω̄‖₁)

with k_ω = 1/3 and k_v = 0.7 (`k_takeoff_omega`, `k_takeoff_velocity`; the thesis's values as we
read its typeset equations). Ours, off by default, two more terms in either exponent:

    − k_y (v_y − v̄_y)²                 `k_takeoff_vertical`: the root's vertical velocity
    − k_q mean_j (q̇_j − q̇̄_j)²          `k_takeoff_joints`: the joints' velocities (rad/s),
                                       over every degree of freedom but the root's

which eqs. 3.13–3.14 leave to the imitation reward. A jump policy trained from the clip's
take-off state can need them: for the plain-PD search's 000 (docs/discovery/README.md, "A full
motion at 1.0 m") a run-up whose last stance began late was still sinking at the take-off
time (−0.93 m/s where the clip rises at 1.10), and one that arrived rising, with the root's
velocities within 0.07 m/s and 0.18 rad/s, still had its joints moving 2.6 rad/s (rms) off
the clip's, and that alone made the 1.0 m jump hit the bar (it clears with the clip's joint
velocities put in); with the joints' term alone the root sank again. For the high jump
ω̄ = (ω_x, −3, ω_z) and v̄_z come from x = (α, ω_x, ω_z, v_z); the approach angle α is not in
the reward, since the jump turns the bar about the take-off point
(`agents.tasks.jump.jump_geometry`). For the obstacle jump ω̄ = x. The targets are read off the
desired take-off state (`desired_state`) itself, the state `JumpEnv.reset` starts from for the
same x, so there is one definition of what x means.

How the thesis weighs the two rewards is not given. Here every step pays the imitation reward
(≤ 1) and the take-off step also `w_takeoff` r_G (default 10: with γ = 0.95 the imitation
rewards ahead of a step are worth at most 20).
"""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import ConfigError, check_positive
from agents.rl.env import end_of_step
from agents.tasks import common, registry, takeoff_state
from agents.tasks.imitation import ImitationEnv, ImitationSettings
from agents.tasks.jump import DEFAULT_TAKEOFF, KINDS, HighJumpSettings, ObstacleSettings
from jaxsim import characters, motion
from jaxsim.world import make_world

REFERENCE_CLIPS = {"highjump": HighJumpSettings.clip, "obstacle": ObstacleSettings.clip}
STARTS = ("random", "clip_start")
K_OMEGA = 1.0 / 3.0         # eqs. 3.13, 3.14
K_VELOCITY = 0.7            # eq. 3.13


@dataclass(frozen=True)
class RunupSettings(ImitationSettings):
    """The `[runup]` config section: the `[imitation]` keys (reward weights, control, actions)
    and the jump it leads into."""

    kind: str = "highjump"                     # "highjump" or "obstacle"
    takeoff: tuple[float, ...] = ()            # x; empty: the jump task's default row
    clip: str = ""                             # empty: the kind's reference run (jump/motions)
    character: str = "humanoid3d_jumper60kg.txt"   # under <data>/jump/characters, or a path
    controller: str = "humanoid3d_ctrl.txt"    # under <data>/deepmimic/controllers, or a path
    start: str = "random"                      # "random" (on the grid) or "clip_start"
    w_takeoff: float = 10.0                    # weight of r_G at the take-off step
    k_takeoff_omega: float = K_OMEGA
    k_takeoff_velocity: float = K_VELOCITY
    k_takeoff_vertical: float = 0.0            # ours: the vertical velocity in r_G (0: off)
    k_takeoff_joints: float = 0.0              # ours: the joints' velocities in r_G (0: off)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}; got {self.kind!r}")
        if not self.clip:
            object.__setattr__(self, "clip", REFERENCE_CLIPS[self.kind])
        super().__post_init__()
        if self.start not in STARTS:
            raise ValueError(f"start must be one of {', '.join(STARTS)}; got {self.start!r}")
        if not self.controller:
            raise ValueError("controller must name a file")
        check_positive(self, ("w_takeoff", "k_takeoff_omega", "k_takeoff_velocity",
                              "k_takeoff_vertical", "k_takeoff_joints"), allow_zero=True)
        if self.takeoff:
            takeoff_state.check_x(self.kind, self.takeoff, "takeoff")

    @property
    def x(self) -> tuple[float, ...]:
        return self.takeoff or DEFAULT_TAKEOFF[self.kind]

    @property
    def takeoff_weights(self) -> dict:
        """The weights of `takeoff_reward`, by keyword."""
        return {"k_omega": self.k_takeoff_omega, "k_velocity": self.k_takeoff_velocity,
                "k_vertical": self.k_takeoff_vertical, "k_joints": self.k_takeoff_joints}


def takeoff_reward(kind: str, omega, velocity, target_omega, target_velocity,
                   k_omega=K_OMEGA, k_velocity=K_VELOCITY, k_vertical=0.0, k_joints=0.0,
                   joint_velocity=None, target_joint_velocity=None):
    """The run-up's task reward r_G of eq. 3.13 (high jump: exp(−k_ω ‖ω − ω̄‖₁ − k_v (v_z −
    v̄_z)²)) or eq. 3.14 (obstacle: exp(−k_ω ‖ω − ω̄‖₁)), with our terms − k_y (v_y − v̄_y)² and
    − k_q mean (q̇_j − q̇̄_j)² added to the exponent where their weights (`k_vertical`,
    `k_joints`; see the module docstring) are not 0; ω, v and their targets are the root's
    angular and linear velocity in the facing frame (3,), q̇_j `joint_velocity` the velocities
    of every degree of freedom but the root's (needed for k_joints > 0)."""
    exponent = -k_omega * jnp.sum(jnp.abs(omega - target_omega), axis=-1)
    if kind == "highjump":
        exponent = exponent - k_velocity * (velocity[..., 2] - target_velocity[..., 2]) ** 2
    if k_vertical:
        exponent = exponent - k_vertical * (velocity[..., 1] - target_velocity[..., 1]) ** 2
    if k_joints:
        if joint_velocity is None:
            raise ValueError("k_joints > 0 needs joint_velocity and target_joint_velocity")
        exponent = exponent - k_joints * joint_velocity_error(joint_velocity,
                                                              target_joint_velocity)
    return jnp.exp(exponent)


def joint_velocities(model, qd):
    """The velocities of every degree of freedom but the root's."""
    return qd[..., int(model.topology.dof_offsets[1]):]


def joint_velocity_error(joint_velocity, target_joint_velocity):
    """mean_j (q̇_j − q̇̄_j)², (rad/s)²: our joint term of r_G."""
    return jnp.mean((joint_velocity - target_joint_velocity) ** 2, axis=-1)


class RunupEnv(ImitationEnv):
    """The run-up task (see the module docstring) with the `agents.rl.env.Env` interface.
    `takeoff` is the clip's take-off frame, `runup_steps` = K the control steps from the
    earliest start to it, `first_start` that start's clip time. Settings that do not fit the
    data are a ConfigError naming the key of the `[runup]` section."""

    def __init__(self, settings: RunupSettings, data_dir, dtype=jnp.float32):
        data = Path(data_dir)
        model = characters.athlete(
            common.data_file(settings.character, data / "jump" / "characters", "character"),
            common.data_file(settings.controller, data / "deepmimic" / "controllers",
                             "controller"), dtype=dtype)
        common.link_indices(model, settings.feet, "feet")
        self.clip_path = common.data_file(settings.clip, data / "jump" / "motions", "clip")
        clip = motion.load_motion(self.clip_path, model)
        self.takeoff, q0, qd0 = takeoff_state.takeoff_start(model, clip, settings.feet,
                                                            settings.clip)
        drop = q0[1] - motion.sample_pose(clip, jnp.asarray(self.takeoff.time, dtype))[1]
        clip = dataclasses.replace(clip, poses=clip.poses.at[:, 1].add(drop))   # grounded
        self._setup(settings, model, clip, make_world(torque_limits=True, dtype=dtype))
        self.kind = settings.kind
        self.q0, self.qd0 = q0.astype(dtype), qd0.astype(dtype)
        self.vertical_velocity = takeoff_state.clip_vertical_velocity(self.q0, self.qd0)
        self._takeoff_foot = model.topology.link_index(self.takeoff.foot)
        # (a take-off frame time in float32 may fall a hair short of a whole step)
        self.runup_steps = int(np.floor(self.takeoff.time * settings.control_hz + 1e-4))
        if self.runup_steps < 1:
            raise ConfigError(f"control_hz: the clip takes off at {self.takeoff.time:.3f} s, "
                              f"less than one control step (1/{settings.control_hz:g} s) in")
        self.first_start = self.takeoff.time - self.runup_steps / settings.control_hz

    def default_params(self):
        """Task parameters: gravity and the take-off x of the jump it leads into."""
        return {"gravity": self.world.gravity,
                "takeoff": jnp.asarray(self.settings.x, self.q0.dtype)}

    def desired_state(self, x):
        """The take-off state of x, (q, qd): exactly the state `JumpEnv.reset` starts a jump
        episode from (the take-off pose, the clip's velocity with x's root velocities and the
        take-off foot planted) when the jump keeps the clip's vertical velocity
        (`full_motion.check_pair` refuses a jump that does not)."""
        qd = takeoff_state.takeoff_velocity(self.kind, self.model, self.q0, self.qd0, x,
                                            self._takeoff_foot, self.vertical_velocity)
        return self.q0, qd

    def phase(self, t):
        """The run-up's phase t / t₀ ∈ [0, 1]: 1 at the take-off."""
        return jnp.clip(t / self.takeoff.time, 0.0, 1.0)

    def reset(self, params, key):
        """An episode on the grid that ends at the take-off time: k steps before it, k uniform
        in 1 … K (`start = "random"`) or K (`"clip_start"`)."""
        start_key, key = jax.random.split(key)
        steps = (jax.random.randint(start_key, (), 1, self.runup_steps + 1)
                 if self.settings.start == "random" else self.runup_steps)
        return self.begin(params, steps, key)

    def begin(self, params, steps, key):
        """An episode that starts `steps` control steps before the take-off time, in the
        clip's pose and velocity there."""
        steps = jnp.asarray(steps, jnp.int32)
        dtype = self.clip.poses.dtype
        start = jnp.asarray(self.takeoff.time, dtype) - steps.astype(dtype) * self.control_dt
        state = self.start_at(start, key)
        q_goal, qd_goal = self.desired_state(params["takeoff"])
        target_omega, target_velocity = takeoff_state.facing_velocities(q_goal, qd_goal)
        task = {"start": start, "to_takeoff": steps, "target_omega": target_omega,
                "target_velocity": target_velocity}
        if self.settings.k_takeoff_joints:     # (only then: older runs' checkpoints still load)
            task["target_joint_velocity"] = joint_velocities(self.model, qd_goal)
        zero = jnp.zeros((), dtype)
        return state.replace(task=task, metrics={**state.metrics,
                                                 **self._takeoff_metrics(zero, zero)})

    def task_reward(self, physics, task):
        """r_G (eq. 3.13 or 3.14, and our terms) of a state against the targets of the
        episode's x."""
        omega, velocity = takeoff_state.facing_velocities(physics.q, physics.qd)
        joints = ({"joint_velocity": joint_velocities(self.model, physics.qd),
                   "target_joint_velocity": task["target_joint_velocity"]}
                  if "target_joint_velocity" in task else {})
        return takeoff_reward(self.kind, omega, velocity, task["target_omega"],
                              task["target_velocity"], **self.settings.takeoff_weights,
                              **joints)

    def step(self, params, state, action):
        """One imitation step (`ImitationEnv.imitate`); at the take-off time the task reward
        is added (unless the character fell) and the episode ends."""
        task = state.task
        physics, t, fell, reward, metrics = self.imitate(params, state, action, task["start"])
        at_takeoff = state.steps + 1 >= task["to_takeoff"]
        reached = at_takeoff & ~fell
        goal = self.task_reward(physics, task)
        reward = reward + jnp.where(reached, self.settings.w_takeoff * goal, 0.0)
        metrics = {**metrics, **self._takeoff_metrics(reached, goal)}
        return end_of_step(state, physics, self._observe(physics, t), reward,
                           fell | at_takeoff, task, metrics, self.episode_steps)

    def _takeoff_metrics(self, reached, goal):
        """Per step; averaged over ended episodes: the share that reached the take-off time
        without falling, and r_G there (0 for those that fell)."""
        dtype = self.clip.poses.dtype
        reached = jnp.asarray(reached, dtype)
        return {"episode/reached_takeoff": reached,
                "episode/takeoff_reward": reached * goal}


registry.register(registry.Task(
    "runup", RunupSettings, RunupEnv,
    # the character sets the networks' sizes, the phase the observation's, whether
    # k_takeoff_joints is 0 the episode state's (its joints' targets)
    fixed_on_resume=("character", "phase_in_observation", "k_takeoff_joints")))
