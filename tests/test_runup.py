"""The run-up task (thesis §3.6.1, eqs. 3.13–3.14) and the full motion: the task reward by hand,
the desired take-off state is the jump's, the episode grid ends at the take-off time, and in the
full motion of two (untrained) policies the jump policy takes over at the take-off time."""

import copy
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.commands import cli, motion_commands, train_commands
from agents.config import ConfigError
from agents.rl import trainer as trainer_lib
from agents.tasks import full_motion as fm
from agents.tasks import jump, runup, takeoff_state
from jaxsim import motion, rotations

FOSBURY = takeoff_state.HIGHJUMP_ROWS["fosbury_flop"]


@pytest.fixture(scope="module")
def env(data_dir):
    return runup.RunupEnv(runup.RunupSettings(takeoff=FOSBURY), data_dir, dtype=jnp.float64)


def _begin(env, x, steps):
    params = {**env.default_params(), "takeoff": jnp.asarray(x, jnp.float64)}
    return params, jax.jit(env.begin)(params, steps, jax.random.PRNGKey(0))


# ---------------------------------------------------------------------------- the task reward

def test_the_task_reward_by_hand():
    omega, velocity = np.array([0.5, -2.0, 1.5]), np.array([2.0, 0.3, -1.0])
    target_omega, target_velocity = np.array([-1.0, -3.0, 1.0]), np.array([9.0, 9.0, -2.4])
    # eq. 3.13: ‖ω − ω̄‖₁ = 1.5 + 1 + 0.5 = 3, (v_z − v̄_z)² = 1.4² = 1.96
    high = runup.takeoff_reward("highjump", omega, velocity, target_omega, target_velocity)
    assert float(high) == pytest.approx(np.exp(-3 / 3 - 0.7 * 1.96), rel=1e-12)
    # eq. 3.14: no velocity term
    low = runup.takeoff_reward("obstacle", omega, velocity, target_omega, target_velocity)
    assert float(low) == pytest.approx(np.exp(-1.0), rel=1e-12)
    assert float(runup.takeoff_reward("highjump", omega, velocity, omega, velocity)) == 1.0
    # ours, k_y = 0.5: − 0.5 (v_y − v̄_y)² = − 0.5 · 8.7² = − 37.845 more, for either kind
    vertical = runup.takeoff_reward("highjump", omega, velocity, target_omega, target_velocity,
                                    k_vertical=0.5)
    assert float(vertical) == pytest.approx(np.exp(-1 - 0.7 * 1.96 - 37.845), rel=1e-12)
    vertical = runup.takeoff_reward("obstacle", omega, velocity, target_omega, target_velocity,
                                    k_vertical=0.5)
    assert float(vertical) == pytest.approx(np.exp(-1 - 37.845), rel=1e-12)
    # ours, k_q = 0.3: − 0.3 mean((1 − 0)², (−2 − 1)²) = − 0.3 · 5 = − 1.5 more
    joints = runup.takeoff_reward("obstacle", omega, velocity, target_omega, target_velocity,
                                  k_joints=0.3, joint_velocity=np.array([1.0, -2.0]),
                                  target_joint_velocity=np.array([0.0, 1.0]))
    assert float(joints) == pytest.approx(np.exp(-1 - 1.5), rel=1e-12)
    with pytest.raises(ValueError, match="k_joints > 0 needs joint_velocity"):
        runup.takeoff_reward("obstacle", omega, velocity, target_omega, target_velocity,
                             k_joints=0.3)


def test_the_settings_give_the_task_reward_its_weights():
    settings = runup.RunupSettings(k_takeoff_omega=0.2, k_takeoff_velocity=0.3,
                                   k_takeoff_vertical=0.4, k_takeoff_joints=0.5)
    assert settings.takeoff_weights == {"k_omega": 0.2, "k_velocity": 0.3, "k_vertical": 0.4,
                                        "k_joints": 0.5}
    thesis = runup.RunupSettings().takeoff_weights           # eq. 3.13 alone by default
    assert thesis["k_vertical"] == thesis["k_joints"] == 0.0


def _imitation_reward(env, state):
    return sum(getattr(env.settings, f"w_{term}") * float(state.metrics[f"reward_{term}"])
               for term in ("pose", "velocity", "end_effector", "com"))


