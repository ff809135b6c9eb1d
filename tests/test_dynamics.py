"""Dynamics checked against independent methods, in float64 (issue: jaxsim foundation)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import random_state
from jaxsim import builder, dynamics, kinematics, tree
from jaxsim.model import State

MODELS = ["humanoid", "quadruped", "snake10", "deepmimic_humanoid", "deepmimic_dog"]
DT = 1.0 / 600.0


def relative_error(a, b):
    return float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b)))


def with_random_gains(model, seed, root_gains):
    rng = np.random.default_rng(seed)
    kp = rng.uniform(0, 2000, model.nv)
    kd = rng.uniform(0, 200, model.nv)
    if not root_gains and model.topology.floating:
        kp[:6] = kd[:6] = 0.0
    return model.replace(kp=jnp.asarray(kp), kd=jnp.asarray(kd))


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("root_gains", [False, True], ids=["physics-root", "hand-of-god-root"])
def test_spd_solvers_agree(models, name, root_gains):
    """maba, sparse and dense solve thesis eq. 2.7 identically; all satisfy M q̈ + C = τ."""
    model = with_random_gains(models[name], 1, root_gains)
    q, qd, target = random_state(model, 2)
    f_ext = jnp.asarray(np.random.default_rng(3).normal(size=(model.n_links, 6)))
    results = {m: jax.jit(dynamics.solve_spd, static_argnames="method")(
        model, q, qd, target, DT, method=m, f_ext=f_ext) for m in ("dense", "sparse", "maba")}
    qdd_dense, tau_dense = results["dense"]
    for method in ("sparse", "maba"):
        qdd, tau = results[method]
        assert relative_error(qdd, qdd_dense) < 1e-9, method
        assert relative_error(tau, tau_dense) < 1e-9, method
    qdd, tau = results["maba"]
    # The returned torques are the ones that produce q̈ through the equations of motion
    # (inverse dynamics, computed without the SPD solve).
    assert relative_error(jax.jit(dynamics.rnea)(model, q, qd, qdd, f_ext), tau) < 1e-9


@pytest.mark.parametrize("method", ["sparse", "maba", "pd"])
def test_passive_dampers_are_solved_implicitly_by_every_method(models, method):
    """Joint-limit dampers −d (q̇ + Δt q̈) beside the motors: every SPD solver gives the same q̈
    (pd against its own equation), and M q̈ + C = τ + τ_extra − d (q̇ + Δt q̈) holds, checked by
    inverse dynamics without any solve."""
    model = with_random_gains(models["deepmimic_humanoid"], 6, root_gains=False)
    q, qd, target = random_state(model, 7)
    rng = np.random.default_rng(8)
    extra = jnp.asarray(rng.normal(scale=10.0, size=model.nv))
    damper = jnp.asarray(np.where(rng.uniform(size=model.nv) < 0.5, 50.0, 0.0))
    solve = jax.jit(dynamics.solve_spd, static_argnames="method")
    qdd, tau = solve(model, q, qd, target, DT, method=method, extra_torque=extra,
                     passive_damping=damper)
    applied = tau + extra - damper * (qd + DT * qdd)
    assert relative_error(jax.jit(dynamics.rnea)(model, q, qd, qdd), applied) < 1e-9
    if method != "pd":
        dense, _ = solve(model, q, qd, target, DT, method="dense", extra_torque=extra,
                         passive_damping=damper)
        assert relative_error(qdd, dense) < 1e-9
    # Without the damper the answer differs: the test sees it.
    undamped, _ = solve(model, q, qd, target, DT, method=method, extra_torque=extra)
    assert relative_error(undamped, qdd) > 1e-3


@pytest.mark.parametrize("name", MODELS)
def test_aba_matches_crba_rnea_and_inverts_rnea(models, name):
    model = models[name]
    q, qd, _ = random_state(model, 4)
    rng = np.random.default_rng(5)
    tau = jnp.asarray(rng.normal(scale=20.0, size=model.nv))
    f_ext = jnp.asarray(rng.normal(size=(model.n_links, 6)))
    qdd = jax.jit(dynamics.aba)(model, q, qd, tau, f_ext)
    mass = jax.jit(dynamics.mass_matrix)(model, q)
    bias = jax.jit(dynamics.bias_torques)(model, q, qd, f_ext)
    np.testing.assert_allclose(mass, mass.T, atol=1e-12)
    assert np.linalg.eigvalsh(mass).min() > 0
    assert relative_error(qdd, jnp.linalg.solve(mass, tau - bias)) < 1e-9
    assert relative_error(jax.jit(dynamics.rnea)(model, q, qd, qdd, f_ext), tau) < 1e-9
    # CRBA against RNEA column by column: H e_k = RNEA(q, 0, e_k) without gravity.
    columns = jax.jit(jax.vmap(lambda e: dynamics.rnea(model, q, jnp.zeros_like(qd), e,
                                               gravity=jnp.zeros(3))))(jnp.eye(model.nv))
    np.testing.assert_allclose(columns.T, mass, atol=1e-10 * float(jnp.abs(mass).max()))


def test_aba_stays_accurate_on_a_195_dof_chain():
    """Deep trees: the articulated inertia of eq. 2.24 in Joseph form keeps ABA's error at the
    level of M's conditioning (cond ≈ 2e8 here). The plain form Iᴬ − U D⁻¹ Uᵀ had relative errors
    growing about tenfold per link (O(1) at 22 links, 1e7 at 63); a block form of the move to the
    parent that rebuilt one off-diagonal block as the other's transpose reached only 3e-7."""
    from jaxsim import characters
    model = characters.snake(63, dtype=jnp.float64)
    q, qd, _ = random_state(model, 6, velocity_scale=0.2)
    tau = jnp.asarray(np.random.default_rng(7).normal(size=model.nv))
    qdd = jax.jit(dynamics.aba)(model, q, qd, tau)
    mass = jax.jit(dynamics.mass_matrix)(model, q)
    expected = jnp.linalg.solve(mass, tau - jax.jit(dynamics.bias_torques)(model, q, qd))
    assert relative_error(qdd, expected) < 1e-9
    # In float32 the same solve stays finite and close to the float64 answer.
    model32 = characters.snake(63, dtype=jnp.float32)
    qdd32 = jax.jit(dynamics.aba)(model32, *(x.astype(jnp.float32) for x in (q, qd, tau)))
    assert relative_error(qdd32.astype(jnp.float64), expected) < 1e-3


