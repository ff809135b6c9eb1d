"""The simulation step and multi-step simulation (docs/design.md, "Simulation step").

One step: collisions → contact forces → joint-limit torques → SPD solve (thesis eq. 2.7, by the
chosen method; the joint-limit dampers implicit in it) → torque limits (clip, and where they
bind re-solve with the clipped torques applied as given) → semi-implicit Euler (q̇ ← q̇ + Δt q̈,
then q advanced with the new velocity, quaternions on the manifold).

All functions act on one character; batch with `jax.vmap`, or faster with `simulate_batch`
(which computes with the batch innermost, `jaxsim.batch_last`).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import batch_last as batch_last_lib
from jaxsim import contact, kinematics, limits, xla_options
from jaxsim.batch_last import vmap as batch_last_vmap
from jaxsim.dynamics import solve_applied, solve_spd
from jaxsim.model import Model, State, check_layout
from jaxsim.world import World


class SimulationError(ValueError):
    """Inputs that cannot be simulated (non-finite numbers, a dt that is not > 0) or a rollout
    that turned non-finite; the message names the joints, control steps and batch members."""


def init_state(model: Model, world: World, q, qd=None) -> State:
    """A state ready to step in `world`: friction springs unstretched, no touches recorded yet.
    `qd` defaults to rest. Outside `jit`, non-finite q or qd raise `SimulationError`."""
    check_layout(model, "q", q, "nq")
    if qd is not None:
        check_layout(model, "qd", qd, "nv")
    for field, values in (("q", q), ("qd", qd)):
        _check_finite(model, "init_state", field, values)
    q = jnp.asarray(q, model.mass.dtype)
    qd = jnp.zeros(model.nv, q.dtype) if qd is None else jnp.asarray(qd, q.dtype)
    n_contacts = len(contact.contact_layout(model, world))
    return State(q, qd, jnp.zeros((n_contacts, 3), q.dtype),
                 jnp.zeros((model.n_links, len(world.object_names)), bool))


def is_finite(state: State):
    """True when q and q̇ hold only finite numbers (jittable: a flag to check after a rollout)."""
    return jnp.all(jnp.isfinite(state.q)) & jnp.all(jnp.isfinite(state.qd))


def first_non_finite(trajectory: State):
    """The first control step whose q or q̇ holds a non-finite number, or -1 when none does, for
    the states after each control step that `simulate` returns (time axis second to last:
    one index, or one per member for `simulate_batch`'s). Jittable: the flag to check after a
    rollout inside `jit`, where `simulate` cannot raise."""
    bad = ~(jnp.all(jnp.isfinite(trajectory.q), -1) & jnp.all(jnp.isfinite(trajectory.qd), -1))
    return jnp.where(jnp.any(bad, -1), jnp.argmax(bad, -1), -1)


def _owners(offsets, index):
    return np.searchsorted(offsets, index, side="right") - 1


def _concrete(*values) -> bool:
    """Whether none of the values is traced (then they can be checked in Python)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(values))


def _listing(indices, limit: int = 8) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:limit])
    return shown if len(indices) <= limit else f"{shown}, … ({len(indices)} in all)"


def _non_finite(model: Model, field: str, values, axes=()):
    """None when `values` (..., nq) for field "q" or (..., nv) for "qd" are all finite; else
    which entries are not, with their joints, and along each leading axis named in `axes` (such
    as "in batch member", "at control step") where."""
    bad = ~np.isfinite(np.asarray(values))
    if not bad.any():
        return None
    topo = model.topology
    offsets = topo.q_offsets if field == "q" else topo.dof_offsets
    columns = np.flatnonzero(bad.reshape(-1, bad.shape[-1]).any(0))
    joints = sorted({topo.names[i] for i in _owners(offsets, columns)}, key=topo.names.index)
    text = f"{field}[{', '.join(map(str, columns))}] (joints {', '.join(joints)})"
    for axis, name in enumerate(axes):
        where = np.flatnonzero(bad.any(tuple(a for a in range(bad.ndim) if a != axis)))
        text += f" {name}{'s' if len(where) > 1 else ''} {_listing(where)}"
    return text


