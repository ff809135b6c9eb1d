"""The body observation (thesis §3.4.1) and the DeepMimic-style imitation task: invariance of the
facing-invariant observation, velocities against finite differences of the kinematics, reference
state initialisation, the reward at the start of an episode, early termination, the time limit,
NaN safety, batching, and settings validation.

Every step goes through one jitted, vmapped `step` over batches of `BATCH` environments, so it
compiles once for the whole module."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents import config as config_io
from agents.tasks.observations import body_observation, observation_size
from agents.tasks.imitation import REWARD_TERMS, ImitationEnv, ImitationSettings
from jaxsim import batch_last, kinematics, rotations

BATCH = 4
# 0.2 s at 30 Hz: the time limit is 6 control steps (the other tests need no more).
# As configs/imitate_walk.toml: SPD also tracks the clip's velocity.
SETTINGS = ImitationSettings(episode_seconds=0.2, spd_target_velocity="reference")



@jax.jit
def observe(model, q, qd):
    """The world-frame and the facing-invariant observations (one compilation for both)."""
    return body_observation(model, q, qd, False), body_observation(model, q, qd, True)


@jax.jit
def moved_kinematics(model, q, qd, h):
    """Link rotations and positions at q advanced by h qd."""
    return kinematics.forward_kinematics(model, kinematics.integrate(model, q, qd, h))


@pytest.fixture(scope="module")
def env(data_dir):
    return ImitationEnv(SETTINGS, data_dir, dtype=jnp.float64)


@pytest.fixture(scope="module")
def batched(env):
    """(reset, step, start_at) over batches; `step` is the one compiled physics step."""
    return (jax.jit(jax.vmap(env.reset, in_axes=(None, 0))),
            jax.jit(jax.vmap(env.step, in_axes=(None, 0, 0))),
            jax.jit(jax.vmap(env.start_at)))


@pytest.fixture(scope="module")
def starts(env, batched):
    """A batch of reset states (keys 0..3)."""
    reset, _, _ = batched
    return reset(env.default_params(), jax.random.split(jax.random.PRNGKey(0), BATCH))


def with_settings(data_dir, **changes):
    return ImitationEnv(dataclasses.replace(SETTINGS, **changes), data_dir, dtype=jnp.float64)


def zeros(env):
    return jnp.zeros((BATCH, env.action_size))


def split_observation(obs, n):
    """(root height, relative positions (n−1, 3), quaternions (n, 4), linear (n, 3) and angular
    (n, 3) velocities) of a body observation."""
    sizes = np.cumsum([1, 3 * (n - 1), 4 * n, 3 * n])
    height, rel, quat, lin, ang = np.split(np.asarray(obs), sizes)
    return (height[0], rel.reshape(n - 1, 3), quat.reshape(n, 4), lin.reshape(n, 3),
            ang.reshape(n, 3))


@pytest.fixture(scope="module")
def reference(env):
    """The clip's (q, qd) at a time, jitted."""
    return jax.jit(env.reference)


def turned(q, yaw, shift):
    """q with the root turned by `yaw` about +Y (about the world origin) and moved by `shift`."""
    turn = rotations.axis_angle_to_quat(jnp.array([0.0, 1.0, 0.0]), jnp.asarray(yaw))
    rot = rotations.quat_to_matrix(turn)
    q = q.at[:3].set(rot @ q[:3] + jnp.asarray(shift))
    return q.at[3:7].set(rotations.quat_multiply(turn, q[3:7]))


# ---------------------------------------------------------------------------- observations


def test_observation_size(env, reference):
    q, qd = reference(0.3)
    n = env.model.n_links
    assert observation_size(env.model) == 1 + 3 * (n - 1) + 10 * n == 193
    for obs in observe(env.model, q, qd):
        assert obs.shape == (193,)
    assert env.observation_size == 195          # + (sin, cos) of the phase
    assert env.action_size == 28


def test_facing_invariant_observation_ignores_yaw_and_horizontal_position(env, reference):
    q, qd = reference(0.7)
    # qd's root velocity is in the root's body frame, so the same qd is the same motion turned
    # along with the root: no change to qd is needed.
    q_turned = turned(q, 2.1, (0.8, 0.0, -1.7))
    world, invariant = observe(env.model, q, qd)
    world_turned, invariant_turned = observe(env.model, q_turned, qd)
    np.testing.assert_allclose(invariant_turned, invariant, atol=1e-10)
    assert np.max(np.abs(world_turned - world)) > 0.1
    # Vertical quantities are the same in both frames: the root height and the Y components.
    n = env.model.n_links
    h_w, rel_w, _, lin_w, ang_w = split_observation(world, n)
    h_i, rel_i, _, lin_i, ang_i = split_observation(invariant, n)
    assert h_w == pytest.approx(h_i) == pytest.approx(float(q[1]))
    for a, b in ((rel_w, rel_i), (lin_w, lin_i), (ang_w, ang_i)):
        np.testing.assert_allclose(a[:, 1], b[:, 1], atol=1e-12)


