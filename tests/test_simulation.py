"""The simulation step: contacts, friction, joint and torque limits, integration, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import (LinkSpec, build_model, characters, contact, kinematics, limits, rest_pose,
                    rotations, simulation)
from jaxsim.dynamics import aba, solve_spd
from jaxsim.simulation import SimulationError, init_state, is_finite, simulate, step
from jaxsim.tracking import tracking_model
from jaxsim.world import MARS_GRAVITY, Box, make_world

DT = 1 / 600


def world(**kwargs):
    return make_world(dtype=jnp.float64, **kwargs)


def assert_names(message, *parts):
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"


def single_body(shape, size, mass=5.0):
    # Contacts are explicit: a light box (1 kg for 20×10×40 cm) has corner contacts too stiff for
    # 600 Hz at the default stiffness, so the free bodies here have a wood-like density.
    link = LinkSpec("body", None, "free", mass=mass, shape=shape, shape_size=size)
    return build_model([link], dtype=jnp.float64)


def run(model, w, q, steps, qd=None, target=None, method="maba"):
    state = init_state(model, w, q, qd)
    target = q if target is None else target
    return simulate(model, w, state, jnp.tile(target, (steps, 1)), DT, method)


def test_humanoid_stands_for_five_seconds_in_its_rest_pose():
    # DeepMimic's own gains are too weak to hold the rest pose passively (the body leans and
    # falls within 3 s); the thesis's tracking gains hold it. The root is not actuated.
    model = tracking_model(characters.humanoid().astype(jnp.float64), root_gains=(0.0, 0.0))
    w = world()
    low, _ = characters.vertical_extent(model)
    q0 = rest_pose(model, -low)
    final, traj = run(model, w, q0, 5 * 600)
    assert bool(jnp.all(jnp.isfinite(traj.q)))
    rot, pos = jax.vmap(lambda q: kinematics.forward_kinematics(model, q))(traj.q)
    _, _, gaps = jax.vmap(lambda r, p: contact.contact_geometry(model, w, r, p))(rot, pos)
    assert -float(gaps.min()) < 0.01                             # feet penetration < 1 cm
    drift = np.linalg.norm(np.asarray(pos[:, 0, [0, 2]] - pos[0, 0, [0, 2]]), axis=-1)
    assert drift.max() < 0.02                                    # horizontal drift < 2 cm
    assert float(traj.q[-1, 1]) > 0.85                            # still standing
    feet = [model.topology.link_index(n) for n in ("right_ankle", "left_ankle")]
    touching = np.asarray(final.touching[:, 0])
    assert touching[feet].all() and touching.sum() == 2          # only the feet touch the ground


@pytest.mark.parametrize("shape,size", [("sphere", (0.1, 0, 0)), ("box", (0.1, 0.05, 0.2)),
                                        ("capsule", (0.05, 0.2, 0))])
def test_dropped_body_comes_to_rest_on_the_ground(shape, size):
    model = single_body(shape, size)
    tilt = jnp.array([0.995, 0.07, 0.0, 0.07])
    q0 = rest_pose(model, 0.6).at[3:7].set(tilt / jnp.linalg.norm(tilt))
    final, traj = run(model, world(), q0, 2 * 600)
    assert float(jnp.max(jnp.abs(final.qd))) < 1e-2
    lowest = characters.vertical_extent(model, final.q)[0]
    assert -0.005 < lowest < 0.0                   # resting a few millimetres into the ground
    assert float(traj.q[:, 1].min()) > -0.01       # never fell through


@pytest.mark.parametrize("slope_deg,should_slide", [(20.0, False), (35.0, True)])
def test_box_on_an_incline_sticks_below_the_friction_angle_and_slides_above(slope_deg,
                                                                           should_slide):
    # μ = 0.5: friction angle atan(0.5) = 26.6°.
    slope = np.radians(slope_deg)
    normal = (-np.sin(slope), np.cos(slope), 0.0)                   # rises towards −X
    model = single_body("box", (0.1, 0.05, 0.1))
    rotation = jnp.array([np.cos(slope / 2), 0.0, 0.0, np.sin(slope / 2)])  # box lies on it
    q0 = rest_pose(model).at[0:3].set(0.0495 * np.array(normal)).at[3:7].set(rotation)
    final, _ = run(model, world(ground_normal=normal, friction=0.5), q0, 600)
    moved = float(jnp.linalg.norm(final.q[:3] - q0[:3]))
    if should_slide:
        expected = 0.5 * 9.81 * (np.sin(slope) - 0.5 * np.cos(slope))   # ½ a t², t = 1 s
        assert moved == pytest.approx(expected, rel=0.1)
    else:
        assert moved < 1e-3


def test_a_body_swung_into_a_static_box_touches_it():
    arm = LinkSpec("base", None, "fixed", mass=1.0, shape="sphere", shape_size=(0.05, 0, 0),
                   joint_pos=(0.0, 1.0, 0.0))
    swing = LinkSpec("arm", "base", "revolute", mass=1.0, shape="capsule",
                     shape_pos=(0.0, -0.3, 0.0), shape_size=(0.04, 0.25, 0.0), axis=(0, 0, 1))
    model = build_model([arm, swing], dtype=jnp.float64)
    bar = Box("bar", center=(0.35, 0.55, 0.0), half_size=(0.05, 0.05, 0.5))
    w = world(ground=False, boxes=[bar])
    q0 = jnp.array([-1.2])                                  # raised to the left, falls right
    final, traj = run(model, w, q0, 600)
    hit = np.asarray(traj.touching[:, 1, w.object_index("bar")])
    assert hit.any() and not np.asarray(traj.touching[:, 0]).any()
    angle = np.asarray(traj.q[:, 0])
    assert angle.max() < 0.7                               # stopped by the bar, not through it
    assert w.object_names == ("ground", "bar")


def test_free_floating_character_keeps_its_momentum_without_gravity():
    # Internal SPD torques cannot change the total momentum; what changes it is the first-order
    # time discretisation, so the drift must be small and halve when the step halves.
    model = characters.humanoid().astype(jnp.float64)
    w = world(gravity=(0.0, 0.0, 0.0), ground=False, joint_limits=False)
    rng = np.random.default_rng(0)
    q0 = rest_pose(model, 1.0)
    qd0 = jnp.asarray(rng.normal(scale=0.5, size=model.nv))
    target = q0.at[7:11].set(jnp.array([0.9, 0.3, 0.2, 0.2]) / np.sqrt(0.98))
    h0 = kinematics.spatial_momentum(model, q0, qd0)

    def drift(dt):
        state = init_state(model, w, q0, qd0)
        final, _ = simulate(model, w, state, jnp.tile(target, (int(round(0.5 / dt)), 1)), dt)
        return np.abs(np.asarray(kinematics.spatial_momentum(model, final.q, final.qd) - h0))

    coarse, fine = drift(1 / 600), drift(1 / 1200)
    scale = float(jnp.linalg.norm(h0))
    assert coarse.max() < 1e-2 * scale
    assert fine.max() == pytest.approx(coarse.max() / 2, rel=0.2)


def _hinge(limit_upper):
    link = LinkSpec("base", None, "fixed", mass=1.0, shape="sphere", shape_size=(0.05, 0, 0))
    arm = LinkSpec("arm", "base", "revolute", mass=1.0, shape="capsule", axis=(0, 0, 1),
                   shape_pos=(0.0, -0.3, 0.0), shape_size=(0.04, 0.25, 0.0), kp=50.0, kd=5.0,
                   q_lower=-limit_upper, q_upper=limit_upper, torque_limit=2.0)
    return build_model([link, arm], dtype=jnp.float64)


def test_joint_limit_holds_a_joint_pushed_past_it():
    model = _hinge(0.5)
    target = jnp.array([1.5])
    free, _ = run(model, world(gravity=(0, 0, 0), ground=False, joint_limits=False),
                  jnp.array([0.0]), 600, target=target)
    held, traj = run(model, world(gravity=(0, 0, 0), ground=False), jnp.array([0.0]), 600,
                     target=target)
    assert float(free.q[0]) == pytest.approx(1.5, abs=1e-3)
    assert float(traj.q[:, 0].max()) < 0.5 + 0.05
    assert float(held.q[0]) > 0.5


def test_limit_damper_on_a_light_link_decays_where_an_explicit_one_would_diverge():
    """A foot-sized link (1 kg, 5 cm from its hinge) moving out of its limit with only the
    damper acting (no spring, no motor gains, no gravity): d Δt / I ≈ 29, far past an explicit
    damper's stability bound of 2 (at the neck, such runaways blew up high-jump episodes). The
    implicit damper gives q̇ ← q̇ / (1 + d Δt / I) each step, analytically; with a motor pushing
    into the limit past its torque limit (the step re-solved with the clipped torque) the
    speed stays bounded."""
    link = LinkSpec("base", None, "fixed", mass=1.0, shape="sphere", shape_size=(0.05, 0, 0))
    tip = LinkSpec("tip", "base", "revolute", mass=1.0, shape="sphere", axis=(0, 0, 1),
                   shape_pos=(0.0, -0.05, 0.0), shape_size=(0.03, 0, 0), kp=0.0, kd=0.0,
                   q_lower=-0.1, q_upper=0.1, torque_limit=1.0)
    model = build_model([link, tip], dtype=jnp.float64)
    inertia = 1.0 * (0.05**2 + 0.4 * 0.03**2)           # offset (parallel axis) + solid sphere
    w = world(gravity=(0, 0, 0), ground=False, limit_stiffness=0.0, limit_damping=50.0)
    ratio = 50.0 * DT / inertia
    assert 20 < ratio < 40
    for torque_limits, kp in ((False, 0.0), (True, 1e4)):   # kp: a motor pushing into the limit
        m = model.replace(kp=jnp.array([kp]))
        wl = w.replace(torque_limits=torque_limits)
        state = init_state(m, wl, jnp.array([0.2]), jnp.array([1.0]))
        if not torque_limits:
            after = step(m, wl, state, jnp.array([0.2 + 0.1]), DT)
            assert float(after.qd[0]) == pytest.approx(1.0 / (1.0 + ratio), rel=1e-9)
        _, traj = run(m, wl, state.q, 600, qd=state.qd, target=jnp.array([0.5]))
        speeds = np.abs(np.asarray(traj.qd[:, 0]))
        assert np.all(np.isfinite(speeds)) and speeds.max() <= 1.0 + 1e-9


def test_spherical_limit_springs_are_continuous_where_the_rotation_vector_flips():
    """A shoulder-like ball joint, limits up to 3.14 rad on two axes, turned through π about an
    axis: its shortest-arc rotation vector flips to the antipode there, which alone would take
    the x and z components outside [−0.5, 3.14] and [−0.7, 3.14] at once (thousands of N·m in
    one step). The limit springs, on the nearer of the two vectors, barely change."""
    base = LinkSpec("base", None, "fixed", mass=1.0, shape="sphere", shape_size=(0.05, 0, 0))
    arm = LinkSpec("arm", "base", "spherical", mass=2.0, shape="capsule",
                   shape_pos=(0.0, -0.15, 0.0), shape_size=(0.04, 0.22, 0.0),
                   q_lower=(-0.5, -1.5, -0.7), q_upper=(3.14, 1.5, 3.14))
    model = build_model([base, arm], dtype=jnp.float64)
    w = world(ground=False)
    axis = jnp.array([0.6, -0.08, 0.8]) / np.linalg.norm([0.6, -0.08, 0.8])
    springs, shortest = [], []
    for angle in (np.pi - 0.01, np.pi + 0.01):
        q = rotations.axis_angle_to_quat(axis, jnp.asarray(angle))
        springs.append(np.asarray(limits.joint_limit_forces(model, w, q, jnp.zeros(3))[0]))
        shortest.append(np.asarray(rotations.quat_to_rotvec(q)))
    assert np.max(np.abs(springs[1] - springs[0])) < 0.05 * 2000.0
    # At rest the choice of vector has a finite gradient (no 0 · ∞ from the angle's norm).
    grad = jax.grad(lambda q: jnp.sum(limits.joint_limit_forces(model, w, q, jnp.zeros(3))[0]))
    assert np.all(np.isfinite(np.asarray(grad(jnp.array([1.0, 0.0, 0.0, 0.0])))))
    # The shortest-arc vectors themselves jump across the x and z limits.
    assert shortest[0][0] > 0 > -0.5 > shortest[1][0]
    assert shortest[0][2] > 0 > -0.7 > shortest[1][2]


def test_torque_limits_clip_and_resolve():
    model = _hinge(np.inf)
    w = world(ground=False, joint_limits=False, torque_limits=True)
    q, qd, target = jnp.array([0.3]), jnp.array([0.0]), jnp.array([1.5])
    state = init_state(model, w, q, qd)
    limited = step(model, w, state, target, DT)
    qdd = (limited.qd - qd) / DT
    expected = aba(model, q, qd, jnp.array([2.0]), gravity=w.gravity)   # clipped to the limit
    np.testing.assert_allclose(qdd, expected, rtol=1e-10)
    unlimited = step(model, w.replace(torque_limits=False), state, target, DT)
    assert float(unlimited.qd[0]) > float(limited.qd[0])
    # Below the limit the re-solve is not used: the result is the plain SPD step.
    gentle = step(model, w, state, jnp.array([0.31]), DT)
    np.testing.assert_allclose(gentle.qd, step(model, w.replace(torque_limits=False), state,
                                               jnp.array([0.31]), DT).qd, rtol=1e-12)


def test_gravity_is_a_parameter_mars_and_earth_in_one_call():
    model = single_body("sphere", (0.1, 0, 0))
    earth, mars = world(ground=False), world(ground=False, gravity=MARS_GRAVITY)
    worlds = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), earth, mars)
    q0 = rest_pose(model, 10.0)

    def fall(w):
        return run(model, w, q0, 600)[0].q[1]

    heights = jax.vmap(fall)(worlds)
    t = 1.0
    np.testing.assert_allclose(10.0 - np.asarray(heights), [0.5 * 9.81 * t**2,
                                                            0.5 * 3.711 * t**2], rtol=5e-3)


def test_gradient_of_a_contact_free_rollout_matches_finite_differences():
    model = characters.humanoid().astype(jnp.float64)
    w = world(ground=False)
    q0 = rest_pose(model, 1.0)

    def final_height(vy):
        qd0 = jnp.zeros(model.nv).at[4].set(vy).at[8].set(0.5)
        state = init_state(model, w, q0, qd0)
        final, _ = simulate(model, w, state, jnp.tile(q0, (60, 1)), DT)
        return final.q[1]

    grad = jax.grad(final_height)(1.0)
    h = 1e-5
    fd = (final_height(1.0 + h) - final_height(1.0 - h)) / (2 * h)
    assert float(grad) == pytest.approx(float(fd), rel=1e-6)
    assert float(grad) == pytest.approx(0.1, rel=0.05)     # ≈ t = 60 steps of 1/600 s


def test_gradients_through_contact_are_finite():
    model = single_body("box", (0.1, 0.05, 0.2))
    w = world(boxes=[Box("step", (0.0, 0.0, 0.5), (0.5, 0.1, 0.1))])

    def final_x(height, push):
        q0 = rest_pose(model).at[1].set(height)
        q0 = q0.at[3:7].set(jnp.array([0.99, 0.1, 0.0, 0.1]) / np.sqrt(0.9998))
        qd0 = jnp.zeros(6).at[3].set(push).at[5].set(push)
        state = init_state(model, w, q0, qd0)
        final, _ = simulate(model, w, state, jnp.tile(q0, (240, 1)), DT)
        return final.q[0] + final.q[1] + final.q[2]

    grads = jax.grad(final_x, argnums=(0, 1))(0.2, 1.0)
    assert all(np.isfinite(float(g)) for g in grads)
    assert float(grads[1]) != 0.0


def test_dense_sparse_and_maba_steps_agree_with_contacts():
    model = characters.humanoid().astype(jnp.float64)
    w = world(torque_limits=True)
    low, _ = characters.vertical_extent(model)
    q0 = rest_pose(model, -low - 0.003)
    state = init_state(model, w, q0, jnp.linspace(-0.5, 0.5, model.nv))
    target = q0.at[7:11].set(jnp.array([0.9, 0.3, 0.2, 0.2]) / np.sqrt(0.98))
    results = {m: step(model, w, state, target, DT, m) for m in ("dense", "sparse", "maba")}
    for method in ("dense", "sparse"):
        np.testing.assert_allclose(results[method].qd, results["maba"].qd, rtol=1e-8,
                                   atol=1e-8)
    assert bool(results["maba"].touching[:, 0].any())


def test_a_non_finite_state_is_reported_with_its_joint():
    model = characters.humanoid().astype(jnp.float64)
    w = world(ground=False)
    q0 = rest_pose(model, 1.0)
    bad = init_state(model, w, q0).replace(qd=jnp.zeros(model.nv).at[15].set(jnp.nan))
    with pytest.raises(SimulationError, match=r"qd\[15\] \(joints right_knee\)"):
        step(model, w, bad, q0, DT)
    stepped = jax.jit(lambda s: step(model, w, s, q0, DT))(bad)
    assert not bool(is_finite(stepped))
    assert bool(is_finite(jax.jit(lambda s: step(model, w, s, q0, DT))(init_state(model, w, q0))))


def test_a_state_without_contact_memory_is_refused():
    model = single_body("sphere", (0.1, 0, 0))
    q0 = rest_pose(model, 1.0)
    from jaxsim.model import State
    with pytest.raises(SimulationError, match="init_state"):
        step(model, world(), State(q0, jnp.zeros(6)), q0, DT)


@pytest.mark.parametrize("kwargs,message", [
    (dict(ground_normal=(0, 0, 0)), "ground_normal"),
    (dict(friction=-1.0), "friction"),
    (dict(tangent_stiffness=0.0), "tangent_stiffness"),
    (dict(boxes=[Box("bar", (0, 1, 0), (0.1, -0.1, 0.1))]), "box 'bar': half_size"),
    (dict(boxes=[Box("ground", (0, 1, 0), (0.1, 0.1, 0.1))]), "unique"),
    (dict(gravity=(0, -9.81)), "gravity"),
    (dict(boxes=[Box("mat", (0, 0, 0), (1, 0.1, 1), np.diag([1.0, -1.0, 1.0]))]),
     "box 'mat': rotation"),
])
def test_bad_world_parameters_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        world(**kwargs)


@pytest.fixture(scope="module")
def humanoid_at_rest():
    model = characters.humanoid().astype(jnp.float64)
    w = world(ground=False)
    q0 = rest_pose(model, 1.0)
    return model, w, q0, init_state(model, w, q0)


def test_a_raw_deepmimic_frame_is_not_taken_for_a_pose(humanoid_at_rest):
    """A DeepMimic motion frame is [dt, pose (43)]: passed whole, it would shift every joint."""
    model, w, q0, _ = humanoid_at_rest
    frame = jnp.concatenate([jnp.array([1 / 30]), q0])
    with pytest.raises(ValueError, match=r"\bq\b.*nq = 43.*\(44,\)"):
        init_state(model, w, frame)


@pytest.mark.parametrize("call, argument, size, shape", [
    (lambda m, w, q, s: init_state(m, w, q, jnp.zeros(35)), "qd", "nv = 34", "(35,)"),
    (lambda m, w, q, s: step(m, w, s, q[:-1], DT), "target", "nq = 43", "(42,)"),
    (lambda m, w, q, s: step(m, w, s, q, DT, target_velocity=jnp.zeros(43)),
     "target_velocity", "nv = 34", "(43,)"),
    (lambda m, w, q, s: step(m, w, s.replace(q=q[None]), q, DT), "state.q", "nq = 43",
     "(1, 43)"),
    (lambda m, w, q, s: step(m, w, s.replace(qd=jnp.zeros(43)), q, DT), "state.qd", "nv = 34",
     "(43,)"),
    (lambda m, w, q, s: simulate(m, w, s, jnp.tile(q, (3, 1))[:, 1:], DT), "targets",
     "nq = 43", "(3, 42)"),
    (lambda m, w, q, s: simulate(m, w, s, jnp.tile(q, (3, 1)), DT,
                                 target_velocities=jnp.zeros((3, 43))),
     "target_velocities", "nv = 34", "(3, 43)"),
    (lambda m, w, q, s: solve_spd(m, q, jnp.zeros(34), jnp.append(q, 0.0), DT), "target",
     "nq = 43", "(44,)"),
    (lambda m, w, q, s: solve_spd(m, q, jnp.zeros(33), q, DT), "qd", "nv = 34", "(33,)"),
])
def test_arrays_of_the_wrong_length_are_named(humanoid_at_rest, call, argument, size, shape):
    model, w, q0, state = humanoid_at_rest
    with pytest.raises(ValueError) as info:
        call(model, w, q0, state)
    assert_names(str(info.value), argument, size, shape)


def test_tracking_gains_cover_the_root_and_the_joints():
    model = tracking_model(characters.humanoid())
    np.testing.assert_array_equal(np.asarray(model.kp[:6]), 20000.0)
    np.testing.assert_array_equal(np.asarray(model.kd[6:]), 4000.0)


def test_simulate_batch_equals_one_character_at_a_time():
    model = single_body("sphere", (0.1, 0, 0))
    w = world()
    heights = [0.3, 0.5]
    states = [init_state(model, w, rest_pose(model, h)) for h in heights]
    targets = jnp.tile(rest_pose(model, 0.3), (2, 120, 1))
    batched = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    final, traj = simulation.simulate_batch(model, w, batched, targets, DT, substeps=2)
    for k, state in enumerate(states):
        alone, _ = simulate(model, w, state, targets[k], DT, substeps=2)
        np.testing.assert_allclose(final.q[k], alone.q, rtol=1e-12, atol=1e-12)
    assert traj.q.shape == (2, 120, model.nq)


STEPS = 6


@pytest.fixture(scope="module")
def chain():
    """Two hinges in a row (nq = nv = 2) with nothing to touch: the cheapest rollout."""
    base = LinkSpec("base", None, "fixed", mass=1.0, shape="sphere", shape_size=(0.05, 0, 0))
    arm = dict(mass=1.0, shape="capsule", axis=(0, 0, 1), shape_pos=(0.0, -0.2, 0.0),
               shape_size=(0.04, 0.15, 0.0), kp=50.0, kd=5.0)
    model = build_model([base, LinkSpec("shoulder", "base", "revolute", **arm),
                         LinkSpec("elbow", "shoulder", "revolute", joint_pos=(0, -0.4, 0), **arm)],
                        dtype=jnp.float64)
    w = world(ground=False)
    q0 = jnp.array([0.3, -0.2])
    return model, w, init_state(model, w, q0), jnp.tile(q0, (STEPS, 1))


def stacked(*states):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)


def test_init_state_refuses_a_non_finite_pose_or_velocity(chain):
    model, w, _, targets = chain
    with pytest.raises(SimulationError, match=r"init_state: .*\bq\[1\] \(joints elbow\)"):
        init_state(model, w, jnp.array([0.0, jnp.nan]))
    with pytest.raises(SimulationError, match=r"init_state: .*qd\[0\] \(joints shoulder\)"):
        init_state(model, w, targets[0], np.array([np.inf, 0.0]))


def test_simulate_names_non_finite_inputs_and_leaves_traced_ones_to_the_flag(chain):
    model, w, state, targets = chain
    bad_state = state.replace(qd=state.qd.at[1].set(jnp.nan))
    with pytest.raises(SimulationError, match=r"qd\[1\] \(joints elbow\)"):
        simulate(model, w, bad_state, targets, DT)
    with pytest.raises(SimulationError,
                       match=r"targets: .*\bq\[1\] \(joints elbow\) at control steps 2, 4$"):
        simulate(model, w, state, targets.at[2, 1].set(jnp.nan).at[4, 1].set(jnp.inf), DT)
    velocities = jnp.zeros((STEPS, 2)).at[0, 0].set(jnp.nan)
    with pytest.raises(SimulationError, match=r"target_velocities: .*qd\[0\] \(joints "
                                              r"shoulder\) at control step 0$"):
        simulate(model, w, state, targets, DT, target_velocities=velocities)
    with pytest.raises(SimulationError, match=r"target: .*\bq\[1\] \(joints elbow\)"):
        step(model, w, state, targets[0].at[1].set(jnp.nan), DT)
    # Inside jit nothing is concrete: no check, and the flag tells.
    traced = jax.jit(lambda s: simulation.first_non_finite(simulate(model, w, s, targets, DT)[1]))
    assert int(traced(bad_state)) == 0 and int(traced(state)) == -1


def test_simulate_batch_names_the_members_with_non_finite_inputs(chain):
    model, w, state, targets = chain
    states = stacked(state, state.replace(q=state.q.at[0].set(jnp.nan)), state)
    with pytest.raises(SimulationError,
                       match=r"states: .*\bq\[0\] \(joints shoulder\) in batch member 1$"):
        simulation.simulate_batch(model, w, states, targets, DT)
    per_member = jnp.stack([targets, targets, targets.at[3, 1].set(jnp.nan)])
    with pytest.raises(SimulationError, match=r"targets: .*\bq\[1\] \(joints elbow\) in batch "
                                              r"member 2 at control step 3$"):
        simulation.simulate_batch(model, w, stacked(state, state, state), per_member, DT)


@pytest.mark.parametrize("dt", [-1.0, 0.0, float("nan"), float("inf"), "fast"])
def test_every_entry_point_refuses_a_time_step_that_is_not_a_positive_number(chain, dt):
    model, w, state, targets = chain
    calls = (lambda: step(model, w, state, targets[0], dt),
             lambda: simulate(model, w, state, targets, dt),
             lambda: simulation.simulate_batch(model, w, stacked(state, state), targets, dt))
    for call in calls:
        with pytest.raises(SimulationError, match=f"dt must be a finite number > 0.*got '?{dt}"):
            call()


def test_a_rollout_that_turns_non_finite_says_when_and_where(chain):
    model, w, state, targets = chain
    # Finite inputs, but the SPD torque towards a target of 1e308 overflows at control step 3,
    # which ends at t = 4 · 2 · DT.
    blown = targets.at[3, 1].set(1e308)
    with pytest.raises(SimulationError, match=r"non-finite at control step 3 \(t = 0\.0133333 s\)"
                                              r".*\(joints [a-z, ]*elbow"):
        simulate(model, w, state, blown, DT, substeps=2)
    per_member = jnp.stack([targets, targets.at[5, 0].set(1e308), blown])
    with pytest.raises(SimulationError, match=r"non-finite at control step 3 .* in batch member 2 "
                                              r".*in all, batch members 1, 2 turn non-finite"):
        simulation.simulate_batch(model, w, stacked(state, state, state), per_member, DT,
                                  substeps=2)
    # Inside jit the flag says the same.
    flag = jax.jit(lambda t: simulation.first_non_finite(
        simulate(model, w, state, t, DT, substeps=2)[1]))
    assert int(flag(blown)) == 3 and int(flag(targets)) == -1
    q = np.zeros((3, STEPS, 2))
    q[1, 5:, 0], q[2, 3:, 1] = np.nan, np.inf
    trajectory = init_state(model, w, targets[0]).replace(q=q, qd=np.zeros((3, STEPS, 2)))
    np.testing.assert_array_equal(jax.jit(simulation.first_non_finite)(trajectory), [-1, 5, 3])
