"""Shared test setup: float64 everywhere, the reference data directory, random states, dropped
humanoids, the smallest high-jump training config."""

import os
import pathlib

# The suite's time is mostly XLA compiling small programs, so its processes (and the commands
# they start, which inherit the environment) compile without LLVM's optimisations: the same
# operations (fast-math is off either way), generated faster, if rounded differently in
# places. The whole run took 1,364 s in place of 1,481 s on the 2-core AMD EPYC VM
# (2026-12-06); the tests that run long rollouts take longer, the others less. (It found one
# gradient that depended on rounding: `jaxsim.contact.box_distance`.) Users' programs compile
# at XLA's defaults; set TAKEOFF_TEST_XLA_DEFAULTS=1 to test under them. (Before jax is
# imported: XLA reads the flags once, when its CPU backend starts.)
TEST_XLA_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
_flags = os.environ.get("XLA_FLAGS", "")
if not os.environ.get("TAKEOFF_TEST_XLA_DEFAULTS") and TEST_XLA_FLAGS not in _flags:
    os.environ["XLA_FLAGS"] = f"{_flags} {TEST_XLA_FLAGS}".strip()

import jax  # noqa: E402
import jax.numpy as jnp
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
# One CPU device in the test processes, whatever a config's run.devices asks `takeoff train` for
# (it asks only while the backend's device count is unset): which test first starts the backend
# must not decide how many devices the rest of a worker's tests see. Tests of several devices
# run in their own processes (tests/test_parallel_training.py).
jax.config.update("jax_num_cpu_devices", 1)

from agents import datadir  # noqa: E402  (after enabling float64)
from jaxsim import characters, simulation  # noqa: E402
from jaxsim.model import rest_pose  # noqa: E402
from jaxsim.tracking import tracking_model  # noqa: E402
from jaxsim.world import make_world  # noqa: E402


# The test files that take longest, first (measured 2026-12-04 with `--durations`, the README's
# command on the 2-core VM: the README file alone ~7.5 min, then ~2–4 min each). With
# `-n 2 --dist loadfile` a file goes whole to one worker, in the order the files are collected
# (`--no-loadscope-reorder` in pyproject.toml; xdist would otherwise put files with many tests
# first), so a long file collected last keeps one worker busy alone at the end of the run. A file
# not named keeps its place after these; a stale list only costs time.
SLOWEST_FILES_FIRST = ("test_readme.py", "test_sweep.py", "test_simulation.py",
                       "test_dynamics.py", "test_batch_last.py", "test_sensitivity.py",
                       "test_runup.py", "test_discovery.py", "test_jump.py",
                       "test_parallel_training.py", "test_stage2.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))     # (stable)


@pytest.fixture(scope="session")
def data_dir() -> pathlib.Path:
    """The reference data, where the commands look for it (`agents.datadir`); a missing one is
    a failure."""
    path = pathlib.Path(os.environ.get("TAKEOFF_DATA") or datadir.checkout_default()).resolve()
    if not (path / "deepmimic" / "characters" / "humanoid3d.txt").exists():
        pytest.fail(f"reference data not found in {path}; set TAKEOFF_DATA to ../shared/data")
    return path


def random_state(model, seed, joint_spread=0.6, velocity_scale=1.0):
    """A random (q, qd) with unit quaternions and a random target pose, all float64."""
    rng = np.random.default_rng(seed)
    topo = model.topology

    def random_pose():
        q = np.array(rest_pose(model), float)
        for i, kind in enumerate(topo.joint_types):
            o = topo.q_offsets[i]
            if kind == "free":
                q[o:o + 3] = rng.normal(size=3)
                quat = rng.normal(size=4)
                q[o + 3:o + 7] = quat / np.linalg.norm(quat)
            elif kind == "spherical":
                quat = np.concatenate([[1.0], rng.normal(scale=joint_spread, size=3)])
                q[o:o + 4] = quat / np.linalg.norm(quat)
            elif kind == "revolute":
                q[o] = rng.normal(scale=joint_spread)
        return q

    q, target = random_pose(), random_pose()
    qd = rng.normal(scale=velocity_scale, size=topo.nv)
    return jnp.asarray(q), jnp.asarray(qd), jnp.asarray(target)


def dropped_humanoids(steps, batch, height, jitter=False):
    """`batch` humanoids (joints held by SPD at the rest pose, root free) dropped onto the ground,
    the k-th with its lowest point `height` + 2k cm up; with `jitter`, random joint angles
    (σ 0.05) and velocities (σ 0.3). Contacts, joint limits, float64. Returns the model, the
    world, the batched initial states and the targets (steps, nq)."""
    model = tracking_model(characters.humanoid().astype(jnp.float64), root_gains=(0.0, 0.0))
    world = make_world(dtype=jnp.float64)
    low, _ = characters.vertical_extent(model)
    q0 = rest_pose(model, -low + height)
    rng = np.random.default_rng(1)
    states = []
    for k in range(batch):
        q, qd = q0.at[1].add(0.02 * k), None
        if jitter:
            q = q.at[7:].add(jnp.asarray(rng.normal(scale=0.05, size=model.nq - 7)))
            qd = jnp.asarray(rng.normal(scale=0.3, size=model.nv))
        states.append(simulation.init_state(model, world, q, qd))
    return model, world, jax.tree.map(lambda *x: jnp.stack(x), *states), jnp.tile(q0, (steps, 1))


@pytest.fixture(scope="session")
def models(data_dir):
    """Every character the dynamics tests run on, in float64."""
    dm = data_dir / "deepmimic"
    built = {
        "humanoid": characters.humanoid(),
        "quadruped": characters.quadruped(),
        "snake10": characters.snake(10),
        "deepmimic_humanoid": characters.load_deepmimic(
            dm / "characters" / "humanoid3d.txt", dm / "controllers" / "humanoid3d_ctrl.txt"),
        "deepmimic_dog": characters.load_deepmimic(
            dm / "characters" / "dog3d.txt", dm / "controllers" / "dog3d_ctrl.txt"),
    }
    return {name: m.astype(jnp.float64) for name, m in built.items()}


def tiny_highjump_training(iterations=1, hidden=16, actions='actions = "pd"'):
    """The TOML of the smallest high-jump training: 4 environments × 4 steps an iteration, a
    network of one `hidden`-unit layer, 4-step episodes (0.13 s: no episode can clear the bar).
    `actions` is the [highjump] line (or lines) choosing the action space."""
    return f"""
[run]
task = "highjump"
envs = 4
steps_per_iteration = 4
iterations = {iterations}
checkpoint_every = 1
devices = 1

[ppo]
hidden = [{hidden}]
minibatch_size = 16
epochs = 1

[highjump]
{actions}
episode_steps = 4
control_schedule = false
control_hz = 30.0
"""
