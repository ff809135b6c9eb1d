"""The ballistic black box (agents.tasks.ballistic): the take-off state's held-pose flight against
the free-flight parabola of its centre of mass, its failures, its batched and one-point paths,
and pickling. Float64 (conftest)."""

import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.tasks import ballistic, jump, takeoff_state
from bds.search import Failure
from jaxsim import kinematics

LOWER, UPPER = (np.array(b) for b in takeoff_state.HIGHJUMP_BOUNDS)


@pytest.fixture(scope="module")
def box(data_dir):
    return ballistic.BallisticBlackBox("highjump", data_dir, dtype="float64", block=4)


@pytest.fixture(scope="module")
def fine(data_dir):
    """The same flights at four times the simulation rate (2400 Hz, 4800 substeps)."""
    return ballistic.BallisticBlackBox("highjump", data_dir,
                                       jump.HighJumpSettings(sim_hz=2400.0), dtype="float64",
                                       block=4)


def _points(count, seed):
    """The thesis's six take-off states (Table 3.3) and `count` uniform points of the box."""
    rng = np.random.default_rng(seed)
    rows = np.array(list(takeoff_state.HIGHJUMP_ROWS.values()))
    return np.concatenate([rows, LOWER + (UPPER - LOWER) * rng.uniform(size=(count, 4))])


def _analytic(box, xs):
    """Per x, from the take-off state alone: the time t* at which a centre of mass moving at its
    take-off velocity reaches the crossing plane (inf when it moves away from it), and the
    free-flight height y(t) = y0 + v_y t − g t²/2 as a function."""
    env = box.env
    foot = env.model.topology.link_index(env.takeoff.foot)

    @jax.jit
    @jax.vmap
    def com_velocity(x):
        qd = takeoff_state.takeoff_velocity(env.kind, env.model, env.q0, env.qd0, x, foot)
        return kinematics.center_of_mass_velocity(env.model, env.q0, qd)

    g = -env.settings.gravity[1]
    com = np.asarray(kinematics.center_of_mass(env.model, env.q0))   # x changes no pose
    times, heights = [], []
    for x, velocity in zip(xs, np.asarray(com_velocity(jnp.asarray(xs)))):
        task = {"takeoff": jnp.asarray(x), "difficulty": env.settings.z_min}
        normal, origin, _, cross, *_ = (np.asarray(a) for a in env.geometry(task))
        assert abs(normal[1]) < 1e-12                       # a vertical plane
        speed = normal @ velocity                           # gravity has no part along n
        gap = float(cross) - normal @ (com - origin)
        times.append(gap / speed if speed > 0 else np.inf)
        heights.append(lambda t, vy=velocity[1]: com[1] + vy * t - 0.5 * g * t ** 2)
    return np.array(times), heights


def _crossing_errors(box, xs, t_star, height):
    """The flights' centre-of-mass height at the crossing less the free-flight parabola's at
    that time, and the crossing time less the analytic t*."""
    out = box.flights(xs)
    assert out["crossed"].all() and out["sound"].all()
    t = out["crossing_time"]
    return (np.array([out["com_height"][i] - height[i](t[i]) for i in range(len(xs))]),
            t - t_star)


def _reaching(box, count, seed):
    """Points (the table's rows and uniform ones) whose centre of mass reaches the plane well
    within 2 s, with their analytic crossing times and parabolas."""
    xs = _points(count, seed)
    t_star, height = _analytic(box, xs)
    within = t_star < 1.5
    assert within.sum() >= 10
    return xs[within], t_star[within], [h for h, w in zip(height, within) if w]


def test_the_centre_of_mass_flies_on_its_parabola_and_crosses_when_it_reaches_the_plane(box):
    """With nothing to touch, the centre of mass moves under gravity alone whatever the joints
    do: at the crossing it has the height of the free-flight parabola from its take-off velocity,
    at the time that velocity's component along the bar normal takes it to the plane — to the
    600 Hz step's first-order accuracy (centimetres; `..._converge_...` below shows that the
    errors are the step's). A flight that touched something or felt another gravity would be
    off by decimetres or more."""
    xs, t_star, height = _reaching(box, 6, seed=0)
    height_error, time_error = _crossing_errors(box, xs, t_star, height)
    assert np.max(np.abs(height_error)) < 0.05
    assert np.max(np.abs(time_error)) < 0.1


@pytest.mark.slow
def test_the_crossing_errors_converge_at_first_order_in_the_time_step(box, fine):
    """The simulation (semi-implicit Euler) is first-order accurate, so the errors against the
    free flight must shrink at least twofold when the time step shrinks fourfold."""
    xs, t_star, height = _reaching(box, 6, seed=0)
    coarse = _crossing_errors(box, xs, t_star, height)
    finer = _crossing_errors(fine, xs, t_star, height)
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))
    for c, f in zip(coarse, finer):
        assert rms(f) <= rms(c) / 2, (c, f)


