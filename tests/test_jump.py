"""The jump tasks (thesis §3.6): take-off states, the rules and the reward on scripted states,
the crossing feature on a scripted flight, the curriculum and its schedules, the variations, and
settings that give errors naming their key. Float64 (conftest)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.commands import train_commands
from agents.config import ConfigError
from agents.rl import curriculum as curriculum_lib
from agents.rl import trainer as trainer_lib
from agents.rl.env import end_of_step, start_of_episode
from agents.rl.ppo import PPOSettings
from agents.tasks import jump, takeoff_state
from jaxsim import kinematics, motion, rotations, simulation
from jaxsim.model import rest_pose


@pytest.fixture(scope="module")
def highjump(data_dir):
    return jump.JumpEnv(jump.HighJumpSettings(actions="pd"), data_dir, dtype=jnp.float64)


@pytest.fixture(scope="module")
def obstacle(data_dir):
    return jump.JumpEnv(jump.ObstacleSettings(actions="pd"), data_dir, dtype=jnp.float64)


@pytest.fixture(scope="module")
def high_step(highjump):
    return jax.jit(highjump.step)


# ------------------------------------------------------------------------- take-off states

@pytest.mark.parametrize("kind", ["highjump", "obstacle"])
def test_the_takeoff_state_has_x_s_root_velocities_in_the_facing_frame_and_the_clip_s_pose(
        kind, highjump, obstacle):
    env = highjump if kind == "highjump" else obstacle
    rows = takeoff_state.HIGHJUMP_ROWS if kind == "highjump" else takeoff_state.OBSTACLE_ROWS
    clip_q, clip_qd = takeoff_state.clip_state(env.model, _clip(env), env.takeoff.time)
    foot = env.model.topology.link_index(env.takeoff.foot)
    leg = takeoff_state.leg_dofs(env.model, foot)
    others = np.setdiff1d(np.arange(6, env.model.nv), leg)
    for x in rows.values():
        params = {**env.default_params(), "takeoff": jnp.asarray(x)}
        state = env.reset(params, jax.random.PRNGKey(0))
        q, qd = state.physics.q, state.physics.qd
        # The clip's pose, put down on the take-off foot: only the root's height differs.
        np.testing.assert_array_equal(np.delete(q, 1), np.delete(clip_q, 1))
        assert float(takeoff_state.foot_clearance(env.model, q, env.takeoff.foot)) == \
            pytest.approx(0.0, abs=1e-12)
        assert float(takeoff_state.foot_clearance(env.model, clip_q, env.takeoff.foot)) > 0.05
        omega, velocity = takeoff_state.facing_velocities(q, qd)
        clip_omega, clip_velocity = takeoff_state.facing_velocities(clip_q, clip_qd)
        if kind == "highjump":
            np.testing.assert_allclose(omega, [x[1], -3.0, x[2]], atol=1e-12)
            np.testing.assert_allclose(velocity, [*clip_velocity[:2], x[3]], atol=1e-12)
        else:
            np.testing.assert_allclose(omega, x, atol=1e-12)
            np.testing.assert_allclose(velocity, clip_velocity, atol=1e-12)
        # The take-off foot is planted; the joints off the take-off leg move as in the clip.
        np.testing.assert_allclose(takeoff_state.foot_velocity(env.model, q, qd, foot), 0,
                                   atol=1e-9)
        np.testing.assert_array_equal(qd[others], clip_qd[others])
        # The facing frame: x along the root's X axis projected on the ground, y up.
        rot = rotations.quat_to_matrix(env.q0[3:7])
        forward = np.asarray(rot[:, 0]) * [1, 0, 1]
        np.testing.assert_allclose(env.heading[:, 0], forward / np.linalg.norm(forward),
                                   atol=1e-12)
        np.testing.assert_allclose(env.heading[:, 1], [0, 1, 0], atol=1e-12)


def test_the_vertical_velocity_parameter_sets_the_root_s_upward_take_off_speed(highjump):
    """Its default is the clip's (so x alone decides the take-off); set, it replaces only the
    root's vertical velocity, and the take-off foot stays planted."""
    env = highjump
    clip_q, clip_qd = takeoff_state.clip_state(env.model, _clip(env), env.takeoff.time)
    clip_velocity = takeoff_state.facing_velocities(clip_q, clip_qd)[1]
    params = env.default_params()
    assert float(params["vertical_velocity"]) == pytest.approx(float(clip_velocity[1]),
                                                                abs=1e-12)
    foot = env.model.topology.link_index(env.takeoff.foot)
    faster = {**params, "vertical_velocity": params["vertical_velocity"] + 0.5}
    state = env.reset(faster, jax.random.PRNGKey(0))
    velocity = takeoff_state.facing_velocities(state.physics.q, state.physics.qd)[1]
    np.testing.assert_allclose(velocity, [clip_velocity[0], clip_velocity[1] + 0.5,
                                          params["takeoff"][3]], atol=1e-12)
    np.testing.assert_allclose(takeoff_state.foot_velocity(env.model, state.physics.q,
                                                           state.physics.qd, foot), 0, atol=1e-9)