@pytest.mark.parametrize("name", ["deepmimic_humanoid", "deepmimic_dog"])
def test_unrolled_and_scanned_tree_traversals_agree(models, name):
    """`jaxsim.tree` walks shallow trees level by level in straight-line code, or by a scan over
    a padded level table on request (`Model.with_traversal`); both give the same kinematics,
    ABA, MABA and RNEA."""
    model = with_random_gains(models[name], 8, root_gains=True)
    q, qd, target = random_state(model, 7)
    rng = np.random.default_rng(9)
    tau = jnp.asarray(rng.normal(scale=20.0, size=model.nv))
    f_ext = jnp.asarray(rng.normal(size=(model.n_links, 6)))

    @jax.jit
    def everything(m):
        return (kinematics.link_velocities(m, q, qd), dynamics.aba(m, q, qd, tau, f_ext),
                dynamics.solve_spd(m, q, qd, target, DT, method="maba", f_ext=f_ext),
                dynamics.rnea(m, q, qd, tau, f_ext))

    results = {}
    for unrolled in (False, True):
        walked = model.with_traversal(unrolled)
        assert tree.unrolled(walked.topology) == unrolled
        results[unrolled] = everything(walked)
    for scanned, straight in zip(*(jax.tree.leaves(r) for r in results.values())):
        assert relative_error(straight, scanned) < 1e-12


@pytest.mark.parametrize("name", ["humanoid", "quadruped", "snake10"])
def test_momentum_is_conserved_without_gravity_or_torques(models, name):
    """Zero gravity, zero torques: d/dt of the total spatial momentum, computed from ABA's q̈
    through the kinematics alone (a jvp of the momentum along q̇, q̈), is zero."""
    model = models[name]
    q, qd, _ = random_state(model, 6, velocity_scale=2.0)
    qdd = jax.jit(dynamics.aba)(model, q, qd, jnp.zeros_like(qd), gravity=jnp.zeros(3))
    qdot = kinematics.qd_to_qdot(model, q, qd)
    momentum_and_rate = jax.jit(lambda x, v, x_dot, v_dot: jax.jvp(
        lambda x_, v_: kinematics.spatial_momentum(model, x_, v_), (x, v), (x_dot, v_dot)))
    momentum, rate = momentum_and_rate(q, qd, qdot, qdd)
    assert float(jnp.abs(momentum).max()) > 1.0          # the test is not vacuous
    assert float(jnp.abs(rate).max()) < 1e-9 * float(jnp.abs(qdd).max()) * model.nv


def pendulum(mass=2.0, length=0.7, radius=0.05, axis=(0.0, 0.0, 1.0)):
    """A fixed base with a revolute link whose sphere bob hangs `length` below the joint."""
    links = [
        builder.LinkSpec(name="base", parent=None, joint="fixed", mass=1.0, shape="box",
                         shape_size=(0.05, 0.05, 0.05), joint_pos=(0.0, 2.0, 0.0)),
        builder.LinkSpec(name="arm", parent="base", joint="revolute", axis=axis, mass=mass,
                         shape="sphere", shape_pos=(0.0, -length, 0.0),
                         shape_size=(radius, 0, 0)),
    ]
    return builder.build_model(links, source="pendulum", dtype=jnp.float64)


