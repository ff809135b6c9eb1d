"""Stable-PD control: the SPD force and the four solvers of thesis eq. 2.7.

SPD (thesis eq. 2.6) computes the PD torque from the next step's predicted state,
    τ = −K_p (q + Δt q̇ − q̄) − K_d (q̇ + Δt q̈ − q̄̇),
so the equations of motion M q̈ + C = τ become (eq. 2.7)
    (M + K_d Δt) q̈ = −C − K_p (q + Δt q̇ − q̄) − K_d (q̇ − q̄̇) = Q − C.
The target velocity q̄̇ is zero in the thesis's eq. 2.6 (a pose target only); tracking a moving
reference passes the reference's velocity (as in Tan et al.'s original SPD), which removes the
lag K_d q̄̇ / K_p that a pose-only target leaves. It changes Q only, so MABA is unaffected.
Solvers, selected by name:
    dense   CRBA for M, RNEA for C, Cholesky of M + K_d Δt           O(n³)
    sparse  the same matrix factorised by branch-induced sparse LTDL   O(n d²)
    maba    the Modified Articulated-Body Algorithm                    O(n)
    pd      explicit PD torques τ = −K_p (q − q̄) − K_d q̇, then ABA    O(n), not stable-PD
Each returns (q̈, τ) with τ the joint torques actually applied (eq. 2.17: τ = Q − K_d Δt q̈).
Passive dampers beside the motors (joint limits') act implicitly in every solver, −d (q̇ + Δt q̈):
d Δt joins K_d Δt on the diagonal, so they are stable at any d.
"""

import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxsim import rotations
from jaxsim.dynamics.aba import articulated_body_solve
from jaxsim.dynamics.crba import mass_matrix
from jaxsim.dynamics.ltdl import ltdl_factor, ltdl_solve
from jaxsim.dynamics.rnea import bias_torques
from jaxsim.model import Model, check_layout
from jaxsim.spatial import mat_vec, transpose

METHODS = ("dense", "sparse", "maba", "pd")


def pose_error(model: Model, q, target):
    """Per-DoF pose error q ⊖ q̄ (nv).

    Revolute: θ − θ̄. Spherical (and the root's orientation): the rotation vector of q̄⁻¹ ⊗ q, the
    rotation taking the target to the current orientation, in the child frame. Root position: the
    world offset p − p̄ expressed in the root frame, matching the root's body-frame velocity.
    """
    topo = model.topology
    err = jnp.zeros((topo.nv,), q.dtype)
    rev = topo.links_of_type("revolute")
    if len(rev):
        err = err.at[topo.dof_offsets[rev]].set(q[topo.q_offsets[rev]] - target[topo.q_offsets[rev]])

    qi, vi = topo.spherical_indices
    if len(qi):
        err = err.at[vi].set(rotations.relative_rotvec(target[qi], q[qi]))
    if topo.floating:
        rot = rotations.quat_to_matrix(rotations.quat_normalize(q[3:7]))
        err = err.at[0:3].set(rotations.relative_rotvec(target[3:7], q[3:7]))
        err = err.at[3:6].set(mat_vec(transpose(rot), q[0:3] - target[0:3]))
    return err


def _velocity_error(qd, target_velocity):
    return qd if target_velocity is None else qd - target_velocity


def spd_force(model: Model, q, qd, target, dt, target_velocity=None):
    """Q = −K_p (q ⊖ q̄ + Δt q̇) − K_d (q̇ − q̄̇) (thesis eq. 2.20, per DoF; q̄̇ = 0 by default)."""
    return (-model.kp * (pose_error(model, q, target) + dt * qd)
            - model.kd * _velocity_error(qd, target_velocity))


def solve_applied(model: Model, q, qd, tau, dt, f_ext=None, gravity=None, passive_damping=None):
    """Accelerations under the joint torques `tau` (nv) applied as given, plus passive dampers
    −d (q̇ + Δt q̈) with d = `passive_damping` (nv, N·m·s/rad; none by default), solved
    implicitly: (M + d Δt) q̈ = τ − d q̇ − C, by the ABA of MABA in O(n). Arrays of the wrong
    length raise ValueError."""
    for name, value, layout in (("q", q, "nq"), ("qd", qd, "nv"), ("tau", tau, "nv"),
                                ("passive_damping", passive_damping, "nv")):
        if value is not None:
            check_layout(model, name, value, layout)
    passive = jnp.zeros_like(qd) if passive_damping is None else passive_damping
    return articulated_body_solve(model, q, qd, tau - passive * qd, passive * dt, f_ext, gravity)


def solve_spd(model: Model, q, qd, target, dt, method="maba", f_ext=None, gravity=None,
              extra_torque=None, target_velocity=None, passive_damping=None):
    """Accelerations and motor torques of SPD control towards `target` (a pose, nq), eq. 2.7.

    `f_ext` (n_links, 6): spatial forces on the links in link coordinates; `gravity`: 3-vector;
    `extra_torque` (nv): joint torques applied as given (joint-limit springs);
    `passive_damping` (nv): coefficients d of dampers applied implicitly, −d (q̇ + Δt q̈)
    (joint-limit dampers); neither is part of the returned motor torques τ = Q − K_d Δt q̈
    (eq. 2.17); `target_velocity` (nv): q̄̇. Arrays of the wrong length raise ValueError.
    """
    for name, value, layout in (("q", q, "nq"), ("qd", qd, "nv"), ("target", target, "nq"),
                                ("extra_torque", extra_torque, "nv"),
                                ("target_velocity", target_velocity, "nv"),
                                ("passive_damping", passive_damping, "nv")):
        if value is not None:
            check_layout(model, name, value, layout)
    extra = jnp.zeros_like(qd) if extra_torque is None else extra_torque
    passive = jnp.zeros_like(qd) if passive_damping is None else passive_damping
    if method == "pd":
        tau = (-model.kp * pose_error(model, q, target)
               - model.kd * _velocity_error(qd, target_velocity))
        return solve_applied(model, q, qd, tau + extra, dt, f_ext, gravity, passive), tau
    force = spd_force(model, q, qd, target, dt, target_velocity)
    damping = model.kd * dt
    applied = force + extra - passive * qd
    if method == "maba":
        qdd = articulated_body_solve(model, q, qd, applied, damping + passive * dt, f_ext,
                                     gravity)
    elif method in ("dense", "sparse"):
        h = mass_matrix(model, q) + jnp.diag(damping + passive * dt)
        rhs = applied - bias_torques(model, q, qd, f_ext, gravity)
        if method == "dense":
            qdd = jsl.cho_solve(jsl.cho_factor(h, lower=True), rhs)
        else:
            qdd = ltdl_solve(model.topology, ltdl_factor(model.topology, h), rhs)
    else:
        raise ValueError(f"unknown SPD method {method!r}; choose one of {', '.join(METHODS)}")
    return qdd, force - damping * qdd