def test_the_sprint_turns_as_the_fixed_omega_y_does(highjump):
    """ω_y = −3 rad/s is the curved sprint's own turning at take-off (the thesis's "3 rad/s")."""
    clip = _clip(highjump)
    turning = [float(takeoff_state.facing_velocities(
        *takeoff_state.clip_state(highjump.model, clip, t))[0][1])
        for t in np.arange(highjump.takeoff.support[0], highjump.takeoff.flight[0], 1 / 30)]
    assert np.mean(turning) < -1.0
    assert np.sign(takeoff_state.HIGHJUMP_OMEGA_Y) == np.sign(np.mean(turning))


@pytest.mark.parametrize("kind", ["highjump", "obstacle"])
def test_the_takeoff_frame_is_in_a_support_phase_of_the_takeoff_foot(kind, highjump, obstacle):
    env = highjump if kind == "highjump" else obstacle
    frame = env.takeoff
    assert frame.support[0] <= frame.time <= frame.support[1] < frame.flight[0]
    times, support = takeoff_state.support_flags(env.model, _clip(env), env.settings.feet)
    foot = env.settings.feet.index(frame.foot)
    at = np.argmin(np.abs(times - frame.time))
    assert support[at, foot] and not np.delete(support[at], foot).any()   # single support
    # ... and the flight after it is the clip's longest time with neither foot down.
    assert frame.flight[1] - frame.flight[0] > 0.3


def test_the_takeoff_frame_is_midway_through_the_single_support_before_the_flight():
    times = np.arange(12) / 10
    #      frame:       0  1  2  3  4  5  6  7  8  9 10 11
    right = np.array([1, 1, 0, 0, 0, 1, 1, 1, 0, 0, 0, 1], bool)
    left = np.array([0, 0, 0, 1, 1, 1, 1, 1, 1, 0, 0, 0], bool)
    frame = takeoff_state.takeoff_from_support(times, np.stack([right, left], 1), 1.2,
                                               ("right", "left"))
    # The longest flight is frames 9–10; before it the left foot supports frames 3–8, alone
    # only in frame 8 after the double support of frames 5–7.
    assert frame.foot == "left" and frame.support == (0.8, 0.8) and frame.time == 0.8
    assert frame.flight == (0.9, 1.1)
    both = np.stack([right, left], 1)
    both[8] = True
    with pytest.raises(ConfigError, match="box.txt: the clip takes off from both feet"):
        takeoff_state.takeoff_from_support(times, both, 1.2, ("right", "left"), "box.txt")


def _clip(env):
    return motion.load_motion(env.clip_path, env.model)


def test_every_table_row_lies_in_the_search_bounds():
    for rows, kind in ((takeoff_state.HIGHJUMP_ROWS, "highjump"),
                       (takeoff_state.OBSTACLE_ROWS, "obstacle")):
        for x in rows.values():
            assert takeoff_state.check_x(kind, x, "takeoff") == x


# ------------------------------------------------------------------------- the rules