def test_fixed_base_pendulum_matches_analytic_equation():
    m, l, r = 2.0, 0.7, 0.05
    model = pendulum(m, l, r)
    inertia_about_pivot = 0.4 * m * r * r + m * l * l
    for theta, theta_dot, torque in [(0.3, 0.0, 0.0), (-1.2, 2.0, 0.5), (2.5, -1.0, -3.0)]:
        q, qd = jnp.array([theta]), jnp.array([theta_dot])
        qdd = jax.jit(dynamics.aba)(model, q, qd, jnp.array([torque]))
        expected = (torque - m * 9.81 * l * np.sin(theta)) / inertia_about_pivot
        np.testing.assert_allclose(qdd[0], expected, rtol=1e-12)
        mass = jax.jit(dynamics.mass_matrix)(model, q)
        np.testing.assert_allclose(mass[0, 0], inertia_about_pivot, rtol=1e-12)


def test_pendulum_spd_is_stable_where_pd_explodes():
    """SPD keeps a stiff pendulum stable at a large time step (DeepMimic's gain ratio
    kd = kp / 10); explicit PD at the same gains and step diverges (thesis §2.2)."""
    model = pendulum().replace(kp=jnp.array([5e4]), kd=jnp.array([5e3]))
    target, dt = jnp.array([0.5]), 1.0 / 60.0

    def simulate(method):
        def step(state, _):
            qdd, _ = dynamics.solve_spd(model, state.q, state.qd, target, dt, method)
            qd = state.qd + dt * qdd
            return State(state.q + dt * qd, qd), None
        final, _ = jax.lax.scan(step, State(jnp.array([0.0]), jnp.array([0.0])), None, 120)
        return final

    spd, pd = simulate("maba"), simulate("pd")
    assert abs(float(spd.q[0]) - 0.5) < 0.01
    assert not (abs(float(pd.q[0])) < 10.0)


def central_difference(fn, x, eps=1e-6):
    flat = np.asarray(x, float).ravel()
    grads = []
    for k in range(flat.size):
        up, down = flat.copy(), flat.copy()
        up[k] += eps
        down[k] -= eps
        grads.append((fn(jnp.asarray(up.reshape(np.shape(x))))
                      - fn(jnp.asarray(down.reshape(np.shape(x))))) / (2 * eps))
    return np.array(grads).reshape(np.shape(x))


@pytest.mark.parametrize("method", ["aba", "maba"])
def test_gradients_match_finite_differences(models, method):
    model = with_random_gains(models["humanoid"], 7, root_gains=False)
    q, qd, target = random_state(model, 8)
    tau = jnp.asarray(np.random.default_rng(9).normal(scale=10.0, size=model.nv))
    weights = jnp.asarray(np.random.default_rng(10).normal(size=model.nv))

    def loss(mass, joint_pos, qd_):
        m = model.replace(mass=mass, joint_pos=joint_pos)
        if method == "aba":
            qdd = dynamics.aba(m, q, qd_, tau)
        else:
            qdd, _ = dynamics.solve_spd(m, q, qd_, target, DT, "maba")
        return jnp.sum(weights * qdd)

    loss_jit = jax.jit(loss)
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(model.mass, model.joint_pos, qd)
    fd_mass = central_difference(lambda x: loss_jit(x, model.joint_pos, qd), model.mass)
    fd_pos = central_difference(
        lambda x: loss_jit(model.mass, model.joint_pos.at[:4].set(x), qd), model.joint_pos[:4])
    fd_qd = central_difference(lambda x: loss_jit(model.mass, model.joint_pos, x), qd)
    for analytic, numeric in [(grads[0], fd_mass), (grads[1][:4], fd_pos), (grads[2], fd_qd)]:
        scale = max(float(np.abs(numeric).max()), 1.0)
        np.testing.assert_allclose(analytic, numeric, atol=1e-5 * scale)


def test_unknown_method_is_rejected(models):
    model = models["humanoid"]
    q, qd, target = random_state(model, 0)
    with pytest.raises(ValueError, match="unknown SPD method 'cholesky'"):
        dynamics.solve_spd(model, q, qd, target, DT, "cholesky")


@pytest.mark.parametrize("argument", ["tau", "passive_damping"])
def test_solve_applied_rejects_wrong_lengths(models, argument):
    model = models["humanoid"]
    q, qd, _ = random_state(model, 0)
    arrays = {"tau": jnp.zeros(model.nv), "passive_damping": jnp.ones(model.nv)}
    arrays[argument] = arrays[argument][:-1]
    with pytest.raises(ValueError, match=rf"{argument}: expected shape \({model.nv},\)"):
        dynamics.solve_applied(model, q, qd, arrays["tau"], DT,
                               passive_damping=arrays["passive_damping"])
