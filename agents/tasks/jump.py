"""The jump tasks of thesis §3.6: the high jump and the obstacle jump, learned from a take-off state.

Episodes start at the take-off state (`agents.tasks.takeoff_state`) built from the task's x and
run under stable-PD control at 600 Hz; the policy acts at the control rate of the curriculum.

World (all in the facing frame at take-off, turned by α for the high jump; `jump_geometry`):
  high jump  the bar: during training a rigid wall from the ground to the bar height z, its
             plane `bar_distance` (1.2 m) from the take-off point along its normal n(α), or
             with `bar_time` where the take-off velocity carries the root in that time
             (`bar_plane_distance`); the landing block: 4 m deep and 6 m wide, its centre
             2.02 m past the bar plane (its near face 2 cm behind it), height
             clip(z − 0.7, 0.02, 0.75) m, friction 0.4.
  obstacle   a box 0.5 m high and z wide (along the approach), its near face 0.7 m ahead of
             the take-off point (`OBSTACLE_DISTANCE`); a landing block of the same kind 2 cm
             past its far face, its height the rule above for a 0.5 m bar (2 cm).
Rules, checked every control step from what happened in its substeps:
  failure    a link touched the bar/obstacle; a link other than the take-off foot touched the
             ground; 2 s passed since take-off without success; the simulation blew up.
  success    every link (its frame origin) is more than 0.2 m past the bar plane (obstacle:
             its far face), and the root, chest or neck (torso/head) or at least four links
             touch the block.
Both end the episode (terminated: no bootstrapping); an episode also ends at `episode_steps`
control steps (60), a truncation.

Actions. With `actions = "pvae"`: a = (latent, offset), the PD target decode(latent) + offset in
exponential coordinates (eq. 3.4, `composite_target`'s sum), with a trained P-VAE named by
`pvae`; with `actions = "pd"`: a is the joint targets in exponential coordinates themselves (the
ablation of Fig. 3.6). Either way every joint target is clamped to the joint's limits.

Reward (eqs. 3.2, 3.16), sparse, at success only:
    r = r_complete · r_ω · r_safety · r_naturalness (· r_novelty in Stage 2: `with_novelty`)
with r_complete = 1, r_ω = exp(−0.02 ω̄), ω̄ the mean root angular speed over the episode's
control steps, r_safety = `unsafe_landing` (0.7) for an unsafe landing, else 1 — unsafe is
head-first (the neck link among the first links to touch the block) or, with
`landing = "feet"`, any first touch of the block that is not by the feet alone — and
r_naturalness = 1 − clip((mean ‖offset‖₁ / c_offset)², 0, 1) over the episode (eq. 3.4, §3.4.2;
0 offsets with `actions = "pd"`, so 1).

Curriculum (§3.6.1, Table 3.1; `agents.rl.curriculum.RewardAccumulator`): z from z_min by Δz
when the accumulated iteration reward passes R_T; c_offset = 48 − 33 clip(p, 0, 1) and
f_control = 10 + 20 clip(p, 0, 1) with p = 2z − 1 (high jump, z in m) or p = z (obstacle).
c_offset is a traced task parameter; f_control, which sets the substeps of a control step, is
rounded to the nearest of `CONTROL_RATES` (divisors of 600 Hz) and is the curriculum's static
key, so a run compiles at most four iterations.

Strategy features (§3.6.1), computed in the substeps: at the first substep where the centre of
mass is past the bar plane (obstacle: its centre plane), the root's orientation relative to the
facing frame at take-off, as a rotation vector (3-D, Stage 2), and the angle between the root's
facing direction (its X axis) and the global up (1-D, Stage 1: near 0 facing up, as a flop
crosses back first; near π facing down, as a straddle). Also the centre of mass's height over
the bar at that instant (`clearance`, m) and its peak height.

Variations (§3.7.3): `weak_takeoff_leg` (its hip, knee and ankle torque limits × 0.6),
`stiff_spine` (the chest cannot extend backwards: its limit about the lateral axis at 0),
`cast_knee` (the take-off knee held at its take-off angle by a stiff stable-PD servo, which SPD
keeps stable), `gravity` (e.g. Mars, [0, −3.711, 0]) and `landing = "feet"`.
"""