def _placed(env, distance, height, lying, gravity=None, params=None, tilt=np.pi / 2):
    """The first state of an episode, with the character moved `distance` m along the bar's
    normal from the take-off point, its root `height` m up, at rest; `lying` (its joints
    straight, turned by `tilt` about the bar's direction: π/2 lies down, π stands on its head),
    else upright in the take-off pose."""
    params = params or env.default_params()
    if gravity is not None:
        params = {**params, "gravity": jnp.asarray(gravity, jnp.float64)}
    state = env.reset(params, jax.random.PRNGKey(0))
    normal, origin, *_ = env.geometry(state.task)
    q = rest_pose(env.model).astype(jnp.float64) if lying else env.q0
    root_rot = rotations.quat_to_matrix(env.q0[3:7])
    if lying:      # lie down along the normal: the body's up axis along n
        side = jnp.cross(normal, jnp.array([0.0, 1.0, 0.0]))
        flat = rotations.axis_angle_to_matrix(side / jnp.linalg.norm(side), tilt)
        root_rot = flat @ env.heading
    position = origin + distance * normal + jnp.array([0.0, height, 0.0])
    q = q.at[:3].set(position).at[3:7].set(rotations.matrix_to_quat(root_rot))
    physics = simulation.init_state(env.model, env.world, q)
    return params, state.replace(physics=physics), q


def _run(env, step, params, state, action, steps):
    for k in range(steps):
        state = step(params, state, action)
        if state.terminated or state.truncated:
            return state, k + 1
    return state, steps


def _hold(env, q):
    """The plain-PD action that holds pose q's joints."""
    from agents.pose import pose_features
    return pose_features.target_to_exp(env.model, pose_features.pd_target(env.model, q))


def test_lying_on_the_block_past_the_bar_is_a_success_with_the_reward_by_hand(highjump,
                                                                            high_step):
    params, state, q = _placed(highjump, jump.BAR_DISTANCE + 1.4, 0.15, lying=True)
    state, steps = _run(highjump, high_step, params, state, _hold(highjump, q), 5)
    m = state.metrics
    assert bool(state.terminated) and float(m["episode/success"]) == 1.0
    assert float(m["episode/failure"]) == 0.0
    task = state.task
    omega_mean = float(task["omega_sum"]) / steps
    assert not bool(task["unsafe"])                      # the back, not the head, lands first
    expected = np.exp(-0.02 * omega_mean) * 1.0 * 1.0       # no offsets with plain PD actions
    assert float(state.reward) == pytest.approx(expected, rel=1e-12)
    # r_naturalness by hand for offsets: 1 − (mean ‖o‖₁ / c)².
    r, terms = highjump.reward({**task, "offset_sum": jnp.asarray(12.0 * steps),
                                "unsafe": jnp.asarray(True)}, steps)
    c = float(task["c_offset"])
    assert float(terms["naturalness"]) == pytest.approx(1 - (12.0 / c) ** 2, rel=1e-12)
    assert float(terms["safety"]) == 0.7                  # a head-first landing
    assert float(r) == pytest.approx(np.exp(-0.02 * omega_mean) * 0.7 * (1 - (12.0 / c) ** 2),
                                     rel=1e-12)
    # Stage 2's novelty multiplies in, from the episode's strategy features.
    novel = highjump.with_novelty(lambda f: jnp.clip(jnp.abs(f["up_angle"]) + 0.25, 0, 1))
    r_novel, terms = novel.reward(task, steps)
    assert float(terms["novelty"]) == pytest.approx(min(abs(float(task["up_angle"])) + 0.25, 1))
    assert float(r_novel) == pytest.approx(expected * float(terms["novelty"]), rel=1e-12)
    # Standing on its head over the block, the head touches it first: unsafe.
    params, state, q = _placed(highjump, jump.BAR_DISTANCE + 1.4, 0.95, lying=True, tilt=np.pi)
    state, _ = _run(highjump, high_step, params, state, _hold(highjump, q), 5)
    assert bool(state.task["landed"]) and bool(state.task["unsafe"])


