"""Pieces every simulated task shares: data files, link names, the task parameters that go into
the world, control steps of simulation substeps with touch bookkeeping, and the guard that keeps
a blown-up state out of an episode."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import ConfigError
from jaxsim import simulation

# Task parameters (the `params` pytree of an env) that are `World` fields by the same name.
WORLD_PARAMS = ("gravity", "friction", "contact_stiffness", "contact_damping")
# rad/s and m/s: no character here comes near it (a sprinter's limbs ~30 rad/s, 15 m/s) unless
# its simulation has blown up.
SPEED_LIMIT = 1e3


def data_file(name: str, folder: Path, key: str) -> Path:
    """`name` in `folder` if it is there, else `name` as a path; a ConfigError naming `key`."""
    for path in (Path(folder) / name, Path(name)):
        if path.is_file():
            return path
    raise ConfigError(f"{key}: no file {name!r} in {folder} nor at that path")


def link_indices(model, names, key: str) -> np.ndarray:
    """The indices of the links `names` in `model`; a ConfigError naming `key` and listing the
    model's links for a name it does not have."""
    topo = model.topology
    unknown = [name for name in names if name not in topo.names]
    if unknown:
        raise ConfigError(f"{key}: unknown link {unknown[0]!r}; links: {', '.join(topo.names)}")
    return np.array([topo.link_index(name) for name in names], int)


def world_of(world, params):
    """`world` with the task parameters that are world fields (`WORLD_PARAMS`) taken from
    `params`, so a sweep or a curriculum can change them without rebuilding anything."""
    return world.replace(**{name: params[name] for name in WORLD_PARAMS if name in params})


def simulate_control_step(model, world, physics, target, dt, substeps: int, method: str,
                          target_velocity=None, observe=None, observed=None):
    """`substeps` simulation steps of dt towards the PD `target` (a `lax.scan`); returns the
    state and which link touched which object in any of them ((n_links, n_objects) bools).
    With `observe(state, observed) -> observed`, also what it makes of every substep's state,
    starting from `observed` (a task's per-substep bookkeeping, e.g. a plane crossing)."""
    def substep(carry, _):
        state, touched, seen = carry
        state = simulation.step(model, world, state, target, dt, method, target_velocity)
        seen = seen if observe is None else observe(state, seen)
        return (state, touched | state.touching, seen), None

    touched = jnp.zeros(physics.touching.shape, bool)
    (physics, touched, observed), _ = jax.lax.scan(substep, (physics, touched, observed), None,
                                                   length=substeps)
    return (physics, touched) if observe is None else (physics, touched, observed)


def keep_sound(stepped, before):
    """(`stepped` where it is sound, else `before`; whether it was sound): a step that blew up
    ends its episode in the last good state instead of carrying NaNs into the batch. Sound is
    finite with every velocity (q̇, rad/s and m/s) within `SPEED_LIMIT`: a simulation that blows
    up can grow for a while before it overflows, and observations of 1e20 m/s, though finite,
    overflow the observation statistics (a jump training stopped so at iteration 440)."""
    sound = simulation.is_finite(stepped) & jnp.all(jnp.abs(stepped.qd) < SPEED_LIMIT)
    kept = jax.tree_util.tree_map(lambda new, old: jnp.where(sound, new, old), stepped, before)
    return kept, sound