def test_world_observation_against_forward_kinematics(env, reference):
    """Positions and rotations from forward kinematics; velocities from central differences of
    the kinematics along q advanced by ±h qd; quaternions canonical (w ≥ 0)."""
    model = env.model
    q, qd = reference(0.45)
    n = model.n_links
    height, rel, quat, lin, ang = split_observation(observe(model, q, qd)[0], n)
    rot, pos = moved_kinematics(model, q, qd, 0.0)
    assert height == pytest.approx(float(pos[0, 1]))
    np.testing.assert_allclose(rel, pos[1:] - pos[0], atol=1e-12)
    assert np.all(quat[:, 0] >= 0)
    np.testing.assert_allclose(rotations.quat_to_matrix(jnp.asarray(quat)), rot, atol=1e-12)
    h = 1e-6
    rot_p, pos_p = moved_kinematics(model, q, qd, h)
    rot_m, pos_m = moved_kinematics(model, q, qd, -h)
    np.testing.assert_allclose(lin, (pos_p - pos_m) / (2 * h), atol=1e-5)
    # R(t+h) R(t−h)ᵀ = exp(2h ω̃) with ω the world angular velocity.
    turn = rotations.matrix_to_rotvec(rot_p @ jnp.swapaxes(rot_m, -1, -2))
    np.testing.assert_allclose(ang, turn / (2 * h), atol=1e-5)


# ---------------------------------------------------------------------------- the task


def test_start_at_a_frame_reproduces_the_clip(env, batched, reference):
    """Reference state initialisation at frame times gives the frames' poses, the clip's velocity
    and an observation with the phase of that time."""
    _, _, start_at = batched
    frames = np.array([0, 5, 17, 30])
    times = env.clip.times[frames]
    states = start_at(times, jax.random.split(jax.random.PRNGKey(1), BATCH))
    np.testing.assert_allclose(states.physics.q, env.clip.poses[frames], atol=1e-12)
    velocities = [reference(t)[1] for t in times]
    np.testing.assert_allclose(states.physics.qd, velocities, atol=1e-12)
    phase = 2 * np.pi * np.asarray(times) / float(env.clip.duration)
    np.testing.assert_allclose(states.obs[:, -2:], np.stack([np.sin(phase), np.cos(phase)], -1),
                               atol=1e-12)
    np.testing.assert_allclose(states.task, times)
    assert not np.any(states.terminated | states.truncated)
    assert np.all(states.steps == 0) and np.all(states.reward == 0)


def test_reset_batches_start_at_different_times(env, starts):
    times = np.asarray(starts.task)
    assert len(np.unique(times)) == BATCH
    assert np.all((times >= 0) & (times < float(env.clip.duration)))
    assert starts.obs.shape == (BATCH, env.observation_size)
    assert starts.physics.q.shape == (BATCH, env.model.nq)
    for name, value in starts.metrics.items():
        assert value.shape == (BATCH,) and np.all(value == 0), name


def test_zero_residual_starts_with_a_high_reward(env, batched, starts):
    """One step with a zero residual (the PD targets are the reference pose and velocity one
    control step ahead) from a state on the reference. In 1/30 s the character drifts from the
    reference only by the SPD tracking lag and the ground contacts, so the pose and end-effector
    terms (weight 0.8 together) stay close to 1 while the velocity and centre-of-mass velocity
    terms may drop: the reward stays above 0.6. A heel strike inside the step jolts the light
    arms (from t = 0.61 s of the walk the left shoulder ends 15° off), so the pose term is only
    above 0.75 everywhere, and above 0.95 for most starts."""
    _, step, _ = batched
    params = env.default_params()
    state = step(params, starts, zeros(env))
    assert np.all(state.reward > 0.6), state.reward
    assert np.all(state.metrics["reward_pose"] > 0.75)
    assert np.median(state.metrics["reward_pose"]) > 0.95
    assert np.all(state.metrics["pose_error_degrees"] < 5)
    assert set(state.metrics) == set(starts.metrics)
    for _ in range(3):
        for term in REWARD_TERMS:
            value = np.asarray(state.metrics[f"reward_{term}"])
            assert np.all((value >= 0) & (value <= 1)), term
        # The step's reward is the weighting of the terms it reports (checked on its own with
        # known numbers in test_reward_terms_against_known_errors).
        terms = {term: state.metrics[f"reward_{term}"] for term in REWARD_TERMS}
        np.testing.assert_allclose(state.reward, env.reward(terms), rtol=1e-12)
        state = step(params, state, zeros(env))


