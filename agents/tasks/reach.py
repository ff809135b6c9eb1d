"""Reaching with a two-link arm: a small task on our simulator that PPO learns in a minute.

A fixed-base arm of two capsule links (0.5 m each, revolute joints about Z, hanging in gravity in
the XY plane) must bring its tip to a goal drawn at random in the reachable ring at every reset.
Actions are the two joints' PD targets (radians, scaled by `action_scale`), tracked by SPD at
`sim_hz`; the reward per control step is exp(−(d / 0.2 m)²) with d the tip-to-goal distance.
Observation: sin and cos of the joint angles, joint velocities, the tip and the goal.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from agents.rl.env import TaskTiming, check_timing, end_of_step, start_of_episode
from agents.tasks import common, registry
from jaxsim import kinematics, simulation
from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.common import Y_TO_X
from jaxsim.world import make_world

LINK_LENGTH = 0.5
REWARD_LENGTH = 0.2


@dataclass(frozen=True)
class ReachSettings(TaskTiming):
    """The `[reach]` config section."""

    control_hz: float = 30.0
    sim_hz: float = 120.0
    episode_seconds: float = 1.0
    action_scale: float = 2.0

    def __post_init__(self):
        check_timing(self)


def arm(dtype=None):
    """The two-link arm: a fixed base, then upper and fore links along +X at rest."""
    half = LINK_LENGTH / 2 - 0.04
    link = dict(mass=1.0, joint="revolute", shape="capsule", shape_pos=(LINK_LENGTH / 2, 0, 0),
                shape_rot=Y_TO_X, shape_size=(0.04, half, 0), kp=200.0, kd=20.0)
    links = [LinkSpec(name="base", parent=None, joint="fixed", mass=1.0, shape="sphere",
                      shape_size=(0.05, 0, 0)),
             LinkSpec(name="upper", parent="base", **link),
             LinkSpec(name="fore", parent="upper", joint_pos=(LINK_LENGTH, 0, 0), **link)]
    kwargs = {} if dtype is None else {"dtype": dtype}
    return build_model(links, source="two-link arm", **kwargs)


class ReachEnv:
    observation_size = 10
    action_size = 2

    def __init__(self, settings: ReachSettings = ReachSettings(), dtype=jnp.float32):
        self.settings = settings
        self.model = arm(dtype)
        self.world = make_world(ground=False, dtype=dtype)
        self.substeps = settings.substeps
        self.episode_steps = settings.episode_steps
        self.control_dt = 1.0 / settings.control_hz

    def default_params(self):
        return {"gravity": self.world.gravity}

    def _tip(self, q):
        return kinematics.point_positions(self.model, q, np.array([2]),
                                          jnp.array([[LINK_LENGTH, 0.0, 0.0]], q.dtype))[0]

    def _observe(self, physics, goal):
        q = physics.q
        return jnp.concatenate([jnp.sin(q), jnp.cos(q), physics.qd, self._tip(q)[:2],
                                goal[:2]])

    def reset(self, params, key):
        """A random arm pose and goal; the state keeps a key split off for its own future use,
        apart from the keys these draws used."""
        key, angle_key, goal_key, radius_key = jax.random.split(key, 4)
        dtype = self.world.gravity.dtype
        q = jax.random.uniform(angle_key, (2,), dtype, -np.pi, np.pi)
        radius = jax.random.uniform(radius_key, (), dtype, 0.2, 2 * LINK_LENGTH - 0.05)
        heading = jax.random.uniform(goal_key, (), dtype, -np.pi, np.pi)
        goal = radius * jnp.array([jnp.cos(heading), jnp.sin(heading), 0.0], dtype)
        physics = simulation.init_state(self.model, self.world, q)
        return start_of_episode(physics, self._observe(physics, goal), key, goal,
                                {"distance": jnp.linalg.norm(self._tip(q) - goal)})

    def markers(self, task):
        """The world points to draw over an episode whose task state is `task` (see
        `jaxsim.render.animation`): the goal, (1, 3)."""
        return jnp.reshape(task, (1, 3))

    def step(self, params, state, action):
        target = self.settings.action_scale * action
        physics, _ = common.simulate_control_step(
            self.model, common.world_of(self.world, params), state.physics, target,
            1.0 / self.settings.sim_hz, self.substeps, "maba")
        goal = state.task
        distance = jnp.linalg.norm(self._tip(physics.q) - goal)
        reward = jnp.exp(-(distance / REWARD_LENGTH) ** 2)
        return end_of_step(state, physics, self._observe(physics, goal), reward, False, goal,
                           {"distance": distance}, self.episode_steps)


registry.register(registry.Task("reach", ReachSettings, lambda settings, _: ReachEnv(settings),
                                needs_data=False))
