"""The real black box of strategy discovery: g(x) trains a jump policy from x, end to end, with a
failure recorded, and a search killed mid-training resumes that training from its checkpoint."""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from agents.commands import strategy_search
from agents.discovery import jump_black_box
from agents.rl import trainer as trainer_lib
from bds.search import Failure, SearchError, logged_evaluations
from conftest import tiny_highjump_training


def _search_config(tmp_path, samples, give_up_samples=0):
    train = tmp_path / "train.toml"
    train.write_text(tiny_highjump_training(iterations=1000))
    config = tmp_path / "search.toml"
    config.write_text(f"""
black_box = "jump"
[search]
strategy = "random"
budget = 1
feature_low = [0.0]
feature_high = [3.14159]
[jump]
train = "{train}"
samples = {samples}
give_up_samples = {give_up_samples}
episodes = 2
""")
    return config


def _metrics(run_dir):
    return [json.loads(line) for line in (run_dir / trainer_lib.METRICS).read_text().splitlines()]


def test_a_search_killed_mid_training_resumes_it_and_records_the_failure(tmp_path, data_dir):
    """`takeoff search` is killed (SIGKILL) while its first evaluation trains; run again, the
    training goes on from its checkpoint (the iterations logged before the kill are kept, none
    is repeated), is given up after 12 of its 24 iterations (no episode of the tiny training
    can succeed), the evaluation ends as a recorded failure with its files, and a third run
    trains and evaluates nothing."""
    config = _search_config(tmp_path, samples=16 * 24, give_up_samples=16 * 12)
    out = tmp_path / "search"
    train_dir = jump_black_box.evaluation_dir(out, 0) / jump_black_box.TRAIN
    # the resumed search, like the killed one, in float32 and in its own process: it finds the
    # killed one's compiled programs in the cache
    env = {**os.environ, "TAKEOFF_DATA": str(data_dir),
           "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax_cache"),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    command = [sys.executable, "-m", "agents.commands.cli", "search", str(config), "--out",
               str(out)]
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    deadline = time.monotonic() + 900
    while not ((train_dir / trainer_lib.METRICS).exists() and len(_metrics(train_dir)) >= 3):
        assert process.poll() is None, process.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "the search did not train 3 iterations in 15 min"
        time.sleep(0.2)
    process.send_signal(signal.SIGKILL)
    process.wait()
    checkpointed = trainer_lib.completed_iterations(trainer_lib.load_checkpoint(
        _template(train_dir, data_dir), train_dir, echo=lambda *_: None))
    assert 1 <= checkpointed < 12
    before = [r for r in _metrics(train_dir) if r["iteration"] <= checkpointed]
    assert not (out / "evaluations.jsonl").exists() or not logged_evaluations(
        out / "evaluations.jsonl")

    resumed = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-2000:]

    after = _metrics(train_dir)
    assert [r["iteration"] for r in after] == list(range(1, 13))
    assert after[:checkpointed] == before          # kept as they were, not trained again
    [record] = logged_evaluations(out / "evaluations.jsonl")
    assert record["feature"] is None and "cleared 0 of 2 episodes at 0.50 m" in record["failure"]
    assert "given up" in record["failure"]
    assert "0 distinct strategies in 1 evaluations, 1 failed" in resumed.stdout, resumed.stdout
    directory = jump_black_box.evaluation_dir(out, 0)
    stored = json.loads((directory / jump_black_box.RESULT).read_text())
    assert stored["outcome"] == "failure" and stored["samples"] == 16 * 12 and stored["gave_up"]
    np.testing.assert_allclose(stored["x"], record["x"])
    episode = np.load(directory / jump_black_box.EPISODE)
    assert episode["poses"].shape[0] >= 1 and (directory / jump_black_box.PEAK).stat().st_size

    log_text = (out / "evaluations.jsonl").read_text()
    result = strategy_search.run(config, out, data_dir=data_dir, echo=lambda *_: None)
    assert result.failures == [record["failure"]] and np.isnan(result.features).all()
    assert (out / "evaluations.jsonl").read_text() == log_text
    assert _metrics(train_dir) == after