import copy
import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.checkpoint import CheckpointError
from agents.config import ConfigError, check_positive
from agents.pose import pose_features, pvae
from agents.rl.curriculum import RewardAccumulator
from agents.rl.env import end_of_step, start_of_episode
from agents.tasks import common, registry, takeoff_state
from agents.tasks import physics as physics_lib
from agents.tasks.observations import body_observation, observation_size
from jaxsim import characters, kinematics, motion, rotations, simulation
from jaxsim.characters.athlete import joint_dofs, scaled_torque_limits
from jaxsim.world import Box, make_world

KINDS = ("highjump", "obstacle")
BAR_DISTANCE = 1.2          # m, take-off point to the bar plane (the release's)
# m, the least bar distance of `bar_time`: the take-off pose's link origins reach at most 0.39 m
# along n(α) (α ∈ [−0.6, 2.1]), so 0.6 m keeps the bar about 0.2 m clear of their shapes.
MIN_BAR_DISTANCE = 0.6
# m, take-off point to the obstacle's near face. Neither the thesis nor the issue gives it. The
# box-jump run at its take-off frame (1.5 s) has its take-off knee 0.27 m ahead at 0.34 m height;
# its own flight lifts its lowest point above 0.5 m 0.24 s later, its rearmost link then 0.1 m
# ahead, and lands on its box with every link 0.65 m ahead. At 0.7 m a 0.5 m box stands where
# that flight passes over it, 0.35 m clear of the knee at take-off (at 0.5 m the knee, falling
# forward with the body, hits it within 0.2 s). At 1.2 m (the bar's distance) the run's 2 m/s
# would need about 0.75 s in the air to take every link 0.2 m past even a 5 cm box.
OBSTACLE_DISTANCE = 0.7
BAR_THICKNESS = 0.05        # m, the wall's
BAR_LENGTH = 4.0            # m
BLOCK_OFFSET = 2.02         # m, bar plane to the block's centre
BLOCK_DEPTH, BLOCK_WIDTH = 4.0, 6.0
BLOCK_FRICTION = 0.4
OBSTACLE_HEIGHT = 0.5
CLEAR_MARGIN = 0.2          # m past the bar plane for success
TIME_AFTER_TAKEOFF = 2.0    # s
CONTROL_RATES = (10.0, 15.0, 20.0, 30.0)
LANDINGS = ("not_head_first", "feet")
ACTIONS = ("pvae", "pd")
FAILURES = ("hit_bar", "on_ground", "blew_up", "timeout")
CAST_GAIN = 1e6             # N·m/rad of the cast knee's servo (kd = CAST_GAIN / 100)


