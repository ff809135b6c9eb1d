"""Training runs: the rollout's bookkeeping, learning on a small task, resume bit for bit, the
run directory and the command line."""

import dataclasses
import json
import os
import signal

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.commands import cli, train_commands
from agents.rl import trainer as trainer_lib
from agents.checkpoint import CheckpointError, previous_path
from agents.config import ConfigError
from agents.rl.env import end_of_step, start_of_episode
from agents.rl.ppo import PPOSettings
from agents.rl.rollout import make_rollout, start_runner
from agents.tasks.reach import ReachEnv, ReachSettings
from jaxsim import atomic
from jaxsim.atomic import OutputError, hold_directory
from conftest import tiny_highjump_training

CONFIG = "configs/reach.toml"


def small_run(tmp_path, iterations, name="run", extra=(), echo=lambda *_: None):
    """A short run of the reach config; every small run shares one compiled trainer."""
    overrides = [f"run.iterations={iterations}", "run.envs=16", "run.steps_per_iteration=16",
                 "run.checkpoint_every=2", "ppo.hidden=[16, 16]", "ppo.minibatch_size=64",
                 *extra]
    return train_commands.train(CONFIG, tmp_path / name, overrides, echo=echo)


def test_rollout_resets_finished_episodes_and_bootstraps_from_the_last_observation():
    env = ReachEnv(ReachSettings(episode_seconds=0.2), dtype=jnp.float64)   # 6 control steps
    trainer = trainer_lib.Trainer(env, env.default_params(),
                                  trainer_lib.RunSettings(task="reach", envs=3,
                                                          steps_per_iteration=14),
                                  PPOSettings(hidden=(8,), minibatch_size=8))
    state = trainer.init()
    rollout = jax.jit(make_rollout(env, trainer.policy_apply, trainer.value_apply, 14))
    runner = start_runner(env, trainer.env_params, jax.random.PRNGKey(1), 3)
    p = state.ppo
    _, batch, _, episodes, _, _ = rollout(
        trainer.env_params, runner, p.policy_params, p.value_params, state.norm, 0.3,
        jax.random.PRNGKey(2))
    truncated = np.asarray(batch.truncated)
    # Every environment is cut at its 6th and 12th step, never terminated (reaching never is).
    assert np.array_equal(np.flatnonzero(truncated[:, 0]), [5, 11])
    assert not np.asarray(batch.terminated).any()
    assert np.array_equal(np.asarray(episodes.ended), truncated)
    np.testing.assert_array_equal(np.asarray(episodes.lengths)[5], [6, 6, 6])
    rewards = np.asarray(batch.reward)
    np.testing.assert_allclose(np.asarray(episodes.returns)[11], rewards[6:12].sum(0),
                               rtol=1e-12)
    # next_value is the value of the step's own next observation: within an episode that is
    # the next step's observation, across a reset it is the old episode's last one.
    values = np.asarray(batch.value)
    next_values = np.asarray(batch.next_value)
    np.testing.assert_allclose(next_values[:5], values[1:6], rtol=1e-12)   # within an episode
    assert np.all(np.abs(next_values[5] - values[6]) > 0)                   # across the reset


class Countdown:
    """A toy environment: obs (steps so far, a random tag drawn at reset); reward 1 a step; the
    episode terminates at its third step."""

    observation_size, action_size, episode_steps = 2, 1, 100

    def default_params(self):
        return {}

    def reset(self, params, key):
        tag = jax.random.uniform(key, (), jnp.float64)
        return start_of_episode(jnp.zeros(()), jnp.stack([0.0, tag]), key, tag, {})

    def step(self, params, state, action):
        count = state.physics + 1.0
        return end_of_step(state, count, jnp.stack([count, state.task]), 1.0, count >= 3.0,
                           state.task, {}, self.episode_steps)


