"""Joint limits as penalty torques, and per-joint torque limits.

Joint limits act per degree of freedom on the joint coordinates: a revolute joint's angle, and for
a spherical joint the three components of its rotation vector (the per-axis scheme; the model's
`q_lower`/`q_upper` hold one bound per component). Outside [lower, upper] a spring pushes back and
a damper resists motion further out:

    τ_limit = k (lower − c)₊ − k (c − upper)₊ − d (q̇ + Δt q̈) · [moving further out of range].

The spring is explicit; the damper is implicit, solved with the step's accelerations like stable
PD's K_d (thesis eq. 2.7: d Δt joins the effective inertia). An explicit damper is stable only
while d Δt / I < 2, and a light link's I can be far smaller: with d = 50 N·m·s/rad at 600 Hz,
whenever a torque limit bound and the step was re-solved without K_d Δt, random high-jump
episodes ran away in about 1 % of cases, mostly at the neck.

Torque limits clip the joint torques of the SPD solve per DoF to ±`Model.torque_limit`; where
one binds, `jaxsim.simulation.step` re-solves with the clipped torques applied as given
(docs/design.md, "Simulation step").
"""

import jax.numpy as jnp

from jaxsim.dynamics import pose_error
from jaxsim.model import Model, rest_pose
from jaxsim.world import World


def joint_coordinates(model: Model, q):
    """Per-DoF joint coordinates (nv): revolute angles and spherical rotation vectors. A free
    root's entries are its pose relative to the world origin; `build_model` refuses limits
    there, so no limit spring acts on them.

    A spherical joint's rotation by θ about u is also one by θ − 2π about u; of the two
    vectors, θ u and (θ − 2π) u, the one nearer its limits is taken. The shortest-arc vector
    alone (θ ≤ π) flips to its antipode as θ passes π; where the limits allow angles near π on
    some axis (the athlete's shoulders: up to 3.14 rad), the flip put the other components
    far outside theirs in one step, and a spring torque of thousands of N·m blew up random
    obstacle episodes. The total violation of the nearer one is continuous through the flip;
    its spring torque can still change sign there where both lie equally far outside (a turn
    about an axis whose limits are symmetric, such as the shoulder's ±1.5 rad on y)."""
    coordinate = pose_error(model, q, rest_pose(model).astype(q.dtype))
    _, vi = model.topology.spherical_indices
    if not len(vi):
        return coordinate
    vector = coordinate[vi]                                          # (k, 3)
    squared = jnp.sum(vector * vector, axis=-1, keepdims=True)
    rotated = squared > 0
    angle = jnp.sqrt(jnp.where(rotated, squared, 1.0))      # no NaN gradient at rest
    other = vector * (1.0 - 2.0 * jnp.pi / angle)                    # (θ − 2π) u
    lower, upper = model.q_lower[vi], model.q_upper[vi]
    outside = lambda v: jnp.sum(jnp.maximum(lower - v, 0.0) + jnp.maximum(v - upper, 0.0), -1)
    nearer = rotated[:, 0] & (outside(other) < outside(vector))
    return coordinate.at[vi].set(jnp.where(nearer[:, None], other, vector))


def joint_limit_forces(model: Model, world: World, q, qd):
    """The joint limits' penalty per DoF: spring torques (nv), and damper coefficients (nv; d
    on DoFs moving further out of range, 0 elsewhere) for the solve to apply implicitly as
    −d (q̇ + Δt q̈) (`passive_damping` of `jaxsim.dynamics.solve_spd`)."""
    coordinate = joint_coordinates(model, q)
    over = coordinate - model.q_upper
    under = model.q_lower - coordinate
    spring = world.limit_stiffness * (jnp.maximum(under, 0.0) - jnp.maximum(over, 0.0))
    moving_out = ((over > 0) & (qd > 0)) | ((under > 0) & (qd < 0))
    return spring, jnp.where(moving_out, world.limit_damping, 0.0).astype(qd.dtype)