def test_the_episode_s_targets_are_x_s_and_the_take_off_step_pays_r_g(env):
    x = FOSBURY                                   # (α, ω_x, ω_z, v_z)
    params, state = _begin(env, x, 2)             # two control steps before the take-off
    np.testing.assert_allclose(state.task["target_omega"], [x[1], -3.0, x[2]], atol=1e-12)
    assert float(state.task["target_velocity"][2]) == pytest.approx(x[3], abs=1e-12)
    # A constructed state: the take-off pose with chosen root velocities in the facing frame.
    q = env.q0
    qd = takeoff_state.with_facing_velocities(q, env.qd0, jnp.array([-2.0, -2.5, 0.0]),
                                              jnp.array([4.0, 0.5, -1.9]))
    constructed = state.physics.replace(q=q, qd=qd)
    by_hand = np.exp(-(1.0 + 0.5 + 1.0) / 3 - 0.7 * 0.5 ** 2)
    assert float(env.task_reward(constructed, state.task)) == pytest.approx(by_hand, rel=1e-9)
    # Our joint-velocity term compares the joints (not the root's 6) with the desired state's;
    # without it the episode's task is an older run's (whose checkpoints then load).
    assert "target_joint_velocity" not in state.task
    with_joints = copy.copy(env)                            # the same env, other weights
    with_joints.settings = runup.RunupSettings(takeoff=x, k_takeoff_joints=0.5)
    _, with_joints_state = _begin(with_joints, x, 2)
    _, qd_goal = env.desired_state(jnp.asarray(x, jnp.float64))
    np.testing.assert_allclose(with_joints_state.task["target_joint_velocity"], qd_goal[6:],
                               atol=1e-12)
    mean_square = np.mean((np.asarray(qd)[6:] - np.asarray(qd_goal)[6:]) ** 2)
    assert mean_square > 0.1
    assert float(with_joints.task_reward(constructed, with_joints_state.task)) == \
        pytest.approx(by_hand * np.exp(-0.5 * mean_square), rel=1e-9)
    # The step before the take-off pays the imitation reward only ...
    step = jax.jit(env.step)
    state = step(params, state, jnp.zeros(env.action_size))
    assert not bool(state.terminated | state.truncated)
    assert float(state.reward) == pytest.approx(_imitation_reward(env, state), rel=1e-12)
    assert float(state.metrics["episode/takeoff_reward"]) == 0.0
    # ... the take-off step also w_takeoff r_G of the state it reaches, and ends the episode.
    state = step(params, state, jnp.zeros(env.action_size))
    assert bool(state.terminated) and not bool(state.truncated)
    assert float(state.metrics["episode/reached_takeoff"]) == 1.0
    omega, velocity = takeoff_state.facing_velocities(state.physics.q, state.physics.qd)
    r_g = np.exp(-np.sum(np.abs(np.asarray(omega) - [x[1], -3.0, x[2]])) / 3
                 - 0.7 * (float(velocity[2]) - x[3]) ** 2)
    assert float(state.reward) == pytest.approx(_imitation_reward(env, state) + 10.0 * r_g,
                                                rel=1e-9)
    assert float(state.metrics["episode/takeoff_reward"]) == pytest.approx(r_g, rel=1e-9)


# ---------------------------------------------------------------------- the take-off state

def test_the_desired_state_is_the_state_the_jump_starts_from(env, data_dir):
    jump_env = jump.JumpEnv(jump.HighJumpSettings(actions="pd"), data_dir, dtype=jnp.float64)
    assert jump_env.takeoff == env.takeoff
    reset, desired = jax.jit(jump_env.reset), jax.jit(env.desired_state)
    for x in takeoff_state.HIGHJUMP_ROWS.values():
        start = reset({**jump_env.default_params(), "takeoff": jnp.asarray(x)},
                      jax.random.PRNGKey(0))
        q, qd = desired(jnp.asarray(x))
        np.testing.assert_array_equal(q, start.physics.q)
        np.testing.assert_array_equal(qd, start.physics.qd)


def test_the_reference_is_grounded_and_the_grid_ends_at_the_take_off_time(env):
    t0 = env.takeoff.time
    np.testing.assert_allclose(env.reference(jnp.asarray(t0))[0], env.q0, atol=1e-6)
    K = env.runup_steps
    assert K == int(np.floor(t0 * 30 + 1e-4)) == 101            # the sprint takes off at 3.37 s
    assert env.first_start == pytest.approx(t0 - K / 30, abs=1e-9)
    assert abs(env.first_start) < 1 / 30                          # within a step of the start
    starts = jax.jit(jax.vmap(env.reset, (None, 0)))(
        env.default_params(), jax.random.split(jax.random.PRNGKey(0), 8)).task
    k = np.asarray(starts["to_takeoff"])
    assert ((1 <= k) & (k <= K)).all() and len(set(k.tolist())) > 1
    np.testing.assert_allclose(np.asarray(starts["start"]) + k / 30, t0, atol=1e-9)