@dataclass(frozen=True)
class JumpSettings:
    """The `[highjump]` / `[obstacle]` config section."""

    clip: str = ""                           # the reference run-up; under <data>/jump/motions
    character: str = "humanoid3d_jumper60kg.txt"   # under <data>/jump/characters, or a path
    controller: str = "humanoid3d_ctrl.txt"  # under <data>/deepmimic/controllers, or a path
    takeoff: tuple[float, ...] = ()          # x; empty: the task's default row
    vertical_velocity: float | None = None   # the root's upward take-off speed, m/s; beside x,
    #                                          for sweeps and sensitivity studies (None: the clip's)
    actions: str = "pvae"                    # "pvae" (latent + offsets) or "pd"
    pvae: str = "runs/pvae"                  # a `takeoff pvae train` run directory
    sim_hz: float = 600.0
    control_hz: float = 10.0                 # without the schedule (control_schedule = false)
    control_schedule: bool = True            # f_control from z (§3.6.1)
    episode_steps: int = 60
    method: str = "maba"
    z_min: float = 0.5                       # m (obstacle: width)
    z_step: float = 0.01
    z_max: float = 2.0
    reward_threshold: float = 30.0           # R_T
    z_freeze: float = 1.0                    # where a strategy-discovery training may stop
    unsafe_landing: float = 0.7              # r_safety of an unsafe landing
    landing: str = "not_head_first"          # or "feet"
    feet: tuple[str, ...] = ("right_ankle", "left_ankle")
    torso: tuple[str, ...] = ("root", "chest", "neck")   # any of them on the block: landed
    head: str = "neck"
    spine: str = "chest"
    gravity: tuple[float, ...] = (0.0, -9.8, 0.0)
    weak_takeoff_leg: bool = False
    stiff_spine: bool = False
    cast_knee: bool = False

    KIND = ""

    def __post_init__(self):
        check_positive(self, ("sim_hz", "control_hz", "z_min", "z_step", "z_max",
                              "reward_threshold", "z_freeze"))
        if not 0.0 <= self.unsafe_landing <= 1.0:
            raise ValueError(f"unsafe_landing must be in [0, 1]; got {self.unsafe_landing}")
        for name, allowed in (("actions", ACTIONS), ("landing", LANDINGS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}; got "
                                 f"{getattr(self, name)!r}")
        if not 1 <= self.episode_steps <= 600:
            raise ValueError(f"episode_steps must be in [1, 600]; got {self.episode_steps}")
        if self.z_min > self.z_max:
            raise ValueError(f"z_min ({self.z_min}) must not exceed z_max ({self.z_max})")
        if len(self.gravity) != 3 or not all(np.isfinite(self.gravity)):
            raise ValueError(f"gravity must be 3 finite numbers; got {list(self.gravity)}")
        for rate in (self.control_hz, *CONTROL_RATES):
            if abs(self.sim_hz / rate - round(self.sim_hz / rate)) > 1e-9:
                raise ValueError(f"sim_hz must be a whole multiple of {rate:g} Hz; got "
                                 f"{self.sim_hz}")
        if self.takeoff:
            takeoff_state.check_x(self.KIND, self.takeoff, "takeoff")

    @property
    def x(self) -> tuple[float, ...]:
        return self.takeoff or DEFAULT_TAKEOFF[self.KIND]


@dataclass(frozen=True)
class HighJumpSettings(JumpSettings):
    clip: str = "VC5_sprint__curves_03.txt"
    bar_distance: float = BAR_DISTANCE       # m, take-off point to the bar plane along n(α)
    bar_time: float = 0.0                    # s; > 0: the bar plane where the take-off velocity
    #                                          carries the root in this time (`bar_plane_distance`)
    KIND = "highjump"

    def __post_init__(self):
        super().__post_init__()
        if self.bar_distance < MIN_BAR_DISTANCE:
            raise ValueError(f"bar_distance must be at least {MIN_BAR_DISTANCE} m (the take-off "
                             f"pose reaches 0.39 m towards the bar); got {self.bar_distance}")
        if not 0.0 <= self.bar_time < TIME_AFTER_TAKEOFF:
            raise ValueError(f"bar_time must be in [0, {TIME_AFTER_TAKEOFF:g}) s, the episode's "
                             f"time after take-off (0: bar_distance); got {self.bar_time}")


@dataclass(frozen=True)
class ObstacleSettings(JumpSettings):
    clip: str = "VC5_Run_jumpToBox_01.txt"
    z_min: float = 0.05
    z_step: float = 0.05
    z_max: float = 2.5
    reward_threshold: float = 50.0
    KIND = "obstacle"


DEFAULT_TAKEOFF = {"highjump": takeoff_state.HIGHJUMP_ROWS["fosbury_flop"],
                   "obstacle": takeoff_state.OBSTACLE_ROWS["straddle"]}


def schedule_p(kind, z):
    """p of the schedules: 2z − 1 for the high jump, z for the obstacle jump (z in m)."""
    return 2.0 * z - 1.0 if kind == "highjump" else z


def offset_coefficient(kind, z):
    """c_offset = 48 − 33 clip(p, 0, 1)."""
    return 48.0 - 33.0 * jnp.clip(schedule_p(kind, z), 0.0, 1.0)