def test_a_flight_that_never_reaches_the_bar_plane_is_a_failure(box):
    """Corners of the box whose take-off velocity points away from the bar (α = −30°, the
    bar behind the run's direction) or reaches it only after 2 s fail; the others cross."""
    corners = np.array(np.meshgrid(*zip(LOWER, UPPER), indexing="ij")).reshape(4, -1).T
    xs = np.concatenate([corners, _points(6, seed=1)])
    t_star, _ = _analytic(box, xs)
    away = np.isinf(t_star)
    assert away.any() and not away.all()
    up_angle, crossed = box.features(xs)
    limit = jump.TIME_AFTER_TAKEOFF
    decided = np.abs(t_star - limit) > 0.2                     # not at the limit
    np.testing.assert_array_equal(crossed[decided], (t_star <= limit)[decided])
    assert np.all(up_angle[~crossed] == 0.0)
    assert np.all((up_angle[crossed] >= 0) & (up_angle[crossed] <= np.pi))
    failure = box(xs[np.flatnonzero(away)[0]])
    assert isinstance(failure, Failure)
    assert failure.reason == "the centre of mass never crossed the bar plane within 2 s"


def test_one_point_agrees_with_the_batch(box):
    """`__call__` (one flight, unbatched) gives what `features` (blocks of 4, the last padded,
    with the batch innermost) gives, failures included."""
    xs = np.concatenate([_points(2, seed=2)[[0, 1, 6]],
                         [[LOWER[0], 0.0, 0.0, UPPER[3]]],         # the bar behind: fails
                         _points(1, seed=3)[-1:]])
    up_angle, crossed = box.features(xs)
    assert crossed.sum() == 4 and not crossed[3]
    for x, angle, ok in zip(xs, up_angle, crossed):
        value = box(x)
        if ok:
            assert isinstance(value, np.ndarray) and value.shape == (1,)
            assert value[0] == pytest.approx(angle, abs=1e-9)
        else:
            assert isinstance(value, Failure)
    assert box.features(np.zeros((0, 4)))[0].shape == (0,)
    with pytest.raises(ValueError, match=r"xs must be \(N, 4\)"):
        box.features(xs[:, :3])


def test_the_black_box_pickles_without_its_environment(box):
    """A search's worker processes get the black box pickled: its settings travel, its built
    environment and compiled functions do not (each process builds its own on first use)."""
    box(np.array(takeoff_state.HIGHJUMP_ROWS["straddle"]))       # built here
    data = pickle.dumps(box)
    assert len(data) < 4000
    twin = pickle.loads(data)
    assert twin._built is None and box._built is not None
    assert {k: v for k, v in vars(twin).items() if k != "_built"} == \
        {k: v for k, v in vars(box).items() if k != "_built"}


def test_settings_of_another_task_or_kind_are_errors(data_dir):
    with pytest.raises(ValueError, match="kind must be one of highjump, obstacle"):
        ballistic.BallisticBlackBox("longjump", data_dir)
    with pytest.raises(ValueError, match="settings are for the obstacle task, not highjump"):
        ballistic.BallisticBlackBox("highjump", data_dir, jump.ObstacleSettings())
    box = ballistic.BallisticBlackBox("highjump", data_dir, jump.HighJumpSettings())
    assert box.settings.actions == "pd"            # no P-VAE is needed for a held pose
    assert box.substeps == 1200


@pytest.mark.slow
def test_the_obstacle_s_flight_crosses_the_obstacle_s_centre_plane(data_dir):
    """The obstacle jump's crossing plane is the obstacle's centre plane at the curriculum's
    first width z_min; its flights too follow the parabola (to the 600 Hz step's accuracy)."""
    box = ballistic.BallisticBlackBox("obstacle", data_dir, dtype="float64", block=4)
    xs = np.array(list(takeoff_state.OBSTACLE_ROWS.values()))
    t_star, height = _analytic(box, xs)
    out = box.flights(xs)
    normal, origin, _, cross, *_ = box.env.geometry(
        {"takeoff": jnp.asarray(xs[0]), "difficulty": box.settings.z_min})
    assert float(cross) == pytest.approx(jump.OBSTACLE_DISTANCE + box.settings.z_min / 2)
    reached = t_star < 1.8
    assert reached.any()
    np.testing.assert_array_equal(out["crossed"][reached], True)
    t = out["crossing_time"][reached]
    np.testing.assert_allclose(t, t_star[reached], atol=0.05)
    np.testing.assert_allclose(out["com_height"][reached],
                               [h(ti) for h, ti in zip(np.array(height)[reached], t)], atol=0.05)