@pytest.mark.parametrize("success, gives_up", [(0.01, True), (0.02, False)])
def test_a_training_is_given_up_by_its_record_at_the_give_up_point(success, gives_up):
    """The give-up rule reads the record at its point, not the last one: a search killed in
    the next leg does not give up a training that has since fallen back."""
    settings = jump_black_box.JumpBlackBoxSettings(give_up_samples=400, give_up_success=0.01)
    [(iteration, judge)] = jump_black_box.JumpBlackBox(settings, None).give_up_points(100)
    assert iteration == 4
    records = [{"iteration": i, "samples": 100 * i, "seconds": 1.0 * i, "env/episode/success": s}
               for i, s in ((3, 0.0), (4, success), (5, 0.0))]
    why = judge(records, iteration)
    assert (why == f"{success:.1%} of the episodes succeeded after 400 samples (given up at "
                   "1.0% or less)") == gives_up
    assert gives_up or why is None
    # an iteration in which no episode ended is judged by the last one before it that had one
    records[1]["env/episode/success"] = None
    assert judge(records, iteration) == "0.0% of the episodes succeeded after 400 samples " \
                                        "(given up at 1.0% or less)"
    with pytest.raises(SearchError, match="no episode ended in the training's first 4"):
        judge([{**r, "env/episode/success": None} for r in records], iteration)
    with pytest.raises(SearchError, match="metrics do not have"):
        judge([{"iteration": 4}], iteration)


@pytest.mark.parametrize("shares, gives_up", [((0.0, 0.06, 0.09), True),
                                              ((0.04, 0.06, 0.08), False)])
def test_the_probe_gives_up_by_the_crossing_share_of_the_first_iterations(shares, gives_up):
    """The probe point averages the crossing share of iterations 1 … its point (a record past
    it, of a training resumed beyond, does not count), and comes before the success point."""
    settings = jump_black_box.JumpBlackBoxSettings(samples=10_000, probe_samples=300,
                                                   probe_crossing=0.05, give_up_samples=2000)
    box = jump_black_box.JumpBlackBox(settings, None)
    points = box.give_up_points(100)
    assert [iteration for iteration, _ in points] == [3, 20]
    later = dataclasses.replace(settings, probe_samples=3000)
    assert [judge.__name__ for _, judge in jump_black_box.JumpBlackBox(
        later, None).give_up_points(100)] == ["_too_few_succeeded", "_too_few_crossed"]
    records = [{"iteration": i + 1, "env/episode/crossed": s} for i, s in enumerate(shares)]
    records.append({"iteration": 4, "env/episode/crossed": 1.0})
    why = points[0][1](records, 3)
    assert (why == "5.0% of its first 3 iterations' episodes crossed the bar's plane (given up "
                   "at 5.0% or less)") == gives_up
    assert gives_up or why is None
    assert points[0][1]([{"iteration": 1, "env/episode/crossed": None},   # no episode ended
                         {"iteration": 2, "env/episode/crossed": 0.2}], 3) is None
    with pytest.raises(SearchError, match="env/episode/crossed, which this task's metrics"):
        points[0][1]([{"iteration": 1, "env/episode/success": 0.0}], 3)
    with pytest.raises(SearchError, match="no episode ended .* set probe_samples later"):
        points[0][1]([{"iteration": 1, "env/episode/crossed": None}], 3)
    # off at 0, and a point at or past the budget is never reached
    assert jump_black_box.JumpBlackBox(jump_black_box.JumpBlackBoxSettings(
        samples=300, probe_samples=300, give_up_samples=0), None).give_up_points(100) == []