def test_touching_the_wall_fails(highjump, high_step):
    params, state, q = _placed(highjump, jump.BAR_DISTANCE, 1.0, lying=False)
    state, steps = _run(highjump, high_step, params, state, _hold(highjump, q), 5)
    assert steps <= 2 and bool(state.terminated) and float(state.reward) == 0.0
    assert float(state.metrics["episode/failure"]) == 1.0
    assert float(state.metrics["episode/hit_bar"]) == 1.0
    assert bool(state.physics.touching[:, highjump.world.object_index("bar")].any())


def test_a_link_other_than_the_takeoff_foot_on_the_ground_fails(highjump, high_step):
    params, state, q = _placed(highjump, -1.0, 0.12, lying=True)
    state, steps = _run(highjump, high_step, params, state, _hold(highjump, q), 5)
    assert steps == 1 and bool(state.terminated)
    assert float(state.metrics["episode/failure"]) == 1.0
    assert float(state.metrics["episode/on_ground"]) == 1.0
    assert float(state.metrics["episode/hit_bar"]) == 0.0
    # The take-off foot alone may touch the ground: standing on it is no failure.
    params, state, q = _placed(highjump, -1.0, float(highjump.q0[1]), lying=False)
    state = high_step(params, state, _hold(highjump, q))
    assert not bool(state.terminated)


def test_two_seconds_after_takeoff_without_success_fail(highjump, high_step):
    params, state, q = _placed(highjump, -1.0, 3.0, lying=False, gravity=(0.0, 0.0, 0.0))
    state, steps = _run(highjump, high_step, params, state, _hold(highjump, q), 30)
    assert steps == 20                                      # 2 s at 10 Hz
    assert bool(state.terminated) and float(state.metrics["episode/failure"]) == 1.0
    assert float(state.metrics["episode/timeout"]) == 1.0
    assert float(state.metrics["episode/on_ground"]) == 0.0
    assert not np.asarray(state.physics.touching).any()


def test_the_crossing_feature_of_a_scripted_ballistic_flight_is_its_analytic_value(highjump):
    """A rigid flight scripted analytically (the take-off pose turning at a constant ω about a
    fixed axis, its root moving on a parabola): the observer keeps the root's orientation at
    the first 600 Hz sample past the instant the centre of mass crosses the bar plane."""
    env = highjump
    state = env.reset(env.default_params(), jax.random.PRNGKey(0))
    normal, origin, _, cross, bar_top, *_ = env.geometry(state.task)
    q0 = env.q0
    com0 = kinematics.center_of_mass(env.model, q0)
    v = 2.0 * normal + jnp.array([0.0, 4.0, 0.0])
    g = jnp.array([0.0, -9.8, 0.0])
    axis, rate = jnp.array([0.0, 0.6, 0.8]), 2.0
    rot0 = rotations.quat_to_matrix(q0[3:7])

    def pose(t):
        turn = rotations.axis_angle_to_matrix(axis, rate * t)
        rot = turn @ rot0
        com = com0 + v * t + 0.5 * g * t ** 2
        root = com + turn @ (q0[:3] - com0)
        return q0.at[:3].set(root).at[3:7].set(rotations.matrix_to_quat(rot)), rot

    dt = 1 / 600
    observe = env._crossing(state.task)
    seen = state.task
    for k in range(1, 600):
        q, _ = pose(k * dt)
        seen = observe(simulation.init_state(env.model, env.world, q), seen)
        if bool(seen["crossed"]):
            break
    # Analytic: the centre of mass reaches the plane at t* = (cross − n·(com0 − origin)) / n·v.
    t_star = float((cross - jnp.dot(com0 - origin, normal)) / jnp.dot(v, normal))
    sample = np.ceil(t_star / dt - 1e-9) * dt
    _, rot = pose(sample)
    np.testing.assert_allclose(seen["cross_rotvec"],
                               rotations.matrix_to_rotvec(env.heading.T @ rot), atol=1e-9)
    assert float(seen["up_angle"]) == pytest.approx(float(jnp.arccos(rot[1, 0])), abs=1e-9)
    com_y = com0[1] + v[1] * sample + 0.5 * g[1] * sample ** 2
    assert float(seen["clearance"]) == pytest.approx(float(com_y - bar_top), abs=1e-9)
    assert abs(sample - t_star) < dt