def _check_finite(model: Model, where: str, field: str, values, axes=()):
    """Raise `SimulationError` when concrete `values` (see `_non_finite`) are not all finite."""
    if values is not None and _concrete(values):
        problem = _non_finite(model, field, values, axes)
        if problem:
            raise SimulationError(f"{where}: non-finite values in {problem}")


def check_state(model: Model, state: State, where: str = "state", axes=()):
    """Raise `SimulationError` naming the joints whose q or q̇ entries are not finite (for states
    with leading axes, such as a batch, those named in `axes` say where along them)."""
    problems = [p for p in (_non_finite(model, "q", state.q, axes),
                            _non_finite(model, "qd", state.qd, axes)) if p]
    if problems:
        raise SimulationError(f"{where}: non-finite values in " + "; ".join(problems))


def _check_dt(dt):
    """Raise `SimulationError` unless `dt`, when concrete, is a finite number > 0."""
    if isinstance(dt, jax.core.Tracer):
        return
    try:
        value = float(np.asarray(dt, dtype=float)) if np.ndim(dt) == 0 else None
    except (TypeError, ValueError):
        value = None
    if value is None or not (np.isfinite(value) and value > 0):
        raise SimulationError("dt must be a finite number > 0 (seconds), got "
                              f"{repr(dt) if value is None else value}")


def step(model: Model, world: World, state: State, target, dt, method: str = "maba",
         target_velocity=None) -> State:
    """Advance one character by dt under SPD control towards the pose `target` (nq) and, if
    given, the velocity `target_velocity` (nv; zero otherwise, as in thesis eq. 2.6).

    The state must carry contact memory when the world has contacts (`init_state`). Called
    outside `jit` the inputs are checked: a non-finite state, target or target velocity, or a dt
    that is not a finite number > 0, raises `SimulationError`; inside `jit`, check `is_finite`
    on the result. Arrays of the wrong length raise ValueError.
    """
    check_layout(model, "state.q", state.q, "nq")
    check_layout(model, "state.qd", state.qd, "nv")
    check_layout(model, "target", target, "nq")
    if target_velocity is not None:
        check_layout(model, "target_velocity", target_velocity, "nv")
    if _concrete(state.q, state.qd):
        check_state(model, state)
    _check_finite(model, "target", "q", target)
    _check_finite(model, "target_velocity", "qd", target_velocity)
    _check_dt(dt)
    q, qd = state.q, state.qd
    f_ext, stretch, touching = None, state.contact_stretch, state.touching
    if world.has_contacts:
        if stretch is None:
            raise SimulationError("the state has no contact memory; make it with "
                                  "jaxsim.simulation.init_state(model, world, q, qd)")
        rot_w, pos_w, v_body = kinematics.link_states(model, q, qd)
        f_ext, stretch, touching = contact.contact_forces(model, world, rot_w, pos_w, v_body,
                                                          stretch, dt)
    spring, damper = (limits.joint_limit_forces(model, world, q, qd) if world.joint_limits
                      else (None, None))
    qdd, tau = solve_spd(model, q, qd, target, dt, method, f_ext, world.gravity, spring,
                         target_velocity, damper)
    if world.torque_limits:
        clipped = jnp.clip(tau, -model.torque_limit, model.torque_limit)
        applied = clipped if spring is None else clipped + spring
        qdd = jax.lax.cond(jnp.any(clipped != tau),
                           lambda: solve_applied(model, q, qd, applied, dt, f_ext, world.gravity,
                                                 damper),
                           lambda: qdd)
    qd_next = qd + dt * qdd
    return State(kinematics.integrate(model, q, qd_next, dt), qd_next, stretch, touching)