@pytest.mark.parametrize("crossed, success, stops_at, legs, why", [
    (0.01, 0.0, None, [3], "crossed the bar's plane"),        # given up at the probe point
    (0.10, 0.0, None, [3, 20], "succeeded after 81,920"),     # at the success point
    (0.10, 0.5, None, [3, 20, 50], None),                     # trained to its budget
    (0.01, 0.0, 2, [3, 20, 50], None),                        # stopped before the probe point
])
def test_a_training_stops_at_the_first_give_up_point_that_judges_it_going_nowhere(
        monkeypatch, tmp_path, crossed, success, stops_at, legs, why):
    """`train` trains leg by leg to each give-up point and to its budget, judges the training
    at each point it reached, and returns the first point's reason; a training that stopped
    short of a point (at z_freeze, or out of minutes) is not judged there."""
    from pathlib import Path
    from agents.commands import train_commands
    config = Path(__file__).resolve().parent.parent / "configs" / "highjump.toml"
    settings = jump_black_box.JumpBlackBoxSettings(
        train=str(config), samples=50 * 4096, probe_samples=3 * 4096, give_up_samples=20 * 4096)
    records, trained = [], []

    def fake_training(config_path, run_dir, overrides, *args):
        end = next(int(o.split("=")[1]) for o in overrides if o.startswith("run.iterations="))
        trained.append(end)
        end = min(end, stops_at or end)
        records.extend({"iteration": i, "env/episode/crossed": crossed,
                        "env/episode/success": success} for i in range(len(records) + 1, end + 1))
    monkeypatch.setattr(train_commands, "train_or_resume", fake_training)
    monkeypatch.setattr(trainer_lib, "read_metrics", lambda run_dir: list(records))
    box = jump_black_box.JumpBlackBox(settings, tmp_path)
    assert [iteration for iteration, _ in box.give_up_points(4096)] == [3, 20]
    given_up = box.train(tmp_path / "000" / "train", [1.0, 0.0, 0.0, -2.0])
    assert trained == legs
    assert given_up is None if why is None else why in given_up
    fields = {"gave_up": True, "gave_up_because": given_up} if given_up else {}
    assert jump_black_box._given_up(fields) == (f", given up: {given_up}" if given_up else "")


@pytest.mark.parametrize("leg, last, minutes, trained", [
    (50, None, 0.0, False),                                               # no checkpoint
    (50, {"iteration": 20, "seconds": 60.0}, 0.0, False),                 # killed
    (20, {"iteration": 20, "seconds": 60.0}, 0.0, True),                  # at a give-up point
    (50, {"iteration": 50, "seconds": 60.0}, 0.0, True),                  # all of its samples
    (50, {"iteration": 20, "seconds": 60.0, trainer_lib.DIFFICULTY: 1.0}, 0.0, True),  # z_freeze
    (50, {"iteration": 20, "seconds": 299.0}, 5.0, False),                # minutes left
    (50, {"iteration": 20, "seconds": 300.0}, 5.0, True),                 # its minutes spent
])
def test_a_training_is_trained_when_its_last_leg_ended_on_its_own(tmp_path, leg, last, minutes,
                                                                 trained):
    """`trained` (Stage 2's test of a Stage-1 policy): the training ran the iterations its last
    leg asked for, reached z_freeze, or spent the black box's `minutes` counted over every
    resume. The run's stored time limit is the minutes left when it was last resumed (1 here),
    which is no measure of that."""
    from pathlib import Path
    from agents.commands import train_commands
    highjump = Path(__file__).resolve().parent.parent / "configs" / "highjump.toml"
    settings = jump_black_box.JumpBlackBoxSettings(train=str(highjump), samples=50 * 4096,
                                                   minutes=minutes, z_freeze=1.0)
    box = jump_black_box.JumpBlackBox(settings, tmp_path)
    run_dir = tmp_path / "train"
    run_dir.mkdir()
    config = train_commands.load_config(highjump, [f"run.iterations={leg}",
                                                   "run.stop_difficulty=1.0",
                                                   "run.time_limit_minutes=1.0"])
    (run_dir / train_commands.CONFIG).write_text(json.dumps(config.sections()))
    if last is not None:
        (run_dir / trainer_lib.CHECKPOINT).write_bytes(b"")
        record = {**last, "samples": 4096 * last["iteration"]}
        (run_dir / trainer_lib.METRICS).write_text(json.dumps(record) + "\n")
    assert box.trained(run_dir) is trained