@pytest.mark.parametrize("section, error", [
    ({"kind": "long_jump"}, "[runup]: kind must be one of highjump, obstacle"),
    ({"takeoff": [0.0, 1.0]}, "takeoff must give 4 numbers"),
    ({"kind": "obstacle", "takeoff": [0.0, 9.0, 1.0]}, "takeoff: omega_y = 9.0 is outside"),
    ({"start": "middle"}, "start must be one of random, clip_start"),
    ({"w_takeoff": -1.0}, "w_takeoff must be a finite number ≥ 0"),
    ({"kick": 1.0}, "unknown key 'runup.kick'"),
])
def test_bad_settings_name_their_key(section, error):
    with pytest.raises(ConfigError) as caught:
        train_commands.build_config({"run": {"task": "runup"}, "runup": section}, "c.toml")
    assert error in str(caught.value)


def test_the_config_and_a_clip_that_takes_off_too_soon(data_dir):
    config = train_commands.load_config("configs/highjump_runup.toml")
    assert config.task.x == FOSBURY and config.task.clip == "VC5_sprint__curves_03.txt"
    assert runup.RunupSettings(kind="obstacle").clip == "VC5_Run_jumpToBox_01.txt"
    with pytest.raises(ConfigError, match="control_hz: the clip takes off at 1.500 s"):
        runup.RunupEnv(runup.RunupSettings(kind="obstacle", control_hz=0.5,
                                           episode_seconds=10.0), data_dir)


# ------------------------------------------------------------------------- the full motion

def fresh_run(directory, task, section, data_dir):
    """A training run directory of a tiny, freshly initialised policy (iteration 0)."""
    config = train_commands.build_config(
        {"run": {"task": task, "envs": 2, "steps_per_iteration": 2, "iterations": 1},
         "ppo": {"minibatch_size": 4, "hidden": [8]}, task: section}, "test")
    directory.mkdir()
    trainer = train_commands.make_trainer(config, data_dir)
    trainer_lib.save_checkpoint(jax.jit(trainer.init)(), directory)
    (directory / train_commands.CONFIG).write_text(json.dumps(config.sections()))
    return directory


@pytest.fixture(scope="module")
def motion_run(data_dir, tmp_path_factory):
    """The full motion of an untrained run-up at 10 Hz (its grid then starts 0.067 s into the
    clip) and an untrained high jump (P-D actions, 0.5 m, 10 Hz)."""
    root = tmp_path_factory.mktemp("motion")
    runs = (fresh_run(root / "runup", "runup", {"control_hz": 10.0, "takeoff": list(FOSBURY)},
                      data_dir),
            fresh_run(root / "jump", "highjump", {"actions": "pd", "takeoff": list(FOSBURY)},
                      data_dir))
    summary, full = motion_commands.full_motion(*runs, root / "out", data_dir,
                                                echo=lambda *_: None)
    return root, runs, summary, full


def test_the_full_motion_switches_to_the_jump_policy_at_the_take_off_time(motion_run,
                                                                          data_dir):
    root, (runup_dir, jump_dir), summary, full = motion_run
    t0 = 3.366666555404663                                    # the sprint's take-off frame
    K = int(np.floor(t0 * 10 + 1e-4))                         # 33 steps at 10 Hz
    policy = np.asarray(full.policy)
    assert (policy[:K] == fm.RUNUP).all() and policy[K] == fm.JUMP
    assert fm.switch_step(full) == summary["switch_step"] == K
    times = fm.step_times(full)
    assert float(full.start_time) == pytest.approx(t0 - K / 10, abs=1e-6)   # 0.067 s
    assert summary["switch_time"] == pytest.approx(t0, abs=1e-6) == times[K - 1]
    assert summary["takeoff_time"] == pytest.approx(t0, abs=1e-6)
    # The run-up's own clock says take-off at the switch.
    assert float(full.runup_task["start"]) + K / 10 == pytest.approx(t0, abs=1e-6)
    # The jump starts from the run-up's state there, moved onto the jump's take-off frame.
    jump_env = motion_commands.load_run(jump_dir, data_dir, echo=lambda *_: None).env
    runup_env = motion_commands.load_run(runup_dir, data_dir, echo=lambda *_: None).env
    physics = jax.tree_util.tree_map(jnp.asarray, full.takeoff_physics)

    @jax.jit
    def hand_over(physics):
        fresh = jump_env.reset(jump_env.default_params(), jax.random.PRNGKey(0))
        started, move = fm.handover(runup_env, jump_env, physics, fresh)
        return started, move, move.pose_to_runup(started.physics.q)

    started, move, back = hand_over(physics)
    np.testing.assert_allclose(back, physics.q, atol=1e-5)
    np.testing.assert_array_equal(started.physics.qd, physics.qd)
    turned = rotations.quat_to_matrix(started.physics.q[3:7])
    np.testing.assert_allclose(takeoff_state.heading_rotation(turned), jump_env.heading,
                               atol=1e-5)
    np.testing.assert_allclose(np.asarray(started.physics.q)[[0, 2]],
                               np.asarray(jump_env.q0)[[0, 2]], atol=1e-5)
    np.testing.assert_allclose(move.turn, full.handover.turn, atol=1e-6)
    assert summary["jump"]["steps"] >= 1 and summary["jump"]["control_hz"] == 10.0