def test_rollout_resets_after_termination_and_bootstraps_nothing_there():
    env = Countdown()
    trainer = trainer_lib.Trainer(env, {}, trainer_lib.RunSettings(task="reach", envs=2,
                                                                   steps_per_iteration=8),
                                  PPOSettings(hidden=(8,), minibatch_size=8))
    state = trainer.init()
    p = state.ppo
    rollout = jax.jit(make_rollout(env, trainer.policy_apply, trainer.value_apply, 8))
    runner = start_runner(env, {}, jax.random.PRNGKey(3), 2)
    _, batch, raw_obs, episodes, _, _ = rollout({}, runner, p.policy_params, p.value_params,
                                                state.norm, 0.3, jax.random.PRNGKey(4))
    raw_obs = np.asarray(raw_obs)
    ended = np.asarray(episodes.ended)
    assert np.array_equal(np.flatnonzero(ended[:, 0]), [2, 5])      # every third step
    assert np.array_equal(np.asarray(batch.terminated), ended)
    np.testing.assert_array_equal(np.asarray(episodes.returns)[[2, 5]], 3.0)
    np.testing.assert_array_equal(np.asarray(episodes.lengths)[[2, 5]], 3)
    # The step after a termination starts a fresh episode: count 0 and a new tag ...
    np.testing.assert_array_equal(raw_obs[[3, 6], :, 0], 0.0)
    assert np.all(raw_obs[3, :, 1] != raw_obs[2, :, 1])
    # ... while next_value at the terminal step is V of the terminal observation (count 3, old
    # tag), not of the fresh one.
    terminal_obs = np.stack([np.full(2, 3.0), raw_obs[2, :, 1]], -1)
    expected = trainer.value_apply(p.value_params, state.norm.normalize(jnp.asarray(terminal_obs)))
    np.testing.assert_allclose(np.asarray(batch.next_value)[2], expected, rtol=1e-12)


def test_first_episode_mask_stops_after_each_environment_s_first_end():
    ended = np.array([[0, 0, 1], [1, 0, 0], [0, 0, 1], [1, 1, 0]], bool)
    np.testing.assert_array_equal(train_commands._first_episode_mask(ended),
                                  [[1, 1, 1], [1, 1, 0], [0, 1, 0], [0, 1, 0]])


def test_ppo_learns_to_reach(tmp_path):
    """Learning happens: the mean return of reaching rises from ~1 (random) past 15 of 30."""
    _, state = train_commands.train(CONFIG, tmp_path / "reach", ["run.iterations=160"],
                                    echo=lambda *_: None)
    records = trainer_lib.read_metrics(tmp_path / "reach")
    first, last = records[0], records[-10:]
    assert first["return"] < 5.0
    assert np.mean([r["return"] for r in last]) > 15.0
    assert np.mean([r["env/distance"] for r in last]) < 0.25


