"""Joint limits as penalty torques, and per-joint torque limits.

Joint limits act per degree of freedom on the joint coordinates: a revolute joint's angle, and for
a spherical joint the three components of its rotation vector (the per-axis scheme; the model's
`q_lower`/`q_upper` hold one bound per component). Outside [lower, upper] a spring pushes back and
a damper resists motion further out:

    τ_limit = k (lower − c)₊ − k (c − upper)₊ − d q̇ · [moving further out of range].

Torque limits clip the joint torques of the SPD solve per DoF to ±`Model.torque_limit` (and,
where one binds, the step re-solves with ABA: docs/design.md, "Simulation step"; see
`jaxsim.simulation.step`).
"""

import jax.numpy as jnp

from jaxsim.dynamics import pose_error
from jaxsim.model import Model, rest_pose
from jaxsim.world import World


def joint_coordinates(model: Model, q):
    """Per-DoF joint coordinates (nv): revolute angles and spherical rotation vectors. A free
    root's entries are its pose relative to the world origin; `build_model` refuses limits
    there, so no limit spring acts on them."""
    return pose_error(model, q, rest_pose(model).astype(q.dtype))


def joint_limit_torques(model: Model, world: World, q, qd):
    """Penalty torques (nv) that push joints back inside their limits."""
    coordinate = joint_coordinates(model, q)
    over = coordinate - model.q_upper
    under = model.q_lower - coordinate
    spring = world.limit_stiffness * (jnp.maximum(under, 0.0) - jnp.maximum(over, 0.0))
    moving_out = ((over > 0) & (qd > 0)) | ((under > 0) & (qd < 0))
    return spring - jnp.where(moving_out, world.limit_damping * qd, 0.0)


def clip_torques(model: Model, tau):
    """Joint torques clipped to ±torque_limit, and whether any limit was reached."""
    clipped = jnp.clip(tau, -model.torque_limit, model.torque_limit)
    return clipped, jnp.any(clipped != tau)