def test_the_full_motion_is_written_as_gif_bvh_and_summary(motion_run):
    root, _, summary, full = motion_run
    out = root / "out"
    assert json.loads((out / "summary.json").read_text()) == summary
    times, poses = fm.keyframes(full)
    clip = motion.load_bvh(out / "motion.bvh")
    frames = int(np.floor((times[-1] - times[0]) * 10 + 1e-9)) + 1
    assert clip.n_frames == summary["bvh"]["frames"] == frames
    assert clip.frame_time == pytest.approx(0.1)
    assert summary["bvh"]["max_joint_deviation_m"] < 1e-4
    from PIL import Image
    with Image.open(out / "motion.gif") as gif:
        assert gif.n_frames == frames
    assert (out / "filmstrip.png").stat().st_size > 0
    error = summary["takeoff_state_error"]
    assert 0.0 <= error["takeoff_reward"] <= 1.0
    assert error["omega_target"] == pytest.approx([FOSBURY[1], -3.0, FOSBURY[2]], abs=1e-6)


def test_a_jump_of_another_x_or_vertical_velocity_is_refused(motion_run, data_dir, capsys):
    root, (runup_dir, _), _, _ = motion_run
    other = fresh_run(root / "straddle", "highjump",
                      {"actions": "pd", "takeoff": list(takeoff_state.HIGHJUMP_ROWS["straddle"])},
                      data_dir)
    with pytest.raises(SystemExit) as caught:
        cli.main(["motion", str(runup_dir), str(other), "--out", str(root / "no"),
                  "--data-dir", str(data_dir)])
    assert "a run-up hands over to the jump of its own x" in str(caught.value)
    assert str(other) in str(caught.value)
    faster = fresh_run(root / "faster", "highjump",
                       {"actions": "pd", "takeoff": list(FOSBURY), "vertical_velocity": 2.0},
                       data_dir)
    with pytest.raises(SystemExit) as caught:
        cli.main(["motion", str(runup_dir), str(faster), "--out", str(root / "no"),
                  "--data-dir", str(data_dir)])
    assert "take-off vertical velocity of 2.000 m/s" in str(caught.value)
    with pytest.raises(SystemExit) as caught:
        cli.main(["motion", str(other), str(other), "--out", str(root / "no"),
                  "--data-dir", str(data_dir)])
    assert "RUNUP_DIR must be a runup run" in str(caught.value)


def test_the_jump_of_a_full_motion_can_be_put_at_another_bar(motion_run, data_dir):
    root, runs, summary, _ = motion_run
    assert summary["jump"]["bar"] == pytest.approx(0.5)             # its run's curriculum's
    higher, full = motion_commands.full_motion(*runs, root / "bar", data_dir, render=False,
                                               echo=lambda *_: None, bar=0.8)
    assert higher["jump"]["bar"] == pytest.approx(0.8)
    jump_env = motion_commands.load_run(runs[1], data_dir, echo=lambda *_: None).env
    bar = jump_env.world_for(jax.tree_util.tree_map(jnp.asarray, full.jump.task))
    assert float(bar.box_half_size[0][1]) == pytest.approx(0.4)     # a wall from 0 to 0.8 m
    with pytest.raises(SystemExit, match=r"--bar must be a bar height \(obstacle width\) > 0 "
                                         r"in m; got -1"):
        cli.main(["motion", *map(str, runs), "--out", str(root / "no"), "--bar", "-1",
                  "--data-dir", str(data_dir)])
    assert not (root / "no").exists()