def test_time_limit_truncates_at_the_last_step(env, batched, starts):
    _, step, _ = batched
    state = starts
    for k in range(1, env.episode_steps + 1):
        state = step(env.default_params(), state, zeros(env))
        assert not np.any(state.terminated), k     # these starts stay up for 0.2 s
        assert np.all(state.steps == k)
        assert np.all(state.truncated == (k == env.episode_steps)), k
    assert env.episode_steps == 6


def test_a_clip_that_does_not_loop_ends_the_episode_when_it_is_over(data_dir, tmp_path):
    """The walk's first four frames, 0.03 s apart and not looping, last 0.09 s. At 30 Hz an
    episode started at 0 s reaches t = 0.1 s, past the end, at its third step; one started at
    0.05 s at its second (t = 0.117 s). That step truncates the episode (the time limit, 6
    steps, is further); the character stood, so nothing terminates."""
    walk = json.loads((data_dir / "deepmimic" / "motions" / "humanoid3d_walk.txt").read_text())
    frames = [[0.03, *frame[1:]] for frame in walk["Frames"][:4]]
    clip = tmp_path / "walk_start.txt"
    clip.write_text(json.dumps({"Loop": "none", "Frames": frames}))
    short = with_settings(data_dir, clip=str(clip))
    assert not short.clip.loop and float(short.clip.duration) == pytest.approx(0.09)
    start_at = jax.jit(jax.vmap(short.start_at))
    step = jax.jit(jax.vmap(short.step, in_axes=(None, 0, 0)))
    state = start_at(jnp.array([0.0, 0.05, 0.0, 0.05]), jax.random.split(jax.random.PRNGKey(0),
                                                                         BATCH))
    first_truncation = np.zeros(BATCH, int)
    for k in range(1, 4):
        state = step(short.default_params(), state, zeros(short))
        assert not np.any(state.terminated), k
        first_truncation = np.where((first_truncation == 0) & state.truncated, k,
                                    first_truncation)
    np.testing.assert_array_equal(first_truncation, [3, 2, 3, 2])


def test_lying_on_the_ground_terminates(env, batched, starts):
    """Environments 1 and 3 lie on their side (root turned 90° about the world Z axis, root 8 cm
    above the ground): the torso touches the ground at once. Standing ones do not terminate."""
    _, step, _ = batched
    lying = jnp.array([False, True, False, True])
    quarter = rotations.axis_angle_to_quat(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(np.pi / 2))
    q = starts.physics.q
    q_lying = q.at[:, 1].set(0.08).at[:, 3:7].set(rotations.quat_multiply(quarter, q[:, 3:7]))
    q = jnp.where(lying[:, None], q_lying, q)
    qd = jnp.where(lying[:, None], 0.0, starts.physics.qd)
    state = step(env.default_params(), starts.replace(physics=starts.physics.replace(q=q, qd=qd)),
                 zeros(env))
    np.testing.assert_array_equal(state.terminated, lying)
    np.testing.assert_array_equal(state.metrics["fell"], lying.astype(float))
    assert not np.any(state.truncated)


def test_nan_actions_terminate_with_finite_observations(env, batched, starts):
    _, step, _ = batched
    bad = jnp.array([False, True, False, True])
    actions = jnp.where(bad[:, None], jnp.nan, zeros(env))
    state = step(env.default_params(), starts, actions)
    assert np.all(np.isfinite(state.obs)) and np.all(np.isfinite(state.reward))
    assert np.all(np.isfinite(state.physics.q)) and np.all(np.isfinite(state.physics.qd))
    for value in state.metrics.values():
        assert np.all(np.isfinite(value))
    np.testing.assert_array_equal(state.terminated, bad)
    # The blown-up environments keep their state from before the step and earn nothing.
    np.testing.assert_array_equal(state.physics.q[1], starts.physics.q[1])
    assert state.reward[1] == 0 and state.reward[0] > 0


def test_the_step_with_the_batch_innermost_equals_vmap(env, batched, starts):
    """The rollout steps its environments with `batch_last.vmap`; it must compute what
    `jax.vmap` does: random actions, one environment given NaN actions (it terminates), two
    control steps (40 simulation steps with contacts), float64."""
    _, step, _ = batched
    step_last = jax.jit(batch_last.vmap(env.step, in_axes=(None, 0, 0)))
    rng = np.random.default_rng(3)
    actions = jnp.asarray(rng.normal(scale=0.3, size=(BATCH, env.action_size)))
    actions = actions.at[2].set(jnp.nan)
    params = env.default_params()
    expected = got = starts
    for _ in range(2):
        expected, got = step(params, expected, actions), step_last(params, got, actions)
        for e, g in zip(jax.tree.leaves(expected), jax.tree.leaves(got)):
            np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.terminated, [False, False, True, False])