def test_the_give_up_settings_are_checked():
    for name in ("give_up_success", "probe_crossing"):
        with pytest.raises(ValueError, match=name):
            jump_black_box.JumpBlackBoxSettings(**{name: 1.0})
    for name in ("give_up_samples", "probe_samples"):
        with pytest.raises(ValueError, match=name):
            jump_black_box.JumpBlackBoxSettings(**{name: -1})


def _template(train_dir, data_dir):
    from agents.commands import train_commands
    config = train_commands.load_run_config(train_dir)
    return train_commands.make_trainer(config, data_dir).init()


def test_an_evaluation_with_a_result_is_not_run_again_and_another_search_s_is_refused(tmp_path):
    """A result.json written before the kill (the log line lost) is what g returns; one for
    another x means the directory belongs to another search."""
    box = jump_black_box.JumpBlackBox(jump_black_box.JumpBlackBoxSettings(), tmp_path)
    directory = jump_black_box.evaluation_dir(tmp_path, 3)
    directory.mkdir(parents=True)
    x = [0.1, -1.0, 2.0, -1.5]
    result = {"x": x, "outcome": "success", "reason": None,
              "feature": {"up_angle": 2.5, "cross_rotvec": [0.0, 0.0, 2.5]}}
    (directory / jump_black_box.RESULT).write_text(json.dumps(result))
    np.testing.assert_array_equal(box.evaluate(3, np.array(x)), [2.5])
    (directory / jump_black_box.RESULT).write_text(json.dumps(
        {**result, "outcome": "failure", "reason": "no jump", "feature": None}))
    assert box.evaluate(3, np.array(x)) == Failure("no jump")
    with pytest.raises(SearchError, match="belongs to another search"):
        box.evaluate(3, np.array(x) + 0.5)
    with pytest.raises(SearchError, match="belongs to another search"):   # another task's x
        box.evaluate(3, np.array(x[:3]))


def test_the_feature_is_the_mean_over_the_clearing_episodes_and_needs_a_majority():
    rng = np.random.default_rng(0)
    n = 5
    outcomes = {f"episode/{name}": rng.normal(size=n) for name in
                ("up_angle", "cross_rotvec_x", "cross_rotvec_y", "cross_rotvec_z", "clearance",
                 "peak_com")}
    outcomes["episode/success"] = np.array([1.0, 0.0, 1.0, 1.0, np.nan])    # nan: never ended
    feature = jump_black_box.crossing_feature(outcomes)
    picked = np.array([0, 2, 3])
    assert feature["up_angle"] == pytest.approx(outcomes["episode/up_angle"][picked].mean())
    np.testing.assert_allclose(feature["cross_rotvec"], [
        outcomes[f"episode/cross_rotvec_{a}"][picked].mean() for a in "xyz"])
    assert feature["peak_com"] == pytest.approx(outcomes["episode/peak_com"][picked].mean())
    outcomes["episode/success"] = np.array([1.0, 0.0, 1.0, 0.0, 0.0])        # 2 of 5
    assert jump_black_box.crossing_feature(outcomes) is None


def test_a_prefixed_echo_puts_every_line_behind_its_prefix_and_no_empty_first_line(capsys):
    echo = jump_black_box.prefixed_echo("[g 007] ")
    echo("\ninterrupted: checkpoint at iteration 3\nsecond line")
    echo()
    assert capsys.readouterr().out.splitlines() == [
        "[g 007] interrupted: checkpoint at iteration 3", "[g 007] second line", "[g 007] "]
