"""A cheap, real black box for benchmarking strategy search: the take-off state's ballistic flight.

BDS (thesis §3.5.1, Algorithm 1) searches take-off states x for diverse strategies; its real
black box trains a jump policy per x (hours). This one keeps everything of that map but the
learning: from x, the jump task's take-off state (thesis §3.3, §3.6.1: `JumpEnv`'s, built by
`takeoff_state.takeoff_velocity`) flies for `TIME_AFTER_TAKEOFF` (2 s) at the task's simulation
rate (600 Hz) with every joint held at its take-off pose by stable PD (thesis eq. 2.6: the PD
target is the take-off pose q0 itself), in a world with gravity and nothing to touch — no ground,
no bar, no landing block. The feature is Stage 1's (§3.6.1): the angle between the root's facing
direction (its X axis) and the global up, in [0, π], at the first substep where the centre of
mass is past the crossing plane (the bar plane; the obstacle's centre plane) — `JumpEnv`'s own
crossing observer computes it, with the plane of the task's geometry at the curriculum's z_min.

A flight whose centre of mass never crosses the plane within the 2 s (its horizontal velocity
points away from the bar, or is too slow) is a failed evaluation: `__call__` returns
`bds.search.Failure`. With the pose held, the centre of mass flies on a parabola whatever the
joints do, so whether and when it crosses depends on x only through the take-off velocity; the
orientation at crossing depends on the angular momentum and the held pose's inertia.

One flight is a `lax.scan` over 1200 substeps; `features(xs)` runs many at once (vmapped with the
batch innermost, `jaxsim.simulation.batched`), in blocks of a fixed size so any number of points
compiles once. The object is picklable (a search's worker processes get it): the environment and
the compiled functions are built on first use in each process and never pickled.
"""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.tasks import common, jump
from jaxsim import simulation
from jaxsim.world import make_world

FAILURE_REASON = "the centre of mass never crossed the bar plane within 2 s"
BLEW_UP_REASON = "the simulation blew up before the centre of mass crossed the bar plane"
SETTINGS = {"highjump": jump.HighJumpSettings, "obstacle": jump.ObstacleSettings}
BLOCK = 64          # flights per compiled call of `features`


