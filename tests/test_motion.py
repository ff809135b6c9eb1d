"""Motion clips: DeepMimic files, sampling, velocities, looping, slither, SPD tracking."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import characters, kinematics, motion, rotations, tracking
from jaxsim.world import make_world


@pytest.fixture(scope="module")
def humanoid(data_dir):
    dm = data_dir / "deepmimic"
    return characters.load_deepmimic(dm / "characters" / "humanoid3d.txt",
                                     dm / "controllers" / "humanoid3d_ctrl.txt",
                                     dtype=jnp.float64)


@pytest.fixture(scope="module")
def walk(data_dir, humanoid):
    return motion.load_motion(data_dir / "deepmimic" / "motions" / "humanoid3d_walk.txt",
                              humanoid)


def test_real_walk_clip_has_its_frames_and_a_known_knee_angle(data_dir, humanoid, walk):
    frames = json.loads((data_dir / "deepmimic/motions/humanoid3d_walk.txt").read_text())
    frames = frames["Frames"]
    assert walk.n_frames == len(frames) == 39 and walk.loop
    assert float(walk.duration) == pytest.approx(sum(f[0] for f in frames[:-1]))
    knee = humanoid.topology.q_offsets[humanoid.topology.link_index("right_knee")]
    t10 = float(walk.times[10])
    assert float(motion.sample_pose(walk, t10)[knee]) == pytest.approx(frames[10][1 + knee])


def test_every_deepmimic_clip_loads_for_its_character(data_dir, humanoid):
    dm = data_dir / "deepmimic"
    dog = characters.load_deepmimic(dm / "characters/dog3d.txt", dm / "controllers/dog3d_ctrl.txt")
    paths = sorted((dm / "motions").glob("*.txt"))
    assert len(paths) == 24
    for path in paths:
        clip = motion.load_motion(path, dog if path.name.startswith("dog") else humanoid)
        assert clip.n_frames > 20 and float(clip.duration) > 0


def test_quaternions_are_interpolated_by_slerp(humanoid, walk):
    t0, t1 = float(walk.times[5]), float(walk.times[6])
    chest = humanoid.topology.q_offsets[humanoid.topology.link_index("chest")] + np.arange(4)
    q0, q1 = walk.poses[5, chest], walk.poses[6, chest]
    mid = motion.sample_pose(walk, 0.5 * (t0 + t1))[chest]
    angle = lambda a, b: np.linalg.norm(rotations.quat_to_rotvec(  # noqa: E731
        rotations.quat_multiply(rotations.quat_conjugate(a), b)))
    assert angle(q0, mid) == pytest.approx(angle(mid, q1), rel=1e-9)
    assert angle(q0, mid) == pytest.approx(0.5 * angle(q0, q1), rel=1e-9)
    assert float(jnp.linalg.norm(mid)) == pytest.approx(1.0)


@pytest.mark.parametrize("t", [0.31, 0.52, 1.0])
def test_clip_velocity_is_the_derivative_of_the_clip_pose(humanoid, walk, t):
    h = 1e-6
    q, qd = motion.sample_pose(walk, t), motion.sample_velocity(walk, t)
    predicted = kinematics.integrate(humanoid, q, qd, h)
    np.testing.assert_allclose(predicted, motion.sample_pose(walk, t + h), atol=1e-10)


def test_looping_carries_the_root_forward_and_a_one_shot_clip_holds_its_end(data_dir,
                                                                            humanoid, walk):
    t = 0.4
    later = motion.sample_pose(walk, t + 2 * float(walk.duration))
    now = motion.sample_pose(walk, t)
    step = walk.poses[-1, :3] - walk.poses[0, :3]
    np.testing.assert_allclose(later[:3] - now[:3], 2 * step * jnp.array([1, 0, 1]), atol=1e-12)
    np.testing.assert_allclose(later[3:], now[3:], atol=1e-12)
    assert float(step[0]) > 1.0                                    # the walk moves forward
    kick = motion.load_motion(data_dir / "deepmimic/motions/humanoid3d_kick.txt", humanoid)
    assert not kick.loop
    np.testing.assert_allclose(motion.sample_pose(kick, float(kick.duration) + 3.0),
                               kick.poses[-1], atol=1e-12)
    # Held still outside the clip, it does not move: no velocity after the end or before the
    # start, while at the ends themselves the velocity is the last (first) interval's rate.
    end = float(kick.duration)
    for t in (end + 3.0, end + 1e-9, -1e-9, -0.5):
        np.testing.assert_array_equal(motion.sample_velocity(kick, t), np.zeros(humanoid.nv))
    for t, inside in ((end, end - 1e-7), (0.0, 1e-7)):
        velocity = motion.sample_velocity(kick, t)
        assert float(jnp.abs(velocity).max()) > 0.1
        np.testing.assert_allclose(velocity, motion.sample_velocity(kick, inside), atol=1e-5)
    jitted = jax.jit(motion.sample_velocity)
    np.testing.assert_array_equal(jitted(kick, jnp.asarray(end + 3.0)), np.zeros(humanoid.nv))
    np.testing.assert_allclose(jitted(kick, jnp.asarray(end)), motion.sample_velocity(kick, end),
                               atol=1e-12)


def test_clip_forward_kinematics_matches_the_pose_kinematics(humanoid, walk):
    times = jnp.array([0.0, 0.5, 1.7])
    positions = motion.link_positions(humanoid, walk, times)
    assert positions.shape == (3, humanoid.n_links, 3)
    _, expected = kinematics.forward_kinematics(humanoid, motion.sample_pose(walk, 0.5))
    np.testing.assert_allclose(positions[1], expected)


@pytest.mark.parametrize("content,message", [
    ("{not json", r"bad\.txt: not valid JSON at line 1"),
    ('{"Loop": "wrap"}', "missing field 'Frames'"),
    ('{"Loop": "sometimes", "Frames": []}', "'Loop' must be 'wrap' or 'none'"),
    ('{"Loop": "wrap", "Frames": [[0.1, 0, 1, 0]]}', "frame 0 has 4 numbers; this character "
                                                     "needs 1 \\+ 43"),
    ('{"Loop": "wrap", "Frames": [[0.1' + ", 0" * 43 + '], [0' + ", 0" * 43 + "]]}",
     "zero quaternion"),
    ('{"Loop": "wrap", "Frames": [["x"' + ", 0" * 43 + "]]}", "not a number"),
])
def test_malformed_motion_files_are_named(tmp_path, humanoid, content, message):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(motion.MotionFileError, match=message):
        motion.load_motion(path, humanoid)


def test_a_dog_clip_is_refused_by_the_humanoid(data_dir, humanoid):
    with pytest.raises(motion.MotionFileError, match="needs 1 \\+ 43"):
        motion.load_motion(data_dir / "deepmimic/motions/dog3d_canter.txt", humanoid)


def test_slither_is_a_travelling_wave_that_moves_the_snake_forward():
    snake = characters.snake(10).astype(jnp.float64)
    clip = motion.slither_clip(snake, frequency=1.0, speed=0.3, frame_rate=64)
    assert clip.loop and float(clip.duration) == pytest.approx(1.0)
    np.testing.assert_allclose(motion.sample_pose(clip, 2.25)[0], -0.3 * 2.25, atol=1e-9)
    # Joint i lags joint i−1 by 1/8 of a cycle: its pose then equals the earlier joint's.
    q_early = motion.sample_pose(clip, 0.0)
    q_late = motion.sample_pose(clip, 1 / 8)
    o = snake.topology.q_offsets
    np.testing.assert_allclose(q_late[o[3]:o[3] + 4], q_early[o[2]:o[2] + 4], atol=1e-9)
    with pytest.raises(ValueError, match="needs a snake"):
        motion.slither_clip(characters.humanoid())


def test_spd_tracking_follows_the_walk_and_dense_equals_maba(humanoid, walk):
    model = tracking.tracking_model(humanoid)
    world = make_world(ground=False, joint_limits=False, dtype=jnp.float64)
    dt, n = 1 / 120, 120
    runs = {m: tracking.track(model, world, walk, dt, n, m) for m in ("dense", "maba")}
    np.testing.assert_allclose(runs["dense"].q, runs["maba"].q, atol=1e-8)
    error = tracking.end_effector_error(model, walk, runs["maba"].q, dt, "right_ankle")
    assert error.shape == (n,) and float(error.mean()) < 0.02
    # Without the reference velocity the PD lags behind by about K_d q̄̇ / K_p.
    poses, _ = tracking.reference_targets(walk, dt, n)
    state = tracking.initial_state(model, world, walk)
    from jaxsim.simulation import simulate
    _, lagging = simulate(model, world, state, poses, dt)
    lag = tracking.end_effector_error(model, walk, lagging.q, dt, "right_ankle")
    assert float(lag.mean()) > 3 * float(error.mean())


TINY_BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 1 0
  CHANNELS 3 Xposition Yposition Zposition
  End Site
  {
    OFFSET 0 2 0
  }
}
MOTION
Frames: 1
Frame Time: 0.1
0 0 0
"""


@pytest.mark.parametrize("value", [-1.0, 0.0, float("nan"), float("inf"), "2"])
def test_loader_scales_and_rates_must_be_positive_numbers(tmp_path, data_dir, value):
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY_BVH)
    np.testing.assert_allclose(motion.load_bvh(path, length_scale=0.5).skeleton.rest_positions,
                               [[0.0, 0.5, 0.0]])
    with pytest.raises(motion.MotionFileError,
                       match=f"tiny.bvh: length_scale must be a finite number > 0.*got '?{value}"):
        motion.load_bvh(path, length_scale=value)
    cmu = data_dir / "cmu" / "02"
    with pytest.raises(motion.MotionFileError,
                       match=f"02_01.amc: frame_rate must be a finite number > 0.*got '?{value}"):
        motion.load_amc(cmu / "02_01.amc", motion.load_asf(cmu / "02.asf"), frame_rate=value)