# ------------------------------------------------------------------------- geometry

def test_the_bar_turns_with_the_approach_angle_about_the_takeoff_point(highjump):
    for alpha in (0.0, 0.7, np.pi / 2):
        params = {**highjump.default_params(), "difficulty": jnp.asarray(1.1),
                  "takeoff": jnp.asarray([alpha, 0.0, 0.0, -1.0])}
        task = highjump.reset(params, jax.random.PRNGKey(0)).task
        normal, origin, *_ = highjump.geometry(task)
        expected = highjump.heading @ jnp.array([np.sin(alpha), 0.0, -np.cos(alpha)])
        np.testing.assert_allclose(normal, expected, atol=1e-12)
        world = highjump.world_for(task)
        bar, block = world.box_center
        np.testing.assert_allclose(jnp.dot(bar - origin, normal), jump.BAR_DISTANCE, atol=1e-12)
        assert float(world.box_half_size[0, 1]) * 2 == pytest.approx(1.1)       # wall to z
        assert float(world.box_half_size[1, 1]) * 2 == pytest.approx(0.4)       # 1.1 − 0.7
        near = jnp.dot(block - origin, normal) - world.box_half_size[1, 0]
        assert float(near) == pytest.approx(jump.BAR_DISTANCE + 0.02)
    assert float(world.friction[highjump.world.object_index("block")]) == 0.4


def test_bar_time_puts_the_bar_where_the_takeoff_velocity_carries_the_root(data_dir):
    env = jump.JumpEnv(jump.HighJumpSettings(actions="pd", bar_time=0.42), data_dir,
                       dtype=jnp.float64)
    distances = []
    for x in ((1.65, 1.00, 0.88, -2.21),        # the straddle row: straight at the bar
              (-0.05, -3.00, 1.00, -2.40),      # the flop row: sideways
              (0.45, 1.00, -0.26, -0.52),       # the front-kick row: 0.59 m, under the least
              (-0.52, 1.00, -1.00, -0.50)):     # moving away from the bar
        params = {**env.default_params(), "takeoff": jnp.asarray(x)}
        state = env.reset(params, jax.random.PRNGKey(0))
        _, velocity = takeoff_state.facing_velocities(state.physics.q, state.physics.qd)
        alpha = x[0]
        speed = float(np.dot(velocity, [np.sin(alpha), 0.0, -np.cos(alpha)]))
        expected = max(0.42 * speed, jump.MIN_BAR_DISTANCE)
        normal, origin, far, cross, *_ = env.geometry(state.task)
        world = env.world_for(state.task)
        (bar, block), (_, block_half) = world.box_center, world.box_half_size
        assert float(jnp.dot(bar - origin, normal)) == pytest.approx(expected, abs=1e-9)
        assert float(cross) == float(far) == pytest.approx(expected, abs=1e-9)
        assert float(jnp.dot(block - origin, normal) - block_half[0]) == pytest.approx(
            expected + 0.02)
        distances.append(float(cross))
    assert distances[0] == pytest.approx(0.83, abs=0.01)
    assert distances[1] == pytest.approx(0.96, abs=0.01)
    assert distances[2] == distances[3] == jump.MIN_BAR_DISTANCE


@pytest.mark.parametrize("key, value", [("bar_distance", 0.3), ("bar_time", -0.1),
                                        ("bar_time", 5.0)])
def test_a_bar_placement_out_of_range_is_an_error_naming_its_key(key, value):
    with pytest.raises(ValueError, match=key):
        jump.HighJumpSettings(**{key: value})


def test_the_obstacle_stands_ahead_of_the_takeoff_point_with_the_block_past_it(obstacle):
    params = {**obstacle.default_params(), "difficulty": jnp.asarray(0.3)}
    task = obstacle.reset(params, jax.random.PRNGKey(0)).task
    normal, origin, far, cross, top, *_ = obstacle.geometry(task)
    np.testing.assert_allclose(normal, obstacle.heading[:, 0], atol=1e-12)   # straight ahead
    world = obstacle.world_for(task)
    (box, block), (box_half, block_half) = world.box_center, world.box_half_size
    near = float(jnp.dot(box - origin, normal) - box_half[0])
    assert near == pytest.approx(jump.OBSTACLE_DISTANCE)
    assert float(box_half[0]) * 2 == pytest.approx(0.3) and float(box_half[1]) * 2 == 0.5
    assert float(far) == pytest.approx(near + 0.3) and float(cross) == pytest.approx(near + 0.15)
    assert float(jnp.dot(block - origin, normal) - block_half[0]) == pytest.approx(near + 0.32)
    assert float(block_half[1]) * 2 == pytest.approx(0.02) and float(top) == 0.5


