"""Sensitivity studies (`agents.sensitivity`): the gradient of a ballistic apex against its
analytic value, an articulated PD rollout's gradient (its return, a walk's tracking error)
against central finite differences, a contact-free gradient that agrees being marked so and a
made-up disagreement flagged, and parameter names checked."""

import jax
import jax.numpy as jnp
import pytest

from agents import sensitivity
from agents.tasks import imitation, reach
from jaxsim import simulation
from jaxsim.builder import LinkSpec, build_model
from jaxsim.world import make_world

DT = 1.0 / 600.0


def ball_apex(values):
    """The highest a free 1 kg ball gets, thrown up at v m/s under gravity g (no ground), over
    0.6 s of 600 Hz steps."""
    model = build_model([LinkSpec("ball", None, "free", mass=1.0, shape="sphere",
                                  shape_size=(0.1, 0.0, 0.0))], dtype=jnp.float64)
    world = make_world(gravity=(0.0, -9.81, 0.0), ground=False, dtype=jnp.float64)
    world = world.replace(gravity=jnp.stack([0.0, -values["g"], 0.0]))
    q = jnp.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    qd = jnp.zeros(6).at[4].set(values["v"])           # body frame [ω; v]: v along +Y
    state = simulation.init_state(model, world, q, qd)

    def substep(carry, _):
        state, apex = carry
        state = simulation.step(model, world, state, q, DT)
        return (state, jnp.maximum(apex, state.q[1])), None

    (_, apex), _ = jax.lax.scan(substep, (state, q[1]), None, length=360)
    return apex


def test_the_apex_of_a_ballistic_flight_has_the_analytic_gradient():
    """h = v²/2g ⇒ ∂h/∂v = v/g, ∂h/∂g = −v²/2g², to the time step, and the finite differences
    agree; elasticities 2 and −1. The simulator's semi-implicit Euler steps reach
    (v − g·dt/2)²/2g (the highest of its states, within g·dt²/8), v·dt/2 below the flight's
    apex; their gradient differs from the flight's by up to dt/2·(1, v/g) (0.5 %, 1 %)."""
    v, g = 3.0, 9.81
    result = sensitivity.study(ball_apex, {"v": v, "g": g}, fd_step=1e-5)
    rows = {r.name: r for r in result.rows}
    assert result.outcome == pytest.approx((v - g * DT / 2) ** 2 / (2 * g), abs=g * DT**2 / 8)
    assert rows["v"].gradient == pytest.approx(v / g, rel=1e-2)
    assert rows["g"].gradient == pytest.approx(-v**2 / (2 * g**2), rel=1e-2)
    assert rows["v"].elasticity == pytest.approx(2.0, rel=1e-2)
    assert rows["g"].elasticity == pytest.approx(-1.0, rel=1e-2)
    assert all(r.agrees for r in result.rows)
    assert [r.name for r in result.rows] == ["v", "g"]      # by |elasticity|


def test_an_articulated_rollout_gradient_matches_finite_differences():
    """The reach arm (two PD-driven links hanging in gravity) held at a constant action for
    1 s: the return's gradient with respect to gravity agrees with central differences, in
    float64."""
    env = reach.ReachEnv(reach.ReachSettings(), dtype=jnp.float64)
    params = env.default_params()
    names = ["reach.gravity[1]"]
    parsed = {n: sensitivity.parse_name(n, "reach", params) for n in names}
    act = lambda obs: jnp.full(env.action_size, 0.3, obs.dtype)
    outcome_of = sensitivity.rollout_outcome(env, params, parsed, act, "return", steps=30)
    result = sensitivity.study(outcome_of, sensitivity.start_values(params, parsed),
                               fd_step=1e-6, tolerance=1e-4)
    [row] = result.rows
    assert row.value == pytest.approx(-9.81, rel=1e-3)
    assert abs(row.gradient) > 1e-4 and row.agrees, row


def test_the_walk_s_tracking_error_gradient_matches_finite_differences(data_dir):
    """The DeepMimic walk's mean joint-angle error to its clip over 4 control steps (0.13 s,
    residual actions of zero: the clip's pose as the PD target) is the mean of the steps'
    `pose_error_degrees`, and its gradient against gravity agrees with central differences in
    float64; a task without a reference clip is refused the outcome. The tree passes run as
    scans, as `takeoff sensitivity` runs them (the same physics, compiled faster)."""
    env = imitation.ImitationEnv(imitation.ImitationSettings(), data_dir, dtype=jnp.float64)
    env.model = env.model.with_traversal(False)
    params = env.default_params()
    parsed = {"imitation.gravity[1]": sensitivity.parse_name("imitation.gravity[1]",
                                                             "imitation", params)}
    act = lambda obs: jnp.zeros(env.action_size, obs.dtype)
    outcome_of = sensitivity.rollout_outcome(env, params, parsed, act, "tracking_error",
                                             steps=4)
    result = sensitivity.study(outcome_of, sensitivity.start_values(params, parsed),
                               fd_step=1e-6, tolerance=1e-4)
    [row] = result.rows
    state, step, errors = env.reset(params, jax.random.PRNGKey(0)), jax.jit(env.step), []
    for _ in range(4):
        state = step(params, state, act(state.obs))
        errors.append(float(state.metrics["pose_error_degrees"]))
    assert result.outcome == pytest.approx(sum(errors) / 4, rel=1e-12)
    assert len(set(errors)) == 4 and min(errors) > 0
    assert abs(row.gradient) > 1e-5 and row.agrees, row
    arm = reach.ReachEnv(reach.ReachSettings(), dtype=jnp.float64)
    with pytest.raises(ValueError, match="follows a reference clip"):
        sensitivity.rollout_outcome(arm, arm.default_params(), {}, act, "tracking_error",
                                    steps=2)


def test_a_disagreement_is_flagged():
    """A function whose jax.grad is not its derivative (a straight-through step, like the
    clipped contact gradients) is flagged."""
    def outcome(values):
        x = values["x"]
        stepped = jnp.floor(x * 10) / 10
        return 1.0 + x + jax.lax.stop_gradient(stepped - x)      # value floor, gradient 1

    result = sensitivity.study(outcome, {"x": 0.55}, fd_step=1e-6)
    [row] = result.rows
    assert row.gradient == pytest.approx(1.0) and row.difference == pytest.approx(0.0, abs=1e-6)
    assert not row.agrees


@pytest.mark.parametrize("name, message", [
    ("gravity", "not of the form"),
    ("reach.gravity", "name one number"),
    ("reach.gravity[3]", "reach.gravity[0] to [2]"),
    ("reach.wind[0]", "the task 'reach' has the parameters reach.gravity"),
    ("physics.mass_scale", "takes no [physics] section"),
])
def test_parameter_names_are_checked(name, message):
    params = {"gravity": jnp.zeros(3)}
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace(".", r"\.")):
        sensitivity.parse_name(name, "reach", params)
