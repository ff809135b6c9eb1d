"""Imitating a motion clip, DeepMimic-style (Peng et al. 2018): the thesis's run-up controller.

The humanoid is simulated at `sim_hz` under SPD control; at `control_hz` the policy gives the PD
targets of the actuated joints in exponential coordinates (a rotation vector per spherical joint,
an angle per revolute joint), either as an offset from the clip's pose ("residual":
q̄ = q_ref ⊗ exp(a) per spherical joint, θ̄ = θ_ref + a per revolute joint) or outright
("absolute"). SPD's target velocity is zero by default (thesis eq. 2.6, as in DeepMimic's PD
controllers) or, with `spd_target_velocity = "reference"`, the clip's velocity (Tan et al.'s SPD
form). The latter makes a zero residual track far better open-loop: over 90 steps from 32 random
starts, the return of zero actions went from 9.8 to 17.4 and the steps before a fall from 32.6 to
37.8, which gives learning a better start.

Reward (Peng et al. 2018), against the clip at the time reached by the step:

    r = w_pose exp(−k_pose Σ_j θ_j²) + w_velocity exp(−k_velocity Σ_j ‖ω̂_j − ω_j‖²)
        + w_end_effector exp(−k_end_effector Σ_e ‖(p_e − p_root) − (p̂_e − p̂_root)‖²)
        + w_com exp(−k_com ‖v_com − v̂_com‖²)

with θ_j the angle of q̂_j⁻¹ q_j, over the root's orientation and every actuated joint (the
root is one of DeepMimic's joints, with weight 1 in humanoid3d.txt), ω_j the joints' velocities
(the root's body-frame angular velocity and every joint's rate), the end effectors the ankles and
wrists by default (`end_effectors`), and hats marking the reference. Episodes start at a random time of the clip, in the
clip's pose and velocity (reference state initialisation), and end early when a link other than
the feet touches the ground (early termination) or the simulation blows up. With a clip that
does not loop, an episode also ends when the clip is over (the reference time reaches its
duration): a truncation, not a termination, since the character did not fail; it is a time limit
like `episode_seconds`.

The observation is `agents.tasks.observations.body_observation` followed, if asked, by the clip's
phase φ ∈ [0, 1) as (sin 2πφ, cos 2πφ) (thesis §3.4.1; DeepMimic's policy sees the phase).
"""

from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import ConfigError, check_positive
from agents.pose.pose_features import PoseLayout, exp_to_pose
from agents.rl.env import TaskTiming, check_timing, end_of_step, start_of_episode
from agents.tasks import common, registry
from agents.tasks.observations import body_observation, observation_size
from jaxsim import characters, kinematics, motion, rotations, simulation
from jaxsim.dynamics import METHODS, pose_error
from jaxsim.world import make_world

ACTION_MODES = ("residual", "absolute")
TARGET_VELOCITIES = ("zero", "reference")
REWARD_TERMS = ("pose", "velocity", "end_effector", "com")


@dataclass(frozen=True)
class ImitationSettings(TaskTiming):
    """The `[imitation]` config section."""

    clip: str = "humanoid3d_walk.txt"        # under <data>/deepmimic/motions, or a path
    character: str = "humanoid3d.txt"        # under <data>/deepmimic/characters, or a path
    control_hz: float = 30.0
    sim_hz: float = 600.0                    # a whole multiple of control_hz
    method: str = "maba"                     # the SPD solver (jaxsim.dynamics.METHODS)
    episode_seconds: float = 10.0
    actions: str = "residual"                # "residual" or "absolute"
    action_scale: float = 1.0
    spd_target_velocity: str = "zero"        # "zero" (eq. 2.6) or "reference" (the clip's)
    w_pose: float = 0.65
    w_velocity: float = 0.1
    w_end_effector: float = 0.15
    w_com: float = 0.1
    k_pose: float = 2.0
    k_velocity: float = 0.1
    k_end_effector: float = 40.0
    k_com: float = 10.0
    feet: tuple[str, ...] = ("right_ankle", "left_ankle")   # links allowed to touch the ground
    end_effectors: tuple[str, ...] = ("right_ankle", "left_ankle", "right_wrist", "left_wrist")
    facing_invariant: bool = False
    phase_in_observation: bool = True

    def __post_init__(self):
        for name in ("clip", "character"):
            if not getattr(self, name):
                raise ValueError(f"{name} must name a file")
        check_timing(self)
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}; got {self.method!r}")
        if self.actions not in ACTION_MODES:
            raise ValueError(f"actions must be one of {', '.join(ACTION_MODES)}; got "
                             f"{self.actions!r}")
        if self.spd_target_velocity not in TARGET_VELOCITIES:
            raise ValueError(f"spd_target_velocity must be one of {', '.join(TARGET_VELOCITIES)}"
                             f"; got {self.spd_target_velocity!r}")
        check_positive(self, [f"{kind}_{term}" for term in REWARD_TERMS for kind in "wk"],
                       allow_zero=True)