# ------------------------------------------------------------------------- schedules

def test_the_control_rate_and_offset_schedules():
    for z, f, c in ((0.5, 10.0, 48.0), (0.6, 15.0, 41.4), (0.75, 20.0, 31.5), (1.0, 30.0, 15.0),
                    (1.8, 30.0, 15.0), (0.3, 10.0, 48.0)):
        assert jump.control_rate("highjump", z) == f
        assert float(jump.offset_coefficient("highjump", z)) == pytest.approx(c)
    assert jump.control_rate("obstacle", 0.05) == 10.0
    assert float(jump.offset_coefficient("obstacle", 0.5)) == pytest.approx(48 - 16.5)


def test_the_curriculum_rises_exactly_per_the_accumulator_rule():
    rule = curriculum_lib.RewardAccumulator(start=0.5, step=0.01, threshold=30.0, maximum=0.52)
    state = rule.init(jnp.float64)
    rewards = [10.0, 15.0, 6.0, 29.0, 0.0, 31.0, 40.0, 40.0]
    expected = []
    z, acc = 0.5, 0.0
    for r in rewards:
        acc += r
        if acc > 30.0:
            z, acc = min(z + 0.01, 0.52), 0.0
        expected.append((z, acc))
        state = rule.update(state, jnp.asarray(r))
        assert float(state["difficulty"]) == pytest.approx(expected[-1][0], abs=1e-12)
        assert float(state["accumulated"]) == pytest.approx(expected[-1][1], abs=1e-12)
    assert int(state["raises"]) == 2                  # the third rise is capped at the maximum


class Hurdle:
    """A toy task with a curriculum: reward 1 per episode when the policy's action beats the
    difficulty; episodes last one step."""

    observation_size, action_size, episode_steps = 1, 1, 1

    def __init__(self):
        self.curriculum = _ToyCurriculum()

    def default_params(self):
        return {"difficulty": jnp.zeros(())}

    def reset(self, params, key):
        return start_of_episode(jnp.zeros(()), jnp.stack([params["difficulty"]]), key,
                                params["difficulty"], {})

    def step(self, params, state, action):
        reward = jnp.where(action[0] > state.task, 1.0, 0.3)
        return end_of_step(state, state.physics, state.obs, reward, True, state.task, {},
                           self.episode_steps)


class _ToyCurriculum:
    rule = curriculum_lib.RewardAccumulator(0.0, 0.1, 1.5, 5.0)
    init, update, metrics = rule.init, rule.update, rule.metrics

    def params(self, env_params, state):
        return {**env_params, "difficulty": state["difficulty"]}

    def static_key(self, state):
        return None