def test_absolute_actions_and_action_scale(env, data_dir, reference):
    """Absolute: the target is exp(a) per joint, whatever the reference; residual: a zero action
    gives the reference, and `action_scale` scales the offset."""
    q_ref, _ = reference(0.2)
    action = 0.1 * jnp.arange(env.action_size, dtype=jnp.float64) / env.action_size
    residual_target = jax.jit(env.pd_target)
    np.testing.assert_allclose(residual_target(q_ref, jnp.zeros(env.action_size)), q_ref)
    target = jax.jit(with_settings(data_dir, actions="absolute").pd_target)(q_ref, action)
    quats, _ = env.model.topology.spherical_indices
    # Residual target rotations are the reference's composed with exp(a): q_ref⁻¹ q̄ = exp(a).
    residual = residual_target(q_ref, action)
    np.testing.assert_allclose(
        rotations.quat_multiply(rotations.quat_conjugate(q_ref[quats]), residual[quats]),
        target[quats], atol=1e-12)
    revolute = env.model.topology.q_offsets[env.model.topology.links_of_type("revolute")]
    np.testing.assert_allclose(residual[revolute] - q_ref[revolute], target[revolute])
    doubled = jax.jit(with_settings(data_dir, action_scale=2.0).pd_target)
    np.testing.assert_allclose(doubled(q_ref, action / 2), residual, atol=1e-12)


def test_reward_terms_against_known_errors(env, reference):
    """Each DeepMimic term from an error we put in by hand: the neck turned by θ from the
    reference (no end effector below it) gives exp(−k_pose θ²) and leaves the end-effector and
    velocity terms at 1; a root velocity offset Δ (body frame, every link moves with it) gives
    exp(−k_com ‖Δ‖²)."""
    terms = jax.jit(env.reward_terms)
    q_ref, qd_ref = reference(0.4)
    neck = env.model.topology.q_offsets[env.model.topology.link_index("neck")]
    theta = 0.3
    turn = rotations.axis_angle_to_quat(jnp.array([0.6, 0.0, 0.8]), jnp.asarray(theta))
    q = q_ref.at[neck:neck + 4].set(rotations.quat_multiply(q_ref[neck:neck + 4], turn))
    values, angles = terms(q, qd_ref, q_ref, qd_ref)
    assert float(values["pose"]) == pytest.approx(np.exp(-SETTINGS.k_pose * theta**2), rel=1e-9)
    assert float(values["end_effector"]) == pytest.approx(1.0, abs=1e-12)
    assert float(values["velocity"]) == pytest.approx(1.0, abs=1e-12)
    assert float(jnp.max(angles)) == pytest.approx(theta, rel=1e-9)
    delta = jnp.array([0.2, -0.1, 0.3])
    values, _ = terms(q_ref, qd_ref.at[3:6].add(delta), q_ref, qd_ref)
    assert float(values["com"]) == pytest.approx(
        np.exp(-SETTINGS.k_com * float(delta @ delta)), rel=1e-9)
    assert float(values["pose"]) == pytest.approx(1.0, abs=1e-12)
    # DeepMimic's weights: pose 0.65, velocity 0.1, end effector 0.15, centre of mass 0.1; only
    # the last term is off here, by exp(−10 · 0.14).
    assert float(env.reward(values)) == pytest.approx(0.9 + 0.1 * np.exp(-1.4), rel=1e-9)


# ---------------------------------------------------------------------------- settings


@pytest.mark.parametrize("key, value", [
    ("control_hz", 0.0), ("sim_hz", 100.0), ("episode_seconds", 0.01), ("method", "euler"),
    ("actions", "torques"), ("action_scale", -1.0), ("w_pose", -0.5), ("k_com", float("nan")),
    ("clip", ""), ("spd_target_velocity", "clip"),
])
def test_settings_errors_name_the_key(key, value):
    with pytest.raises(ValueError, match=key):
        ImitationSettings(**{key: value})


def test_config_section_and_data_errors(data_dir, tmp_path):
    path = tmp_path / "run.toml"
    path.write_text("[imitation]\nsim_hz = 100.0\n")

    @dataclasses.dataclass(frozen=True)
    class Config:
        imitation: ImitationSettings = dataclasses.field(default_factory=ImitationSettings)

    with pytest.raises(config_io.ConfigError, match=r"\[imitation\].*sim_hz"):
        config_io.load(path, Config)
    assert config_io.load(path, Config, ["imitation.sim_hz=600", "imitation.feet=['a']"]) \
        .imitation.feet == ("a",)
    with pytest.raises(ValueError, match="feet"):
        ImitationEnv(ImitationSettings(feet=("right_ankle", "left_foot")), data_dir)
    with pytest.raises(ValueError, match="clip"):
        ImitationEnv(ImitationSettings(clip="no_such_clip.txt"), data_dir)
    with pytest.raises(ValueError, match="character"):
        ImitationEnv(ImitationSettings(character="no_such_character.txt"), data_dir)