def simulate(model: Model, world: World, state: State, targets, dt, method: str = "maba",
             substeps: int = 1, target_velocities=None, check_result: bool = True):
    """Run len(targets) control steps, each holding its target pose (and target velocity, if
    `target_velocities` (T, nv) is given) for `substeps` steps of dt.

    Returns (final state, the states after each control step), the latter with a leading time
    axis. A `lax.scan` over control steps around a `lax.scan` over substeps. Called at the top
    level with any method but sparse, it compiles with `jaxsim.xla_options`.

    Inputs that are not traced are checked first: a non-finite state, target or target
    velocity, or a dt that is not a finite number > 0, raises `SimulationError` naming the
    control steps and joints. Called outside `jit`, a trajectory that turns non-finite from
    finite inputs raises `SimulationError` saying at which control step and in which joints it
    first did (`check_result=False` returns it as it is, for studies of where a method
    diverges); inside `jit`, check `first_non_finite(trajectory)` (-1 when all is finite).
    """
    check_layout(model, "targets", targets, "nq", leading="T")
    if target_velocities is not None:
        check_layout(model, "target_velocities", target_velocities, "nv", leading="T")
    _check_inputs(model, "state", state, targets, dt, target_velocities, ())
    result = _simulate(model, world, state, targets, dt, method, substeps, target_velocities)
    if check_result:
        _check_trajectory(model, "simulate", result[1], dt, substeps)
    return result


def _check_inputs(model: Model, name: str, state: State, targets, dt, target_velocities,
                  batch_axes):
    """The checks of `simulate` (`batch_axes` ("in batch member",) for states with a leading
    batch axis), on the concrete inputs."""
    if _concrete(state.q, state.qd):
        check_state(model, state, name, batch_axes)

    def axes(values):       # (T, n) shared by the batch or (batch, T, n)
        return batch_axes[:np.ndim(values) - 2] + ("at control step",)
    _check_finite(model, "targets", "q", targets, axes(targets))
    if target_velocities is not None:
        _check_finite(model, "target_velocities", "qd", target_velocities,
                      axes(target_velocities))
    _check_dt(dt)


def _check_trajectory(model: Model, where: str, trajectory: State, dt, substeps: int):
    """Raise `SimulationError` when a concrete trajectory (T, n), or (batch, T, n), holds
    non-finite numbers: where they first arose and, for a batch, which members have any."""
    if not _concrete(trajectory.q, trajectory.qd):
        return
    q, qd = np.asarray(trajectory.q), np.asarray(trajectory.qd)
    bad = ~(np.isfinite(q).all(-1) & np.isfinite(qd).all(-1))       # (..., T)
    if not bad.any():
        return
    k = int(np.flatnonzero(bad.reshape(-1, bad.shape[-1]).any(0))[0])
    members = np.flatnonzero(bad[:, k]) if bad.ndim == 2 else None
    at_k = k if members is None else (members, k)
    problems = [p for p in (_non_finite(model, "q", q[at_k]), _non_finite(model, "qd", qd[at_k]))
                if p]
    text = (f"{where}: the trajectory turned non-finite at control step {k} "
            f"(t = {(k + 1) * substeps * float(dt):.6g} s)")
    if members is not None:
        text += f" in batch member{'s' if len(members) > 1 else ''} {_listing(members)}"
    text += f" from a finite state and targets: {'; '.join(problems)}"
    if members is not None:
        every = np.flatnonzero(bad.any(-1))
        text += (f"; in all, batch member{'s' if len(every) > 1 else ''} {_listing(every)} "
                 "turn non-finite")
    raise SimulationError(text + " (inside jit, check first_non_finite(trajectory))")


@functools.partial(xla_options.jit, static_argnames=("method", "substeps"))
def _simulate(model: Model, world: World, state: State, targets, dt, method: str = "maba",
              substeps: int = 1, target_velocities=None):
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


def batched(fun, method: str, batch_last=None, in_axes=0, chunk=None, devices=1):
    """`fun` over a batch (axis 0 in and out), laid out as `uses_batch_last` chooses:
    `jaxsim.batch_last.vmap`, `chunk` members at a time (None: its default), or `jax.vmap`,
    with `in_axes` 0 or None per argument; with `devices` > 1 the batch split evenly over the
    first `devices` local devices, each computing its own share (`jax.shard_map`)."""
    if uses_batch_last(method, batch_last):
        per_device = batch_last_vmap(fun, in_axes=in_axes, chunk=chunk)
    else:
        per_device = jax.vmap(fun, in_axes=in_axes)
    if devices == 1:
        return per_device
    local = jax.local_devices()
    if not 1 <= devices <= len(local):
        raise ValueError(f"devices must be between 1 and the {len(local)} local devices; got "
                         f"{devices}")
    return per_shard(per_device, jax.sharding.Mesh(np.array(local[:devices]), ("batch",)),
                     in_axes)


