"""SPD tracking of a motion clip with a "hand-of-God" root (thesis §2.4.1).

Every joint, the floating root included, is driven by SPD towards the clip's pose and velocity
one step ahead (SPD compares the predicted pose q + Δt q̇ with the target, eq. 2.6; the reference
velocity is passed as the target velocity, see `jaxsim.dynamics.spd`). The thesis's gains: root
k_p = 20000, k_d = 2000; internal joints k_p = 75000, k_d = 4000. The error measure is the
end-effector-to-root vector error: ‖(p_ee − p_root)_sim − (p_ee − p_root)_ref‖ for the right
ankle (humanoid) or the right front toe (dog).
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, motion
from jaxsim.model import Model, State
from jaxsim.simulation import init_state, simulate
from jaxsim.world import World

ROOT_GAINS = (20000.0, 2000.0)
JOINT_GAINS = (75000.0, 4000.0)


def tracking_model(model: Model, root_gains=ROOT_GAINS, joint_gains=JOINT_GAINS) -> Model:
    """The model with the tracking gains on every DoF, the root's six included (root gains of
    zero leave the root free, as for standing)."""
    root = np.arange(model.nv) < (6 if model.topology.floating else 0)
    dtype = model.mass.dtype
    kp = jnp.asarray(np.where(root, root_gains[0], joint_gains[0]), dtype)
    kd = jnp.asarray(np.where(root, root_gains[1], joint_gains[1]), dtype)
    return model.replace(kp=kp, kd=kd)


def initial_state(model: Model, world: World, clip: motion.Clip, t0=0.0) -> State:
    """The clip's pose and velocity at t0, ready to step in `world`."""
    t0 = jnp.asarray(t0, clip.poses.dtype)
    q, qd = motion.sample_pose(clip, t0), motion.sample_velocity(clip, t0)
    return init_state(model, world, q, qd)


def reference_targets(clip: motion.Clip, dt, n_steps: int):
    """The SPD targets of each step: the clip's pose and velocity one step ahead,
    (n_steps, nq) and (n_steps, nv)."""
    times = dt * jnp.arange(1, n_steps + 1, dtype=clip.poses.dtype)
    return (jax.vmap(lambda t: motion.sample_pose(clip, t))(times),
            jax.vmap(lambda t: motion.sample_velocity(clip, t))(times))


def track(model: Model, world: World, clip: motion.Clip, dt, n_steps: int,
          method: str = "maba", check_result: bool = True):
    """Simulate n_steps of tracking; returns the states after each step (leading time axis).

    `model` should carry tracking gains (`tracking_model`); `check_result` as in `simulate`
    (False for a stability study, which records divergence instead of raising)."""
    poses, velocities = reference_targets(clip, dt, n_steps)
    _, trajectory = simulate(model, world, initial_state(model, world, clip), poses, dt, method,
                             target_velocities=velocities, check_result=check_result)
    return trajectory


def end_effector_error(model: Model, clip: motion.Clip, trajectory_q, dt, effector: str):
    """Per-step end-effector-to-root vector error (metres) of a trajectory from `track`."""
    link = model.topology.link_index(effector)
    times = dt * jnp.arange(1, trajectory_q.shape[0] + 1, dtype=trajectory_q.dtype)
    reference = motion.link_positions(model, clip, times)
    simulated = jax.vmap(lambda q: kinematics.forward_kinematics(model, q)[1])(trajectory_q)

    def effector_vector(p):
        return p[:, link] - p[:, 0]

    return jnp.linalg.norm(effector_vector(simulated) - effector_vector(reference), axis=-1)