def control_rate(kind, z) -> float:
    """f_control = 10 + 20 clip(p, 0, 1), rounded to the nearest of `CONTROL_RATES`."""
    f = 10.0 + 20.0 * float(np.clip(schedule_p(kind, z), 0.0, 1.0))
    return min(CONTROL_RATES, key=lambda rate: abs(rate - f))


class JumpCurriculum:
    """The bar height / obstacle width as a `RewardAccumulator`, the offset coefficient it sets
    (traced) and the control rate (static key)."""

    def __init__(self, settings: JumpSettings):
        self.kind, self.settings = settings.KIND, settings
        self.accumulator = RewardAccumulator(settings.z_min, settings.z_step,
                                             settings.reward_threshold, settings.z_max)

    def init(self):
        return self.accumulator.init()

    def update(self, state, iteration_reward):
        return self.accumulator.update(state, iteration_reward)

    def params(self, env_params, state):
        z = state["difficulty"].astype(env_params["gravity"].dtype)
        return {**env_params, "difficulty": z, "c_offset": offset_coefficient(self.kind, z)}

    def static_key(self, state):
        if not self.settings.control_schedule:
            return None
        return control_rate(self.kind, state["difficulty"])

    def metrics(self, state):
        return {**self.accumulator.metrics(state),
                "c_offset": offset_coefficient(self.kind, state["difficulty"])}


def bar_normal(alpha):
    """n(α) = (sin α, 0, −cos α), the bar plane's normal in the facing frame at take-off."""
    return jnp.stack([jnp.sin(alpha), jnp.zeros_like(alpha), -jnp.cos(alpha)])


def bar_plane_distance(speed, bar_distance, bar_time):
    """The bar plane's distance from the take-off point along n(α): `bar_distance` when
    `bar_time` is 0; else where the root's take-off speed towards the bar plane,
    `speed` = v · n(α) (`JumpEnv.bar_speed`), carries it in `bar_time`, and at least
    `MIN_BAR_DISTANCE`.

    The thesis turns "the high jump suite" by α (§3.6.1) but gives no distance. At a fixed 1.2 m,
    v · n(α) sorted our trainings' outcomes into bands (docs/discovery/README.md, "Where the bar
    stands"): α and v_z change the time to the bar."""
    if bar_time == 0.0:
        return jnp.asarray(bar_distance, jnp.result_type(speed))
    return jnp.maximum(speed * bar_time, MIN_BAR_DISTANCE)


def jump_geometry(kind, origin, heading, alpha, z, dtype, distance=BAR_DISTANCE):
    """(normal n (3,), the bar plane's distance d from the origin along n, the far plane's
    (obstacle: its far face; high jump: = d = `distance`), the crossing plane's, box centres
    (2, 3), rotations (2, 3, 3), half sizes (2, 3)) of the bar/obstacle and the block, in the
    world; `heading` turns facing-frame vectors to the world."""
    up = jnp.array([0.0, 1.0, 0.0], dtype)
    if kind == "highjump":
        normal = heading @ bar_normal(alpha)
        near = far = cross = jnp.asarray(distance, dtype)
        thickness, height = jnp.asarray(BAR_THICKNESS, dtype), z
        bar_height = z
    else:
        normal = heading @ jnp.array([1.0, 0.0, 0.0], dtype)
        near = jnp.asarray(OBSTACLE_DISTANCE, dtype)
        far, cross = near + z, near + z / 2
        thickness, height = z, jnp.asarray(OBSTACLE_HEIGHT, dtype)
        bar_height = height
    side = jnp.cross(normal, up)
    rotation = jnp.stack([normal, up, side], axis=1)             # box axes (n, up, side)
    block_height = jnp.clip(bar_height - 0.7, 0.02, 0.75)
    ground = origin * jnp.array([1.0, 0.0, 1.0], dtype)
    bar_centre = ground + ((near + far) / 2) * normal + height / 2 * up
    block_centre = ground + (far + BLOCK_OFFSET) * normal + block_height / 2 * up
    bar_half = jnp.stack([thickness / 2, height / 2, jnp.asarray(BAR_LENGTH / 2, dtype)])
    block_half = jnp.stack([jnp.asarray(BLOCK_DEPTH / 2, dtype), block_height / 2,
                            jnp.asarray(BLOCK_WIDTH / 2, dtype)])
    return (normal, ground, far, cross, bar_height, jnp.stack([bar_centre, block_centre]),
            jnp.stack([rotation, rotation]), jnp.stack([bar_half, block_half]))