def _joint_dof_table(model) -> np.ndarray:
    """(J, 3) indices into a (nv + 1) vector of the rotational DoFs of each "joint" of the
    reward: the root's orientation, then every actuated joint; padded with nv (a zero entry)."""
    topo = model.topology
    rows = [np.arange(3)] if topo.floating else []
    for i in range(1, topo.n_links):
        size = {"spherical": 3, "revolute": 1}.get(topo.joint_types[i], 0)
        if size:
            rows.append(np.concatenate([topo.dof_offsets[i] + np.arange(size),
                                        np.full(3 - size, topo.nv)]))
    return np.array(rows, int)


def _padded(x):
    return jnp.concatenate([x, jnp.zeros(1, x.dtype)])


class ImitationEnv:
    """A DeepMimic-style imitation task (see the module docstring) with the `agents.rl.env.Env`
    interface. `task` holds the clip time at which the episode started; the reference of control
    step k is the clip at start + k / control_hz.

    Settings that do not fit the data (a clip, character or controller file that is not there,
    an unknown foot) are a `ConfigError` naming the key of the `[imitation]` section."""

    def __init__(self, settings: ImitationSettings, data_dir, dtype=jnp.float32):
        deepmimic = Path(data_dir) / "deepmimic"
        character = common.data_file(settings.character, deepmimic / "characters", "character")
        controller = deepmimic / "controllers" / f"{character.stem}_ctrl.txt"
        if not controller.is_file():
            raise ConfigError(f"character: no controller file {controller} for {character}")
        model = characters.load_deepmimic(character, controller, dtype=dtype)
        clip = motion.load_motion(
            common.data_file(settings.clip, deepmimic / "motions", "clip"), model)
        self._setup(settings, model, clip, make_world(dtype=dtype))

    def _setup(self, settings: ImitationSettings, model, clip, world):
        """What every imitation of `clip` by `model` in `world` holds (a task built on this one,
        such as the run-up of `agents.tasks.runup`, loads its own character and clip)."""
        self.settings, self.model, self.clip, self.world = settings, model, clip, world
        topo = self.model.topology
        self._may_touch = np.isin(np.arange(topo.n_links),
                                  common.link_indices(self.model, settings.feet, "feet"))
        self._ground = self.world.object_index("ground")
        self._end_effectors = common.link_indices(self.model, settings.end_effectors,
                                                  "end_effectors")
        self._joint_dofs = _joint_dof_table(self.model)
        self._revolute_q = topo.q_offsets[topo.links_of_type("revolute")]
        self.observation_size = observation_size(self.model) + 2 * settings.phase_in_observation
        self.action_size = PoseLayout.of(self.model).exp_size
        self.episode_steps = settings.episode_steps
        self.control_dt = 1.0 / settings.control_hz
        self.sim_dt = 1.0 / settings.sim_hz

    def default_params(self):
        """Task parameters a sweep may vmap over: gravity (used by `step`)."""
        return {"gravity": self.world.gravity}

    def reference(self, t):
        """The clip's pose (nq) and velocity (nv) at time t (a looping clip repeats; an episode
        on one that does not loop ends at its duration)."""
        return motion.sample_pose(self.clip, t), motion.sample_velocity(self.clip, t)

    def phase(self, t):
        """The clip phase φ ∈ [0, 1] at time t: t / duration, wrapped when the clip loops."""
        fraction = t / self.clip.duration
        return fraction - jnp.floor(fraction) if self.clip.loop else jnp.clip(fraction, 0, 1)

    def pd_target(self, q_ref, action):
        """The SPD target pose (nq) of an action (`action_size`,), scaled by `action_scale`:
        q_ref ⊗ exp(a) and θ_ref + a (residual) or exp(a) and a (absolute); the root part is
        the reference's (the root is unactuated)."""
        action = self.settings.action_scale * action
        pose = exp_to_pose(self.model, action, root=q_ref[:7])
        if self.settings.actions == "absolute":
            return pose
        quats, _ = self.model.topology.spherical_indices
        target = q_ref.at[quats].set(rotations.quat_multiply(q_ref[quats], pose[quats]))
        return target.at[self._revolute_q].add(pose[self._revolute_q])

    def _observe(self, physics, t):
        obs = body_observation(self.model, physics.q, physics.qd,
                               self.settings.facing_invariant)
        if not self.settings.phase_in_observation:
            return obs
        angle = 2 * jnp.pi * self.phase(t)
        return jnp.concatenate([obs, jnp.stack([jnp.sin(angle), jnp.cos(angle)])])

    def errors(self, q, qd, q_ref, qd_ref):
        """The four DeepMimic errors (pose, velocity, end effector, centre-of-mass velocity)
        of (q, qd) against the reference, and the per-joint angle errors (radians)."""
        table = self._joint_dofs
        rotation_error = _padded(pose_error(self.model, q, q_ref))[table]   # (J, 3)
        velocity_error = _padded(qd - qd_ref)[table]
        both_q, both_qd = jnp.stack([q, q_ref]), jnp.stack([qd, qd_ref])   # one pass for both
        _, pos = jax.vmap(kinematics.forward_kinematics, (None, 0))(self.model, both_q)
        relative = pos[:, self._end_effectors] - pos[:, :1]                  # p_e − p_root
        com_velocity = jax.vmap(kinematics.center_of_mass_velocity, (None, 0, 0))(
            self.model, both_q, both_qd)
        effector, com = relative[0] - relative[1], com_velocity[0] - com_velocity[1]
        errors = {"pose": jnp.sum(rotation_error ** 2), "velocity": jnp.sum(velocity_error ** 2),
                  "end_effector": jnp.sum(effector ** 2), "com": jnp.sum(com ** 2)}
        return errors, jnp.linalg.norm(rotation_error, axis=-1)

    def reward_terms(self, q, qd, q_ref, qd_ref):
        """exp(−k_i err_i) for each term (each in [0, 1]), and the per-joint angle errors."""
        errors, angles = self.errors(q, qd, q_ref, qd_ref)
        s = self.settings
        return {term: jnp.exp(-getattr(s, f"k_{term}") * errors[term])
                for term in REWARD_TERMS}, angles

    def reward(self, terms):
        """The DeepMimic reward Σ_i w_i terms_i of the terms of `reward_terms`."""
        return sum(getattr(self.settings, f"w_{term}") * terms[term] for term in REWARD_TERMS)

    def _metrics(self, terms, angles, fell):
        metrics = {f"reward_{term}": terms[term] for term in REWARD_TERMS}
        metrics["pose_error_degrees"] = jnp.degrees(jnp.mean(angles))
        metrics["fell"] = fell.astype(angles.dtype)
        return metrics

    def reset(self, params, key):
        """Reference state initialisation (Peng et al. 2018): `start_at` a uniformly random time
        in [0, duration)."""
        start_key, key = jax.random.split(key)
        start = jax.random.uniform(start_key, (), self.clip.poses.dtype, 0.0, self.clip.duration)
        return self.start_at(start, key)

    def start_at(self, start, key):
        """An episode that starts in the clip's pose and velocity at time `start`; the metrics
        are those of a step, zero-valued."""
        start = jnp.asarray(start, self.clip.poses.dtype)
        q, qd = self.reference(start)
        physics = simulation.init_state(self.model, self.world, q, qd)
        zero = jnp.zeros((), q.dtype)
        metrics = self._metrics({term: zero for term in REWARD_TERMS},
                                jnp.zeros(len(self._joint_dofs), q.dtype), jnp.zeros((), bool))
        return start_of_episode(physics, self._observe(physics, start), key, start, metrics)

    def step(self, params, state, action):
        """One control step (`imitate`), truncated at the time limit or, for a clip that does
        not loop, once the reference time reaches the clip's duration."""
        physics, t, fell, reward, metrics = self.imitate(params, state, action, state.task)
        clip_over = False if self.clip.loop else t >= self.clip.duration
        return end_of_step(state, physics, self._observe(physics, t), reward, fell, state.task,
                           metrics, self.episode_steps, clip_over)

    def imitate(self, params, state, action, start):
        """One control step of an episode that started at clip time `start`: PD target from
        the action and the reference at the next control time t, `substeps` simulation steps,
        reward against that reference, and early termination (a non-foot link touched the
        ground, or a non-finite state, which is replaced by the state before the step and earns
        no reward). Returns (physics, t, fell, reward, metrics)."""
        world = common.world_of(self.world, params)
        dtype = self.clip.poses.dtype
        t = start + (state.steps + 1).astype(dtype) * self.control_dt
        q_ref, qd_ref = self.reference(t)
        target_velocity = qd_ref if self.settings.spd_target_velocity == "reference" else None
        stepped, touched = common.simulate_control_step(
            self.model, world, state.physics, self.pd_target(q_ref, action), self.sim_dt,
            self.settings.substeps, self.settings.method, target_velocity)
        physics, finite = common.keep_sound(stepped, state.physics)
        fell = jnp.any(touched[:, self._ground] & ~self._may_touch) | ~finite
        terms, angles = self.reward_terms(physics.q, physics.qd, q_ref, qd_ref)
        reward = jnp.where(finite, self.reward(terms), 0.0)
        return physics, t, fell, reward, self._metrics(terms, angles, fell)


registry.register(registry.Task(
    "imitation", ImitationSettings, ImitationEnv,
    # the character sets the networks' sizes, the phase the observation's
    fixed_on_resume=("character", "phase_in_observation")))