def test_resumed_run_equals_an_uninterrupted_one_bit_for_bit(tmp_path):
    _, straight = small_run(tmp_path, 4, "straight")
    small_run(tmp_path, 2, "resumed")
    _, resumed = train_commands.train(resume=tmp_path / "resumed",
                                      overrides=["run.iterations=4"], echo=lambda *_: None)
    for a, b in zip(jax.tree_util.tree_leaves(straight), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    lines = trainer_lib.read_metrics(tmp_path / "resumed")
    assert [r["iteration"] for r in lines] == [1, 2, 3, 4]
    # The training clock goes on from the checkpoint's, so curves against minutes continue.
    seconds = [r["seconds"] for r in lines]
    assert all(b > a for a, b in zip(seconds, seconds[1:]))


def test_run_directory_metrics_and_curve(tmp_path):
    small_run(tmp_path, 3)
    run_dir = tmp_path / "run"
    for name in ("config.json", "metrics.jsonl", "checkpoint.msgpack", "learning_curve.png"):
        assert (run_dir / name).exists(), name
    record = trainer_lib.read_metrics(run_dir)[-1]
    for key in ("samples", "samples_per_second", "return", "episode_length", "policy_loss",
                "value_loss", "sigma", "approx_kl", "clip_fraction"):
        assert key in record, key
    assert record["samples"] == 3 * 16 * 16
    config = json.loads((run_dir / "config.json").read_text())
    assert config["run"]["envs"] == 16 and config["ppo"]["hidden"] == [16, 16]
    with pytest.raises(ConfigError, match="already holds a run"):
        small_run(tmp_path, 3)


def test_ctrl_c_saves_a_checkpoint_that_resumes(tmp_path):
    progress = []

    def interrupt_at_the_second_progress_line(line):
        if line.startswith("iter"):     # (lines before: the run, and a compile if not cached)
            progress.append(line)
            if len(progress) == 2:
                raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        small_run(tmp_path, 5, extra=["run.checkpoint_every=100", "run.progress_every=1"],
                  echo=interrupt_at_the_second_progress_line)
    resumed = []
    trainer, state = train_commands.train(resume=tmp_path / "run", echo=resumed.append)
    assert resumed[0] == f"resuming {tmp_path / 'run'} at iteration 2"
    assert int(state.ppo.iteration) == 5
    assert [r["iteration"] for r in trainer_lib.read_metrics(tmp_path / "run")] == [1, 2, 3, 4, 5]


def test_sigterm_stops_after_its_iteration_with_a_checkpoint_that_resumes(tmp_path):
    """A SIGTERM (a batch system's preemption, `kill`) to a one-process run is noted, not fatal:
    the run ends the iteration it arrived in, checkpoints it, and stops as a Ctrl-C does, even
    when it arrives with the last iteration; the handler is put back afterwards."""
    before = signal.getsignal(signal.SIGTERM)
    lines, sent_after = [], []

    def terminate_after_the_first_progress_line(line):
        lines.append(line)
        if line.startswith("iter") and not sent_after:
            sent_after.append(int(line.split()[1].split("/")[0]))
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        small_run(tmp_path, 8, extra=["run.checkpoint_every=100", "run.progress_every=1"],
                  echo=terminate_after_the_first_progress_line)
    assert signal.getsignal(signal.SIGTERM) is before
    logged = [r["iteration"] for r in trainer_lib.read_metrics(tmp_path / "run")]
    # It stops after the iteration the signal arrived in (the one after the line's).
    assert logged == list(range(1, sent_after[0] + 2))
    assert lines[-1] == (f"\ninterrupted: checkpoint at iteration {logged[-1]} in "
                         f"{tmp_path / 'run'}")
    # Resumed where it stopped, and sent a SIGTERM with its last iteration's line: the run
    # was ending anyway, but one that returned would let its caller (a search's next
    # evaluation, Stage 2's next round) start another training.
    resumed = []

    def terminate_at_the_last_line(line):
        resumed.append(line)
        if line.startswith("iter     8/8"):
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        train_commands.train(resume=tmp_path / "run", echo=terminate_at_the_last_line)
    assert resumed[0] == f"resuming {tmp_path / 'run'} at iteration {logged[-1]}"
    assert resumed[-1].startswith("\ninterrupted: checkpoint at iteration 8")
    assert signal.getsignal(signal.SIGTERM) is before
    assert [r["iteration"] for r in trainer_lib.read_metrics(tmp_path / "run")] == list(
        range(1, 9))


def test_eval_reports_and_renders(tmp_path, capsys):
    small_run(tmp_path, 2)
    assert cli.main(["eval", str(tmp_path / "run"), "--episodes", "3",
                     "--render", str(tmp_path / "reach.gif")]) == 0
    out = capsys.readouterr().out
    summary = json.loads(out[out.index("{"): out.rindex("}") + 1])
    assert summary["episodes"] == 3 and summary["episode_length"] == 30
    assert (tmp_path / "reach.gif").stat().st_size > 1000
    assert cli.main(["plot", str(tmp_path / "run")]) == 0


@pytest.mark.parametrize("override, message", [
    ("run.envs=0", "envs must be at least 1"),
    ("run.task=juggling", "run.task must be one of"),
    ("ppo.lam=1.5", "lam must be in"),
    ("ppo.clip=true", "'ppo.clip' must be a float"),
    ("reach.sim_hz=100.0", "whole multiple"),
    ("run.batch=3", "unknown key 'run.batch'"),
    ("ppo.policy_lr=inf", "'ppo.policy_lr' must be a finite number; got inf"),
    ("ppo.policy_lr=-1.0", "policy_lr must be a finite number > 0; got -1.0"),
    ("ppo.sigma_horizon=inf", "'ppo.sigma_horizon' must be a finite number"),
    ("ppo.max_grad_norm=-0.5", "max_grad_norm must be a finite number ≥ 0; got -0.5"),
    ("reach.episode_seconds=0.01", "episode_seconds must last at least one control step"),
    ("run.envs=2", r"run\.envs × run\.steps_per_iteration = 2 × 30 = 60 samples per iteration, "
                   r"fewer than one minibatch \(ppo\.minibatch_size = 256\)"),
])
def test_config_errors_name_the_file_and_key_and_write_nothing(tmp_path, override, message):
    with pytest.raises(SystemExit, match=message) as error:
        cli.main(["train", CONFIG, "--out", str(tmp_path / "r"), "--set", override])
    assert CONFIG in str(error.value)
    assert not (tmp_path / "r").exists()


def test_a_task_setting_that_does_not_fit_the_data_names_the_config_file(tmp_path, data_dir):
    config = "configs/imitate_walk.toml"
    with pytest.raises(SystemExit, match=rf"{config}: \[imitation\]: clip: no file 'walk\.txt'"):
        cli.main(["train", config, "--out", str(tmp_path / "r"), "--data-dir", str(data_dir),
                  "--set", "imitation.clip=walk.txt"])
    assert not (tmp_path / "r").exists()


def test_a_run_that_goes_non_finite_stops_and_keeps_the_last_checkpoint(tmp_path):
    """Resumed with an absurd policy learning rate, the third iteration's policy diverges to
    inf and NaN: the run stops with a message naming the iteration and what went non-finite,
    and neither the checkpoint of iteration 2 nor the log is touched."""
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"
    checkpoint = (run_dir / trainer_lib.CHECKPOINT).read_bytes()
    with pytest.raises(SystemExit) as error:
        cli.main(["train", "--resume", str(run_dir), "--set", "run.iterations=6",
                  "--set", "ppo.policy_lr=1e38"])
    message = str(error.value)
    assert message.startswith(f"takeoff train: {run_dir}: iteration 3 produced non-finite ")
    assert "policy loss" in message and "policy parameters" in message
    assert "value loss" not in message and "value parameters" not in message
    assert "rewards" not in message and "observation statistics" not in message
    assert "checkpoint of iteration 2" in message
    assert (run_dir / trainer_lib.CHECKPOINT).read_bytes() == checkpoint
    assert [r["iteration"] for r in trainer_lib.read_metrics(run_dir)] == [1, 2]


@pytest.mark.parametrize("override", ["run.seed=5", "run.envs=8", "run.steps_per_iteration=8",
                                      "ppo.hidden=[8, 8]"])
def test_resume_refuses_to_change_what_the_checkpoint_fixes(tmp_path, override):
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"
    recorded = (run_dir / "config.json").read_text()
    key = override.split("=")[0]
    with pytest.raises(ConfigError, match=rf"config\.json: {key} cannot change when a run is "
                                          "resumed"):
        train_commands.train(resume=run_dir, overrides=[override, "run.iterations=3"],
                             echo=lambda *_: None)
    assert (run_dir / "config.json").read_text() == recorded
    assert [r["iteration"] for r in trainer_lib.read_metrics(run_dir)] == [1, 2]


def test_resume_accepts_a_fixed_key_at_the_run_s_own_value(tmp_path):
    small_run(tmp_path, 2)
    _, state = train_commands.train(resume=tmp_path / "run", echo=lambda *_: None,
                                    overrides=["run.iterations=3", "run.seed=0"])
    assert int(state.ppo.iteration) == 3


def test_a_run_another_process_holds_is_refused_and_left_as_it_was(tmp_path):
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"

    def contents():
        return {p.name: p.read_bytes() for p in run_dir.iterdir() if p.name != atomic.LOCK_FILE}

    before = contents()
    with hold_directory(run_dir, "the run"):        # as another process training it would
        with pytest.raises(OutputError, match=rf"{run_dir}: the run is in use by process "):
            train_commands.train(resume=run_dir, overrides=["run.iterations=3"],
                                 echo=lambda *_: None)
        assert contents() == before
        with hold_directory(tmp_path / "new", "the run"):   # a new run's directory alike
            with pytest.raises(OutputError, match="new: the run is in use by process "):
                small_run(tmp_path, 2, name="new")
    assert not (tmp_path / "new" / "metrics.jsonl").exists()
    _, state = train_commands.train(resume=run_dir, overrides=["run.iterations=3"],
                                    echo=lambda *_: None)
    assert int(state.ppo.iteration) == 3


def test_the_minutes_axis_interpolates_the_log_and_extends_it_at_its_mean_rate():
    records = [{"samples": 100, "seconds": 60.0}, {"samples": 200, "seconds": 240.0},
               {"samples": 300, "seconds": 300.0}]
    to_minutes, to_samples = train_commands.minutes_axis(records)
    np.testing.assert_allclose(to_minutes(np.array([100, 150, 250, 300])), [1, 2.5, 4.5, 5])
    # Past the ends the mean rate, 4 minutes per 200 samples: a tick at 7 minutes lies
    # beyond the last sample, not on it.
    np.testing.assert_allclose(to_minutes(np.array([0, 400])), [-1, 7])
    np.testing.assert_allclose(to_samples(np.array([7.0, 4.5])), [400, 250])


def test_reach_reset_keeps_a_key_it_did_not_draw_with():
    """A reset that keeps the key it drew from hands the rollout a key whose splits are the
    keys already drawn with (jax.random.split(k, 2)[0] == jax.random.split(k, 3)[0])."""
    env = ReachEnv()
    key = jax.random.PRNGKey(7)
    state = env.reset(env.default_params(), key)
    kept = np.asarray(state.key)
    assert not np.array_equal(kept, np.asarray(key))
    # Nor is it, or a first split of it, any key that a split of the reset key can give.
    for n in range(2, 6):
        for drawn in np.asarray(jax.random.split(key, n))[1:]:
            assert not np.array_equal(kept, drawn)
            assert not np.array_equal(np.asarray(jax.random.split(state.key, 2)[0]), drawn)


def test_train_needs_a_config_or_a_run_to_resume(tmp_path):
    with pytest.raises(SystemExit, match="CONFIG"):
        cli.main(["train"])
    with pytest.raises(SystemExit, match="config.json"):
        cli.main(["train", "--resume", str(tmp_path)])
    small_run(tmp_path, 1)                          # as if it died before its first checkpoint
    (tmp_path / "run" / trainer_lib.CHECKPOINT).unlink()
    with pytest.raises(SystemExit, match=r"checkpoint\.msgpack: missing; the run has no "
                                         "checkpoint"):
        cli.main(["train", "--resume", str(tmp_path / "run")])


def test_a_checkpoint_that_does_not_fit_names_the_leaf(tmp_path):
    small_run(tmp_path, 2)
    config = train_commands.load_run_config(tmp_path / "run")
    other = train_commands.make_trainer(dataclasses.replace(
        config, ppo=dataclasses.replace(config.ppo, hidden=(8, 16))))
    with pytest.raises(CheckpointError, match=r"checkpoint\.msgpack: \.ppo\.policy_params"
                                              r"\['Dense_0'\]\['bias'\] is float32\[16\] in "
                                              r"the file but this run's config needs float32\[8\]"):
        trainer_lib.load_checkpoint(other.init(), tmp_path / "run")


def test_a_torn_run_config_is_a_config_error_naming_the_file(tmp_path):
    (tmp_path / "config.json").write_text('{"run": {"task": ')
    with pytest.raises(ConfigError, match="config.json: not a readable run config"):
        train_commands.load_run_config(tmp_path)


# ---- Faults: damaged run files, output folders, sizes (issue 23) -----------------------------

def _echoed():
    lines = []
    return lines, lambda line="": lines.append(str(line))


def _damage(path, at=0.5, count=400):
    """Overwrite `count` bytes of the file in its middle, as a disk fault would."""
    data = bytearray(path.read_bytes())
    start = int(len(data) * at)
    data[start:start + count] = bytes(range(256)) * (count // 256) + bytes(count % 256)
    path.write_bytes(bytes(data))


def test_a_damaged_checkpoint_is_refused_and_the_previous_one_resumed(tmp_path, capsys):
    small_run(tmp_path, 4)                   # checkpoints at iterations 2 and 4
    run_dir = tmp_path / "run"
    _damage(run_dir / trainer_lib.CHECKPOINT)
    lines, echo = _echoed()
    _, state = train_commands.train(resume=run_dir, overrides=["run.iterations=5"], echo=echo)
    warning = next(line for line in lines if line.startswith("warning"))
    assert "checkpoint.msgpack: damaged" in warning and "checkpoint.previous.msgpack" in warning
    assert any("resuming" in line and "at iteration 2" in line for line in lines)
    assert int(state.ppo.iteration) == 5
    assert [r["iteration"] for r in trainer_lib.read_metrics(run_dir)] == [1, 2, 3, 4, 5]
    # With both damaged, nothing is run from either.
    _damage(run_dir / trainer_lib.CHECKPOINT)
    _damage(run_dir / "checkpoint.previous.msgpack")
    with pytest.raises(SystemExit, match=r"checkpoint\.msgpack: damaged"):
        cli.main(["eval", str(run_dir), "--episodes", "2"])


def test_eval_prints_strict_json_and_fails_when_its_numbers_are_not_finite(tmp_path, capsys):
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"
    config = train_commands.load_run_config(run_dir)
    trainer = train_commands.make_trainer(config)
    state = trainer_lib.load_checkpoint(trainer.init(), run_dir)
    broken = jax.tree_util.tree_map(lambda x: jnp.full_like(x, jnp.nan), state.ppo.policy_params)
    state = dataclasses.replace(state, ppo=dataclasses.replace(state.ppo, policy_params=broken))
    trainer_lib.save_checkpoint(state, run_dir)
    with pytest.raises(SystemExit, match="came out non-finite"):
        cli.main(["eval", str(run_dir), "--episodes", "2"])
    out = capsys.readouterr().out
    strict = json.loads(out[out.index("{"): out.rindex("}") + 1],
                        parse_constant=lambda name: pytest.fail(f"{name} in the JSON"))
    assert strict["distance"] is None


def test_a_torn_or_missing_metrics_log_is_named_on_resume_and_its_text_kept(tmp_path):
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"
    log = run_dir / trainer_lib.METRICS
    text = log.read_text()
    log.write_text(text[:-40])               # the record of iteration 2 cut off
    lines, echo = _echoed()
    train_commands.train(resume=run_dir, overrides=["run.iterations=3"], echo=echo)
    warnings = [line for line in lines if line.startswith("warning")]
    assert "its last line was cut off" in warnings[0] and "metrics.jsonl.torn" in warnings[0]
    assert "no record of iteration 2 " in warnings[1]
    assert (run_dir / "metrics.jsonl.torn").read_text() == text.splitlines()[1][:-39] + "\n"
    assert [r["iteration"] for r in trainer_lib.read_metrics(run_dir)] == [1, 3]
    log.unlink()
    lines, echo = _echoed()
    train_commands.train(resume=run_dir, overrides=["run.iterations=4"], echo=echo)
    assert any("no record of iterations 1–3" in line and "clock starts again" in line
               for line in lines)


def test_plot_of_a_log_with_a_bad_line_is_one_error_naming_it(tmp_path):
    small_run(tmp_path, 2)
    log = tmp_path / "run" / trainer_lib.METRICS
    lines = log.read_text().splitlines()
    log.write_text(lines[0][:30] + "\n" + lines[1] + "\n")
    with pytest.raises(SystemExit, match=r"takeoff plot: .*metrics\.jsonl, line 1: not a log "
                                         "record"):
        cli.main(["plot", str(tmp_path / "run")])


def test_an_output_folder_that_cannot_be_written_fails_before_compiling(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    lines, echo = _echoed()
    with pytest.raises(OutputError, match=r"a_file/run: cannot write the run's checkpoints "
                                          "there"):
        train_commands.train(CONFIG, blocker / "run", ["run.iterations=1"], echo=echo)
    assert lines == []                       # nothing compiled, nothing trained
    monkeypatch.setattr(atomic.shutil, "disk_usage",
                        lambda _: type("Usage", (), {"free": 1000})())
    with pytest.raises(SystemExit, match=r"the run's checkpoints needs [\d.,]+ MB on disk, and "
                                         r"only 0\.0 MB is free there"):
        cli.main(["train", CONFIG, "--out", str(tmp_path / "full")])


def test_a_failed_checkpoint_write_is_the_error_reported_and_the_last_one_kept(
        tmp_path, monkeypatch):
    small_run(tmp_path, 2)
    run_dir = tmp_path / "run"
    kept = (run_dir / trainer_lib.CHECKPOINT).read_bytes()

    def full_disk(*_):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(trainer_lib, "write_msgpack", full_disk)
    monkeypatch.setattr(train_commands, "plot", full_disk)     # the curve fails as well
    lines, echo = _echoed()
    with pytest.raises(CheckpointError, match=r"checkpoint\.msgpack: could not be written "
                                              r"\(No space left on device\)"):
        train_commands.train(resume=run_dir, overrides=["run.iterations=4"], echo=echo)
    assert any("learning curve was not drawn" in line for line in lines)
    assert (run_dir / trainer_lib.CHECKPOINT).read_bytes() == kept


def test_progress_says_it_compiles_and_leaves_compile_time_out_of_the_estimate(tmp_path):
    lines, echo = _echoed()
    small_run(tmp_path, 2, extra=["run.seed=11"], echo=echo)   # a new trainer: it compiles
    assert lines[1] == "compiling the rollout and the PPO update…"
    assert lines[2].startswith("compiled, and ran the iteration, in ")
    iterations = [line for line in lines if line.startswith("iter")]
    assert iterations[0].endswith("left —")
    assert not iterations[1].endswith("left —")


@pytest.mark.parametrize("override, message", [
    ("run.envs=1000000000000", r"'run\.envs' is 1000000000000, beyond the ±2,147,483,647"),
    ("run.envs=2000000000", r"run\.envs × run\.steps_per_iteration = 2000000000 × 30 needs at "
                            r"least [\d,.]+ GB of memory"),
    ("reach.episode_seconds=1e12", r"an episode may have at most 2,147,483,647 simulation "
                                   "steps"),
    ("ppo.clip=nan", r"'ppo\.clip' must be a finite number; got nan"),
])
def test_sizes_and_numbers_that_cannot_run_are_refused_up_front(tmp_path, override, message):
    with pytest.raises(SystemExit, match=message):
        cli.main(["train", CONFIG, "--out", str(tmp_path / "r"), "--set", override])
    assert not (tmp_path / "r" / trainer_lib.CHECKPOINT).exists()


def test_a_directory_or_an_empty_file_is_not_a_config(tmp_path):
    with pytest.raises(SystemExit, match=r"is a directory, not a config file"):
        cli.main(["train", str(tmp_path)])
    (tmp_path / "empty.toml").write_text("")
    with pytest.raises(SystemExit, match=r"empty\.toml: the file holds no settings"):
        cli.main(["train", str(tmp_path / "empty.toml")])


@pytest.mark.parametrize("stop", ["run.iterations=3", "run.time_limit_minutes=1e-6"])
def test_the_record_that_says_a_run_stopped_is_logged_after_its_checkpoint(
        tmp_path, monkeypatch, stop):
    """A run killed just after logging its last record must not leave a log that says
    "finished" beside an older checkpoint (the commands that resume trainings would measure
    that older policy): when the last record is appended, the final checkpoint is on disk."""
    append, on_disk = trainer_lib.runlog.append, {}

    def append_noting_the_checkpoint(path, record):
        checkpoint = path.parent / trainer_lib.CHECKPOINT
        on_disk[record["iteration"]] = checkpoint.read_bytes() if checkpoint.exists() else None
        append(path, record)

    monkeypatch.setattr(trainer_lib.runlog, "append", append_noting_the_checkpoint)
    small_run(tmp_path, 5, extra=["run.checkpoint_every=100", stop])
    run_dir = tmp_path / "run"
    last = trainer_lib.read_metrics(run_dir)[-1]["iteration"]
    assert last == (3 if "iterations" in stop else 1)
    assert on_disk[last] == (run_dir / trainer_lib.CHECKPOINT).read_bytes()
    assert not previous_path(run_dir / trainer_lib.CHECKPOINT).exists()   # saved once


def test_trainings_that_differ_only_in_the_take_off_state_compile_one_rollout(tmp_path, data_dir):
    """The task parameters are an argument of the compiled rollout, not constants in it: the
    evaluations of a strategy search, each from its own x, compile the same program (which a
    persistent compilation cache finds), and each still rolls out from its own x."""
    config = tmp_path / "tiny.toml"
    config.write_text(tiny_highjump_training(1))
    programs, starts = [], []
    for x in ([-0.05, -3.0, 1.0, -2.4], [1.65, 1.0, 0.88, -2.21]):
        trainer = train_commands.make_trainer(
            train_commands.load_config(config, [f"highjump.takeoff={x}"]), data_dir)
        state = trainer.init()
        programs.append(trainer.rollout_program(state.curriculum).lower(
            state, trainer.env_params).as_text())
        np.testing.assert_allclose(trainer.env_params["takeoff"], x, rtol=1e-6)
        starts.append(np.asarray(state.runner.envs.physics.qd))
    assert programs[0] == programs[1]
    assert not np.allclose(starts[0], starts[1])
