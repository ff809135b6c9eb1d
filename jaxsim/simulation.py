"""The simulation step and multi-step simulation (docs/design.md, "Simulation step").

One step: collisions → contact forces → joint-limit torques → SPD solve (thesis eq. 2.7, by the
chosen method) → torque limits (clip, and re-solve with ABA where they bind) → semi-implicit Euler
(q̇ ← q̇ + Δt q̈, then q advanced with the new velocity, quaternions on the manifold).

All functions act on one character; batch with `jax.vmap`, or faster with `simulate_batch`
(which computes with the batch innermost, `jaxsim.batch_last`).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import contact, kinematics, limits, xla_options
from jaxsim.batch_last import vmap as batch_last_vmap
from jaxsim.dynamics import aba, solve_spd
from jaxsim.model import Model, State, check_layout
from jaxsim.world import World


class SimulationError(ValueError):
    """A state cannot be simulated (non-finite numbers); the message names the joints."""


def init_state(model: Model, world: World, q, qd=None) -> State:
    """A state ready to step in `world`: friction springs unstretched, no touches recorded yet.
    `qd` defaults to rest."""
    check_layout(model, "q", q, "nq")
    if qd is not None:
        check_layout(model, "qd", qd, "nv")
    q = jnp.asarray(q, model.mass.dtype)
    qd = jnp.zeros(model.nv, q.dtype) if qd is None else jnp.asarray(qd, q.dtype)
    n_contacts = len(contact.contact_layout(model, world))
    return State(q, qd, jnp.zeros((n_contacts, 3), q.dtype),
                 jnp.zeros((model.n_links, len(world.object_names)), bool))


def is_finite(state: State):
    """True when q and q̇ hold only finite numbers (jittable: a flag to check after a rollout)."""
    return jnp.all(jnp.isfinite(state.q)) & jnp.all(jnp.isfinite(state.qd))


def _owners(offsets, index):
    return np.searchsorted(offsets, index, side="right") - 1


def check_state(model: Model, state: State, where: str = "state"):
    """Raise `SimulationError` naming the joints whose q or q̇ entries are not finite."""
    topo = model.topology
    problems = []
    for field, values, offsets in (("q", state.q, topo.q_offsets),
                                   ("qd", state.qd, topo.dof_offsets)):
        values = np.asarray(values)
        bad = np.flatnonzero(~np.isfinite(values.reshape(-1, values.shape[-1])).all(0))
        if len(bad):
            joints = sorted({topo.names[i] for i in _owners(offsets, bad)},
                            key=topo.names.index)
            problems.append(f"{field}[{', '.join(map(str, bad))}] (joints {', '.join(joints)})")
    if problems:
        raise SimulationError(f"{where}: non-finite values in " + "; ".join(problems))


def step(model: Model, world: World, state: State, target, dt, method: str = "maba",
         target_velocity=None) -> State:
    """Advance one character by dt under SPD control towards the pose `target` (nq) and, if
    given, the velocity `target_velocity` (nv; zero otherwise, as in thesis eq. 2.6).

    The state must carry contact memory when the world has contacts (`init_state`). Called
    outside `jit` the input is checked and a non-finite state raises `SimulationError`; inside
    `jit`, check `is_finite` on the result. Arrays of the wrong length raise ValueError.
    """
    check_layout(model, "state.q", state.q, "nq")
    check_layout(model, "state.qd", state.qd, "nv")
    if not isinstance(state.q, jax.core.Tracer):
        check_state(model, state)
    q, qd = state.q, state.qd
    f_ext, stretch, touching = None, state.contact_stretch, state.touching
    if world.has_contacts:
        if stretch is None:
            raise SimulationError("the state has no contact memory; make it with "
                                  "jaxsim.simulation.init_state(model, world, q, qd)")
        rot_w, pos_w, v_body = kinematics.link_states(model, q, qd)
        f_ext, stretch, touching = contact.contact_forces(model, world, rot_w, pos_w, v_body,
                                                          stretch, dt)
    extra = limits.joint_limit_torques(model, world, q, qd) if world.joint_limits else None
    qdd, tau = solve_spd(model, q, qd, target, dt, method, f_ext, world.gravity, extra,
                         target_velocity)
    if world.torque_limits:
        clipped, bound = limits.clip_torques(model, tau)
        applied = clipped if extra is None else clipped + extra
        qdd = jax.lax.cond(bound, lambda: aba(model, q, qd, applied, f_ext, world.gravity),
                           lambda: qdd)
    qd_next = qd + dt * qdd
    return State(kinematics.integrate(model, q, qd_next, dt), qd_next, stretch, touching)


@functools.partial(xla_options.jit, static_argnames=("method", "substeps"))
def simulate(model: Model, world: World, state: State, targets, dt, method: str = "maba",
             substeps: int = 1, target_velocities=None):
    """Run len(targets) control steps, each holding its target pose (and target velocity, if
    `target_velocities` (T, nv) is given) for `substeps` steps of dt.

    Returns (final state, the states after each control step), the latter with a leading time
    axis. A `lax.scan` over control steps around a `lax.scan` over substeps. Called at the top
    level with any method but sparse, it compiles with `jaxsim.xla_options`.
    """
    check_layout(model, "targets", targets, "nq", leading="T")
    if target_velocities is not None:
        check_layout(model, "target_velocities", target_velocities, "nv", leading="T")
    def control_step(s, control):
        target, target_velocity = control
        s, _ = jax.lax.scan(
            lambda c, _: (step(model, world, c, target, dt, method, target_velocity), None),
            s, None, length=substeps)
        return s, s

    return jax.lax.scan(control_step, state, (targets, target_velocities))


# Batched, every method runs faster with the batch innermost (`jaxsim.batch_last`) but sparse:
# at batch 4096 the tracking step 1.8–1.9× with maba and 4–6× with dense, the contact step 1.7×
# (docs/benchmarks.md). Sparse LTDL, which updates its work matrix one DoF at a time, runs 0.6×
# as fast that way at batch 256 (1.7× at 4096), so it keeps `jax.vmap`'s layout.
BATCH_FIRST_METHODS = ("sparse",)


def uses_batch_last(method: str, batch_last=None) -> bool:
    """Whether a batch computed by `method` has the batch innermost: `batch_last` if given,
    otherwise for every method outside `BATCH_FIRST_METHODS`."""
    return method not in BATCH_FIRST_METHODS if batch_last is None else batch_last


def batched(fun, method: str, batch_last=None, in_axes=0):
    """`fun` over a batch (axis 0 in and out), laid out as `uses_batch_last` chooses:
    `jaxsim.batch_last.vmap` or `jax.vmap`, with `in_axes` 0 or None per argument."""
    vmap = batch_last_vmap if uses_batch_last(method, batch_last) else jax.vmap
    return vmap(fun, in_axes=in_axes)


@functools.partial(xla_options.jit, static_argnames=("method", "substeps", "batch_last"))
def simulate_batch(model: Model, world: World, states: State, targets, dt, method: str = "maba",
                   substeps: int = 1, target_velocities=None, batch_last=None):
    """`simulate` for a batch of characters: states with a leading batch axis; targets (T, nq)
    shared by all or (batch, T, nq), target velocities likewise (T, nv) or (batch, T, nv); one
    model and world for all. Outputs carry the batch on axis 0.

    `batch_last` chooses how the batch is computed: with the batch as the innermost axis
    (`jaxsim.batch_last.vmap`), or as `jax.vmap` does, first. By default (None) the former for
    every method but those in `BATCH_FIRST_METHODS`. The results are the same either way.
    """
    def run(state, target, target_velocity):
        return simulate(model, world, state, target, dt, method, substeps, target_velocity)

    def axis(value):
        return None if value is None or jnp.ndim(value) == 2 else 0
    return batched(run, method, batch_last, in_axes=(0, axis(targets), axis(target_velocities)))(
        states, targets, target_velocities)