def per_shard(batched_fun, mesh, in_axes=0):
    """`batched_fun` (arguments batched on axis 0, or not where `in_axes` is None; outputs
    batched on axis 0) with each device of the one-axis `mesh` computing its own shard of the
    batch (`jax.shard_map`), so what it does with its batch (`batch_last`'s chunks) is each
    device's own. `in_axes`: 0 or None, or one of them per positional argument."""
    P = jax.sharding.PartitionSpec
    (axis,) = mesh.axis_names

    def spec(in_axis):
        return P() if in_axis is None else P(axis)
    specs = (tuple(spec(a) for a in in_axes) if isinstance(in_axes, (tuple, list))
             else spec(in_axes))
    # (check_vma off: `batch_last` binds primitives itself, without the replication bookkeeping
    # that check asks of each operation; every output is per shard anyway)
    return jax.shard_map(batched_fun, mesh=mesh, in_specs=specs, out_specs=P(axis),
                         check_vma=False)


def simulate_batch(model: Model, world: World, states: State, targets, dt, method: str = "maba",
                   substeps: int = 1, target_velocities=None, batch_last=None,
                   check_result: bool = True, chunk=None, devices: int = 1):
    """`simulate` for a batch of characters: states with a leading batch axis; targets (T, nq)
    shared by all or (batch, T, nq), target velocities likewise (T, nv) or (batch, T, nv); one
    model and world for all. Outputs carry the batch on axis 0.

    `batch_last` chooses how the batch is computed: with the batch as the innermost axis
    (`jaxsim.batch_last.vmap`), or as `jax.vmap` does, first. By default (None) the former for
    every method but those in `BATCH_FIRST_METHODS`. The results are the same either way.
    With the batch innermost, `chunk` members are simulated at once, the whole trajectory of one
    piece of the batch after another (`jaxsim.batch_last.vmap`; None: its measured default), so
    that a large batch runs as fast per character as a small one. With `devices` > 1 the batch
    is split over that many local devices (on the CPU, host devices: start Python with
    XLA_FLAGS=--xla_force_host_platform_device_count=N), each simulating its own share; the
    batch size must be a multiple of it.

    Inputs and results are checked as `simulate` checks them, the errors naming the batch
    members too; inside `jit`, `first_non_finite(trajectory)` gives one index per member.
    """
    check_layout(model, "states.q", states.q, "nq", leading="batch")
    check_layout(model, "states.qd", states.qd, "nv", leading="batch")
    for name, values, layout in (("targets", targets, "nq"),
                                 ("target_velocities", target_velocities, "nv")):
        if values is not None:          # (T, n), or (batch, T, n): checked as one member's
            shape = np.shape(values)
            member = jax.ShapeDtypeStruct(shape[1:] if len(shape) == 3 else shape, float)
            check_layout(model, name, member, layout, leading="T")
    _check_inputs(model, "states", states, targets, dt, target_velocities, ("in batch member",))
    size = states.q.shape[0]
    if devices > 1 and size % devices:
        raise ValueError(f"simulate_batch: a batch of {size} cannot be split evenly over "
                         f"devices = {devices}")
    result = _simulate_batch(model, world, states, targets, dt, method, substeps,
                             target_velocities, batch_last,
                             batch_last_lib.default_chunk() if chunk is None else chunk, devices)
    if check_result:
        _check_trajectory(model, "simulate_batch", result[1], dt, substeps)
    return result


@functools.partial(xla_options.jit,
                   static_argnames=("method", "substeps", "batch_last", "chunk", "devices"))
def _simulate_batch(model: Model, world: World, states: State, targets, dt,
                    method: str = "maba", substeps: int = 1, target_velocities=None,
                    batch_last=None, chunk=None, devices=1):
    def run(state, target, target_velocity):
        return _simulate(model, world, state, target, dt, method, substeps, target_velocity)

    def axis(value):
        return None if value is None or jnp.ndim(value) == 2 else 0
    return batched(run, method, batch_last, in_axes=(0, axis(targets), axis(target_velocities)),
                   chunk=chunk, devices=devices)(states, targets, target_velocities)