def test_a_resumed_run_continues_the_curriculum_bit_for_bit(tmp_path):
    run = trainer_lib.RunSettings(task="reach", envs=8, steps_per_iteration=8, iterations=6)
    env = Hurdle()
    trainer = trainer_lib.Trainer(env, env.default_params(), run,
                                  PPOSettings(hidden=(8,), minibatch_size=16))
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
    straight = trainer_lib.run(trainer, trainer.init(), tmp_path / "a", echo=lambda *_: None)
    assert int(straight.curriculum["raises"]) >= 2            # it rose
    half = trainer.with_run_settings(dataclasses.replace(run, iterations=3))
    trainer_lib.run(half, trainer.init(), tmp_path / "b", echo=lambda *_: None)
    resumed = trainer_lib.load_checkpoint(trainer.init(), tmp_path / "b")
    assert float(resumed.curriculum["difficulty"]) > 0           # checkpointed mid-curriculum
    resumed = trainer_lib.run(trainer, resumed, tmp_path / "b", echo=lambda *_: None)
    for a, b in zip(jax.tree_util.tree_leaves(straight), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(a, b)
    # The difficulty reached the environments (their observation is the difficulty they were
    # reset at: the last iteration's, one rise behind at most).
    difficulty = float(resumed.curriculum["difficulty"])
    assert np.all(np.asarray(resumed.runner.envs.obs[:, 0]) >= difficulty - 0.1 - 1e-6)


def test_a_run_stops_where_the_curriculum_reaches_the_stop_difficulty(tmp_path):
    run = trainer_lib.RunSettings(task="reach", envs=8, steps_per_iteration=8, iterations=50,
                                  stop_difficulty=0.2)
    env = Hurdle()
    trainer = trainer_lib.Trainer(env, env.default_params(), run,
                                  PPOSettings(hidden=(8,), minibatch_size=16))
    lines = []
    state = trainer_lib.run(trainer, trainer.init(), tmp_path, echo=lines.append)
    difficulty = [r[trainer_lib.DIFFICULTY] for r in trainer_lib.read_metrics(tmp_path)]
    # The last iteration is the first at 0.2 (two rises of 0.1; float32 sums to 1e-5).
    assert difficulty[-1] == pytest.approx(0.2, abs=1e-5) and max(difficulty[:-1]) < 0.15
    assert trainer_lib.completed_iterations(state) == len(difficulty) < 50
    assert lines[-1].startswith("difficulty 0.2 reached at")
    saved = trainer_lib.load_checkpoint(trainer.init(), tmp_path)
    assert trainer_lib.completed_iterations(saved) == len(difficulty)


def test_task_parameters_may_differ_per_environment(highjump):
    params = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), highjump.default_params())
    params["difficulty"] = jnp.array([0.5, 1.4])
    tasks = jax.vmap(highjump.reset)(params, jax.random.split(jax.random.PRNGKey(0), 2))
    heights = [float(highjump.world_for(jax.tree_util.tree_map(lambda x: x[i], tasks.task))
                     .box_half_size[0, 1]) * 2 for i in range(2)]
    assert heights == pytest.approx([0.5, 1.4])


# ------------------------------------------------------------------------- variations

def test_a_cast_knee_does_not_bend(data_dir):
    env = jump.JumpEnv(jump.HighJumpSettings(actions="pd", cast_knee=True), data_dir,
                       dtype=jnp.float64)
    state = env.reset(env.default_params(), jax.random.PRNGKey(0))
    knee = env.model.topology.q_offsets[env.model.topology.link_index("right_knee")]
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    angles = []
    for _ in range(3):
        state = step(env.default_params(), state, jnp.asarray(rng.normal(size=env.action_size)))
        angles.append(float(state.physics.q[knee]))
    assert env.takeoff.foot == "right_ankle"
    np.testing.assert_allclose(angles, float(env.q0[knee]), atol=2e-3)


def test_mars_gravity_and_the_other_variations(data_dir, highjump, high_step):
    mars = (0.0, -3.711, 0.0)
    for gravity, g in ((None, 9.8), (mars, 3.711)):
        params, state, q = _placed(highjump, -2.0, 4.0, lying=False, gravity=gravity)
        com_v0 = kinematics.center_of_mass_velocity(highjump.model, state.physics.q,
                                                    state.physics.qd)
        after = high_step(params, state, _hold(highjump, q))
        com_v = kinematics.center_of_mass_velocity(highjump.model, after.physics.q,
                                                   after.physics.qd)
        assert float(com_v[1] - com_v0[1]) == pytest.approx(-g * 0.1, rel=1e-6)
    settings = jump.HighJumpSettings(actions="pd", weak_takeoff_leg=True, stiff_spine=True)
    weak = jump.JumpEnv(settings, data_dir, dtype=jnp.float64)
    topo = weak.model.topology
    ratio = np.asarray(weak.model.torque_limit) / np.asarray(highjump.model.torque_limit)
    for link in topo.names[1:]:
        dofs = slice(topo.dof_offsets[topo.link_index(link)],
                     topo.dof_offsets[topo.link_index(link) + 1])
        expected = 0.6 if link in ("right_hip", "right_knee", "right_ankle") else 1.0
        np.testing.assert_allclose(ratio[dofs], expected)
    chest = topo.dof_offsets[topo.link_index("chest")]
    assert float(weak.model.q_upper[chest + 2]) == 0.0                # no backward arching
    assert float(highjump.model.q_upper[chest + 2]) > 0.5