class BallisticBlackBox:
    """g(x) = the up angle at the bar-plane crossing of the take-off state's held-pose flight.

    `kind` is "highjump" (x = (α, ω_x, ω_z, v_z)) or "obstacle" (x = (ω_x, ω_y, ω_z));
    `data_dir` holds the reference data (None: `agents.datadir`'s rule); `settings` the task's
    `JumpSettings` (its character, clip, variations, gravity, simulation rate and method; its
    actions are irrelevant, no policy acts).
    `dtype` the simulation's (float32 by default; float64 for correctness checks); `block` the
    number of flights per compiled call of `features`.
    """

    def __init__(self, kind="highjump", data_dir=None, settings=None, dtype="float32",
                 block=BLOCK):
        if kind not in SETTINGS:
            raise ValueError(f"kind must be one of {', '.join(SETTINGS)}; got {kind!r}")
        settings = SETTINGS[kind]() if settings is None else settings
        if settings.KIND != kind:
            raise ValueError(f"settings are for the {settings.KIND or 'unknown'} task, not {kind}")
        if block < 1:
            raise ValueError(f"block must be at least 1; got {block}")
        if data_dir is None:
            from agents import datadir
            data_dir = datadir.data_dir_from()
        self.kind = kind
        # No policy acts, so no P-VAE is needed: the plain-PD action space builds without one.
        self.settings = dataclasses.replace(settings, actions="pd")
        self.data_dir = Path(data_dir)
        self.dtype = np.dtype(dtype).name
        self.block = int(block)
        self._built = None

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_built"] = None           # the environment and compiled code stay per process
        return state

    # ------------------------------------------------------------------ building (lazily)

    @property
    def env(self) -> jump.JumpEnv:
        """The jump environment whose take-off states, geometry and crossing observer fly."""
        return self._build()["env"]

    @property
    def substeps(self) -> int:
        return int(round(jump.TIME_AFTER_TAKEOFF * self.settings.sim_hz))

    def _build(self):
        if self._built is None:
            env = jump.JumpEnv(self.settings, self.data_dir, dtype=jnp.dtype(self.dtype))
            # The jump's world without its contact objects: no ground, no bar, no block; joint
            # and torque limits as in the task.
            world = make_world(gravity=self.settings.gravity, ground=False, boxes=(),
                               torque_limits=env.world.torque_limits,
                               joint_limits=env.world.joint_limits, dtype=env.q0.dtype)
            flight = _Flight(env, world, self.substeps)
            batched = simulation.batched(flight, self.settings.method, chunk=self.block)
            self._built = {"env": env, "flight": flight, "one": jax.jit(flight),
                           "many": jax.jit(batched)}
        return self._built

    # ------------------------------------------------------------------ evaluating

    def flights(self, xs) -> dict:
        """What each flight of the points xs (N, d) did, as numpy arrays with N rows:
        `crossed` (bool), `up_angle` (rad, the feature; 0 where not crossed), `cross_rotvec`
        (the root's orientation then relative to the facing frame, Stage 2's feature),
        `crossing_time` (s after take-off of the first substep past the plane; the flight's
        length where not crossed), `com_height` (the centre of mass's height then; NaN where not
        crossed), `peak_com` (its highest) and `sound` (the flight's end state finite and within
        the speed guard)."""
        built = self._build()
        xs = np.asarray(xs, self.dtype)
        dim = len(self.settings.x)
        if xs.ndim != 2 or xs.shape[1] != dim:
            raise ValueError(f"xs must be (N, {dim}) take-off features of the {self.kind}; got "
                             f"shape {xs.shape}")
        n = len(xs)
        if n == 0:
            return _empty(built["flight"], dim, self.dtype)
        padded = -(-n // self.block) * self.block
        xs = np.concatenate([xs, np.repeat(xs[-1:], padded - n, axis=0)])
        # A batch of any size runs as blocks of one compiled shape.
        pieces = [built["many"](jnp.asarray(xs[i:i + self.block]))
                  for i in range(0, padded, self.block)]
        return jax.tree_util.tree_map(lambda *p: np.concatenate(p)[:n], *pieces)

    def features(self, xs):
        """(up_angle (N,), crossed (N,) bool) of the points xs (N, d): the Stage-1 feature of
        each flight and whether its centre of mass crossed the plane within 2 s."""
        out = self.flights(xs)
        return out["up_angle"], out["crossed"]

    def flight(self, x) -> dict:
        """`flights` of one point x (d,), computed unbatched."""
        out = self._build()["one"](jnp.asarray(np.asarray(x, self.dtype)))
        return jax.tree_util.tree_map(np.asarray, out)

    def __call__(self, x):
        """The feature of one point as the search takes it: np.array([up_angle]), or a
        `bds.search.Failure` saying why there is none."""
        from bds.search import Failure
        out = self.flight(x)
        if not bool(out["crossed"]):
            return Failure(FAILURE_REASON if bool(out["sound"]) else BLEW_UP_REASON)
        return np.array([float(out["up_angle"])])


class _Flight:
    """One take-off state's held-pose flight (see the module docstring) as a pure function of
    x, for jit and vmap."""

    def __init__(self, env, world, substeps):
        self.env, self.world, self.substeps = env, world, substeps

    def __call__(self, x):
        env = self.env
        params = {**env.default_params(), "takeoff": x.astype(env.q0.dtype)}
        start = env.reset(params, jax.random.PRNGKey(0))          # the take-off state (§3.6.1)
        physics = simulation.init_state(env.model, self.world, start.physics.q, start.physics.qd)
        geometry = env.geometry(start.task)
        observe_crossing = env._crossing(start.task, geometry)

        def observe(state, seen):
            # `JumpEnv`'s observer, and a count of the substeps up to and including the one
            # that crossed (all of them when none did).
            task = observe_crossing(state, seen["task"])
            return {"task": task, "steps": seen["steps"] + (~seen["task"]["crossed"])}

        dt = 1.0 / env.settings.sim_hz
        end, _, seen = common.simulate_control_step(
            env.model, self.world, physics, env.q0, dt, self.substeps, env.settings.method,
            observe=observe, observed={"task": start.task, "steps": jnp.zeros((), jnp.int32)})
        task, bar_top = seen["task"], geometry[4]
        sound = simulation.is_finite(end) & jnp.all(jnp.abs(end.qd) < common.SPEED_LIMIT)
        return {"crossed": task["crossed"], "up_angle": task["up_angle"],
                "cross_rotvec": task["cross_rotvec"],
                "crossing_time": seen["steps"].astype(env.q0.dtype) * dt,
                "com_height": jnp.where(task["crossed"], task["clearance"] + bar_top, jnp.nan),
                "peak_com": task["peak_com"], "sound": sound}


def _empty(flight, dim, dtype):
    """`flights`' output for no points."""
    shapes = jax.eval_shape(flight, jax.ShapeDtypeStruct((dim,), np.dtype(dtype)))
    return jax.tree_util.tree_map(lambda s: np.zeros((0, *s.shape), s.dtype), shapes)