def _exp_dofs(model) -> np.ndarray:
    """The velocity index of each entry of the joint targets in exponential coordinates."""
    layout = pose_features.PoseLayout.of(model)
    sph, rev = layout.exp_index
    dofs = np.zeros(layout.exp_size, int)
    offsets = model.topology.dof_offsets
    for block, link in zip(sph, layout.spherical):
        dofs[block] = offsets[link] + np.arange(3)
    for index, link in zip(rev, layout.revolute):
        dofs[index] = offsets[link]
    return dofs


class JumpEnv:
    """A jump task (see the module docstring) with the `agents.rl.env.Env` interface; `kind` is
    "highjump" or "obstacle". Settings that do not fit the data are a ConfigError naming the
    key of the section."""

    def __init__(self, settings: JumpSettings, data_dir, dtype=jnp.float32):
        self.settings, self.kind = settings, settings.KIND
        data = Path(data_dir)
        model = characters.athlete(
            common.data_file(settings.character, data / "jump" / "characters", "character"),
            common.data_file(settings.controller, data / "deepmimic" / "controllers",
                             "controller"), dtype=dtype)
        common.link_indices(model, (*settings.feet, *settings.torso, settings.head,
                                    settings.spine), "feet, torso, head or spine")
        self.clip_path = common.data_file(settings.clip, data / "jump" / "motions", "clip")
        clip = motion.load_motion(self.clip_path, model)
        self.takeoff, q0, qd0 = takeoff_state.takeoff_start(model, clip, settings.feet,
                                                            settings.clip)
        self.q0, self.qd0 = q0.astype(dtype), qd0.astype(dtype)
        self.model = self._varied(model)
        self.heading = takeoff_state.heading_rotation(rotations.quat_to_matrix(self.q0[3:7]))
        self._forward_speed = takeoff_state.facing_velocities(self.q0, self.qd0)[1][0]   # v_x
        obstacle = "bar" if self.kind == "highjump" else "obstacle"
        dummy = Box(obstacle, (0.0, -5.0, 0.0), (0.1, 0.1, 0.1))
        self.world = make_world(
            boxes=[dummy, dataclasses.replace(dummy, name="block")], torque_limits=True,
            friction=(0.9, 0.9, BLOCK_FRICTION), dtype=dtype)
        self._bar, self._block = self.world.object_index(obstacle), self.world.object_index("block")
        topo = self.model.topology
        self._takeoff_foot = topo.link_index(self.takeoff.foot)
        self._torso = common.link_indices(self.model, settings.torso, "torso")
        self._feet = common.link_indices(self.model, settings.feet, "feet")
        self._head = topo.link_index(settings.head)
        self._exp_dofs = _exp_dofs(self.model)
        self.decoder = self._decoder() if settings.actions == "pvae" else None
        self.latent_size = 0 if self.decoder is None else self.decoder.network.latent_size
        self.offset_size = len(self._exp_dofs)
        self.action_size = self.latent_size + self.offset_size
        self.observation_size = observation_size(self.model)
        self.episode_steps = settings.episode_steps
        self.curriculum = JumpCurriculum(settings)
        self.control_hz = settings.control_hz
        self.novelty = None                                  # Stage 2: `with_novelty`

    def with_novelty(self, novelty):
        """This environment with the reward × `novelty(features)` (Stage 2's r_novelty, eq. 3.2):
        `features` are the episode's strategy features at its success — `cross_rotvec` (3,)
        and `up_angle` — and `novelty` a traced function of them with values in [0, 1]."""
        twin = copy.copy(self)
        twin.novelty = novelty
        return twin

    def variant(self, control_hz):
        """This environment with another control rate (the curriculum's static key)."""
        twin = copy.copy(self)
        twin.control_hz = float(control_hz)
        return twin

    @property
    def control_dt(self):
        return 1.0 / self.control_hz

    @property
    def substeps(self) -> int:
        return int(round(self.settings.sim_hz / self.control_hz))

    def _varied(self, model):
        """The athlete with the variations of the settings applied."""
        s, topo = self.settings, model.topology
        side = self.takeoff.foot.rpartition("_")[0]                       # "right" / "left"
        if s.weak_takeoff_leg:
            model = scaled_torque_limits(model, {f"{side}_{j}": None
                                                 for j in ("hip", "knee", "ankle")}, 0.6)
        if s.stiff_spine:
            lateral = joint_dofs(model, s.spine)[2]          # + about Z leans the chest back
            model = model.replace(q_upper=jnp.asarray(model.q_upper).at[lateral].set(0.0))
        if s.cast_knee:
            knee = joint_dofs(model, f"{side}_knee")
            model = model.replace(
                kp=jnp.asarray(model.kp).at[knee].set(CAST_GAIN),
                kd=jnp.asarray(model.kd).at[knee].set(CAST_GAIN / 100),
                torque_limit=jnp.asarray(model.torque_limit).at[knee].set(jnp.inf))
        self._cast_knee_q = (topo.q_offsets[topo.link_index(f"{side}_knee")]
                             if s.cast_knee else None)
        return model

    def _decoder(self):
        try:
            return pvae.load_decoder(self.settings.pvae, self.model)
        except CheckpointError as error:
            raise ConfigError(f"pvae: {error}") from None

    def default_params(self):
        """Task parameters (per environment under the trainer): gravity, the take-off x and
        vertical velocity, the difficulty z and the offset coefficient of the curriculum's start."""
        dtype = self.q0.dtype
        z = jnp.asarray(self.settings.z_min, dtype)
        vertical = self.settings.vertical_velocity
        if vertical is None:
            vertical = takeoff_state.clip_vertical_velocity(self.q0, self.qd0)
        return {"gravity": jnp.asarray(self.settings.gravity, dtype),
                "takeoff": jnp.asarray(self.settings.x, dtype),
                "vertical_velocity": jnp.asarray(vertical, dtype), "difficulty": z,
                "c_offset": offset_coefficient(self.kind, z).astype(dtype)}

    def geometry(self, task):
        if self.kind == "obstacle":
            return jump_geometry(self.kind, self.q0[:3], self.heading, 0.0, task["difficulty"],
                                 self.q0.dtype)
        x = task["takeoff"]
        distance = bar_plane_distance(self.bar_speed(x), self.settings.bar_distance,
                                      self.settings.bar_time)
        return jump_geometry(self.kind, self.q0[:3], self.heading, x[0], task["difficulty"],
                             self.q0.dtype, distance)

    def bar_speed(self, x):
        """v · n(α): the root's take-off speed towards the bar plane (high jump), from the
        clip's forward speed v_x and x = (α, ω_x, ω_z, v_z) (or a batch of them, (..., 4))."""
        x = jnp.asarray(x, self.q0.dtype)
        alpha, v_z = x[..., 0], x[..., 3]
        return self._forward_speed * jnp.sin(alpha) - v_z * jnp.cos(alpha)

    def world_for(self, task, geometry=None):
        """The world of an episode (its bar or obstacle and block), e.g. to draw it; from its
        `geometry` when the caller has it."""
        *_, centres, rotations_, halves = self.geometry(task) if geometry is None else geometry
        return self.world.replace(box_center=centres, box_rotation=rotations_,
                                  box_half_size=halves)

    def pd_target(self, action):
        """The PD target pose of an action, every joint target clamped to its limits; and the
        offset part of the action (zeros with plain PD actions)."""
        if self.decoder is None:
            joints, offset = action, jnp.zeros_like(action)
        else:
            latent, offset = action[:self.latent_size], action[self.latent_size:]
            joints = pose_features.target_to_exp(self.model, self.decoder.target(latent)) + offset
        low, high = self.model.q_lower[self._exp_dofs], self.model.q_upper[self._exp_dofs]
        target = pose_features.exp_to_pose(self.model, jnp.clip(joints, low, high), self.q0[:7])
        if self._cast_knee_q is not None:
            target = target.at[self._cast_knee_q].set(self.q0[self._cast_knee_q])
        return target, offset

    def reset(self, params, key):
        """The take-off state of x = params["takeoff"], at the episode's difficulty."""
        model, _ = self.physical(params, self.world)
        q0 = (self.q0 if model is self.model else
              takeoff_state.grounded(model, self.q0, self.takeoff.foot))
        qd = takeoff_state.takeoff_velocity(self.kind, model, q0, self.qd0,
                                            params["takeoff"], self._takeoff_foot,
                                            params["vertical_velocity"])
        physics = simulation.init_state(model, self.world, q0, qd)
        dtype = self.q0.dtype
        zero = jnp.zeros((), dtype)
        com = kinematics.center_of_mass(model, q0)
        task = {"takeoff": params["takeoff"], "difficulty": params["difficulty"],
                "c_offset": params["c_offset"], "omega_sum": zero, "offset_sum": zero,
                "crossed": jnp.zeros((), bool), "cross_rotvec": jnp.zeros(3, dtype),
                "up_angle": zero, "clearance": zero, "peak_com": com[1],
                "landed": jnp.zeros((), bool), "unsafe": jnp.zeros((), bool)}
        return start_of_episode(physics, body_observation(model, physics.q, physics.qd),
                                key, task, self._metrics(
                                    task, *(jnp.zeros((), bool),) * 2, zero,
                                    dict.fromkeys(FAILURES, jnp.zeros((), bool))))

    def physical(self, params, world):
        """(model, world) of an episode: the task's, with the `[physics]` factors of
        `params["physics"]` applied when the config has that section (`agents.tasks.physics`)."""
        if "physics" not in params:
            return self.model, world
        return physics_lib.varied(self.model, world, params["physics"])

    def _crossing(self, task, geometry=None, model=None):
        """The per-substep observer: the root's orientation at the first substep where the
        centre of mass is past the crossing plane (bar plane; obstacle centre plane), and the
        peak centre-of-mass height."""
        normal, origin, _, cross, bar_top, *_ = (self.geometry(task) if geometry is None
                                                 else geometry)
        model = self.model if model is None else model

        def observe(state, seen):
            com = kinematics.center_of_mass(model, state.q)
            now = ~seen["crossed"] & (jnp.dot(com - origin, normal) - cross >= 0)
            rot = rotations.quat_to_matrix(state.q[3:7])
            relative = rotations.matrix_to_rotvec(self.heading.T @ rot)
            up_angle = jnp.arccos(jnp.clip(rot[1, 0], -1.0, 1.0))      # root X axis vs +Y
            pick = lambda new, old: jnp.where(now, new, old)
            return {**seen, "crossed": seen["crossed"] | now,
                    "cross_rotvec": pick(relative, seen["cross_rotvec"]),
                    "up_angle": pick(up_angle, seen["up_angle"]),
                    "clearance": pick(com[1] - bar_top, seen["clearance"]),
                    "peak_com": jnp.maximum(seen["peak_com"], com[1])}
        return observe

    def step(self, params, state, action):
        """One control step: the PD target, `substeps` of simulation with the crossing
        observed, then the rules and, at success, the reward."""
        task = state.task
        geometry = self.geometry(task)                 # fixed for the episode at its reset
        model, world = self.physical(
            params, common.world_of(self.world_for(task, geometry), params))
        target, offset = self.pd_target(action)
        stepped, touched, task = common.simulate_control_step(
            model, world, state.physics, target, 1.0 / self.settings.sim_hz,
            self.substeps, self.settings.method, observe=self._crossing(task, geometry, model),
            observed=task)
        physics, finite = common.keep_sound(stepped, state.physics)
        task = jax.tree_util.tree_map(lambda new, old: jnp.where(finite, new, old), task,
                                      state.task)          # what a blown-up substep saw is dropped
        omega = jnp.linalg.norm(physics.qd[:3])
        task = {**task, "omega_sum": task["omega_sum"] + omega,
                "offset_sum": task["offset_sum"] + jnp.sum(jnp.abs(offset))}
        on_block = touched[:, self._block]
        first_touch = on_block.any() & ~task["landed"]
        unsafe_now = (on_block[self._head] if self.settings.landing == "not_head_first" else
                      jnp.any(on_block & ~np.isin(np.arange(len(on_block)), self._feet)))
        task = {**task, "landed": task["landed"] | on_block.any(),
                "unsafe": task["unsafe"] | (first_touch & unsafe_now)}
        _, pos = kinematics.forward_kinematics(model, physics.q)
        normal, origin, far, *_ = geometry
        past = jnp.all((pos - origin) @ normal > far + CLEAR_MARGIN)
        landed = jnp.any(on_block[self._torso]) | (jnp.sum(on_block) >= 4)
        success = past & landed & finite
        others = np.arange(len(on_block)) != self._takeoff_foot
        elapsed = (state.steps + 1) * self.control_dt
        causes = {"hit_bar": touched[:, self._bar].any(),
                  "on_ground": jnp.any(touched[:, 0] & others),
                  "blew_up": ~finite, "timeout": elapsed >= TIME_AFTER_TAKEOFF - 1e-6}
        causes = {name: causes[name] & ~success for name in FAILURES}
        failed = functools.reduce(jnp.logical_or, causes.values())
        reward, terms = self.reward(task, state.steps + 1)
        reward = jnp.where(success, reward, 0.0)
        obs = body_observation(model, physics.q, physics.qd)
        return end_of_step(state, physics, obs, reward, success | failed, task,
                           self._metrics(task, success, failed, reward, causes),
                           self.episode_steps)

    def reward(self, task, steps):
        """r_ω · r_safety · r_naturalness (· r_novelty with `with_novelty`) of an episode of
        `steps` control steps (r_complete = 1; the caller pays it at success only), and the
        terms."""
        steps = jnp.maximum(steps, 1).astype(task["omega_sum"].dtype)
        terms = {"omega": jnp.exp(-0.02 * task["omega_sum"] / steps),
                 "safety": jnp.where(task["unsafe"], self.settings.unsafe_landing, 1.0),
                 "naturalness": pvae.naturalness_of_norm(task["offset_sum"] / steps,
                                                         task["c_offset"])}
        if self.novelty is not None:
            terms["novelty"] = self.novelty({"cross_rotvec": task["cross_rotvec"],
                                             "up_angle": task["up_angle"]})
        return functools.reduce(jnp.multiply, terms.values()), terms

    def _metrics(self, task, success, failed, reward, causes):
        """Per step; the `episode/` ones mean something where an episode ended (the trainer
        averages them over ended episodes only): success, failure and each failure's cause
        (`causes`: hit_bar, on_ground — a link other than the take-off foot —, blew_up,
        timeout; more than one may hold), and the strategy features."""
        dtype = task["clearance"].dtype
        f = lambda v: jnp.asarray(v, dtype)
        return {"episode/success": f(success), "episode/failure": f(failed),
                **{f"episode/{name}": f(cause) for name, cause in causes.items()},
                "episode/crossed": f(task["crossed"]), "episode/up_angle": task["up_angle"],
                **{f"episode/cross_rotvec_{axis}": task["cross_rotvec"][k]
                   for k, axis in enumerate("xyz")},
                "episode/clearance": task["clearance"], "episode/peak_com": task["peak_com"],
                "episode/difficulty": f(task["difficulty"]), "episode/reward": f(reward)}


def _make(settings, data_dir):
    return JumpEnv(settings, data_dir)


VMAPPABLE = ("gravity", "takeoff", "vertical_velocity")   # settings that are task parameters
for _kind, _settings in (("highjump", HighJumpSettings), ("obstacle", ObstacleSettings)):
    registry.register(registry.Task(_kind, _settings, _make,
                                    fixed_on_resume=("character", "actions", "pvae"),
                                    takes_physics=True, vmappable=VMAPPABLE))