def test_landing_on_the_feet_is_safe_only_feet_first(data_dir):
    env = jump.JumpEnv(jump.HighJumpSettings(actions="pd", landing="feet"), data_dir,
                       dtype=jnp.float64)
    step = jax.jit(env.step)
    params, state, q = _placed(env, jump.BAR_DISTANCE + 1.4, env.q0[1] + 0.03, lying=False)
    state = step(params, state, _hold(env, q))
    for _ in range(3):
        if bool(state.task["landed"]):
            break
        state = step(params, state, _hold(env, q))
    assert bool(state.task["landed"]) and not bool(state.task["unsafe"])
    params, state, q = _placed(env, jump.BAR_DISTANCE + 1.4, 0.15, lying=True)
    state = step(params, state, _hold(env, q))
    assert bool(state.task["unsafe"])


# ------------------------------------------------------------------------- settings

@pytest.mark.parametrize("override, message", [
    ("highjump.takeoff=[3.0, 0.0, 0.0, -1.0]", "takeoff: alpha = 3.0 is outside"),
    ("highjump.takeoff=[0.0, 0.0]", "takeoff must give 4 numbers"),
    ("highjump.feet=['right_foot', 'left_ankle']", "unknown link 'right_foot'"),
    ("highjump.pvae='no/such/run'", "pvae: no/such/run/pvae.msgpack: missing"),
    ("highjump.landing='hands'", "landing must be one of"),
    ("highjump.sim_hz=500.0", "sim_hz must be a whole multiple of 15 Hz"),
    ("highjump.vertical_velocity='fast'", "'highjump.vertical_velocity' must be a float"),
    ("highjump.vertical_velocity=nan", "'highjump.vertical_velocity' must be a finite number"),
])
def test_bad_jump_settings_name_the_key(override, message, tmp_path, data_dir):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")) as error:
        train_commands.train("configs/highjump.toml", tmp_path / "run",
                             ["run.iterations=1", override], data_dir=data_dir)
    assert "highjump" in str(error.value)


def test_an_optional_setting_reads_whole_numbers_as_floats_and_round_trips():
    """`vertical_velocity: float | None`: absent is None (the clip's), 1 is 1.0, and a run's
    stored config.json (None as null) reads back as the same config."""
    for section, expected in (({}, None), ({"vertical_velocity": 1}, 1.0)):
        config = train_commands.build_config({"run": {"task": "highjump"},
                                              "highjump": section}, "test.toml")
        assert config.task.vertical_velocity == expected
        assert type(config.task.vertical_velocity) is type(expected)
        stored = json.loads(json.dumps(config.sections()))
        assert train_commands.build_config(stored, "config.json") == config


def test_a_blown_up_but_finite_step_ends_the_episode_in_the_state_before(highjump, high_step):
    """A simulation can grow for a while before it overflows: a step to speeds of 1e20, still
    finite, is kept out of the episode like a NaN (it overflowed the observation statistics of a
    training), and the jump episode fails as blown up."""
    from agents.tasks import common
    state = highjump.reset(highjump.default_params(), jax.random.PRNGKey(0))
    huge = state.physics.replace(qd=state.physics.qd.at[6].set(1e20))
    kept, sound = common.keep_sound(huge, state.physics)
    assert not bool(sound)
    np.testing.assert_array_equal(kept.qd, state.physics.qd)
    stepped = high_step(highjump.default_params(), state.replace(physics=huge),
                        _hold(highjump, highjump.q0))
    assert bool(stepped.terminated) and float(stepped.metrics["episode/blew_up"]) == 1.0
    np.testing.assert_array_equal(stepped.physics.qd, huge.qd)          # the state before
