"""Stage 2 of strategy discovery (thesis §3.5.2): the novelty reward (eq. 3.12) by hand with the
geodesic distance between rotations, the [novelty] section of a training config and its errors,
the warm start from a Stage-1 checkpoint, the reward of a success with novelty (eq. 3.15), and
`takeoff stage2` over a small search directory (its rounds, known features, resumption and
summary). Float64 (conftest)."""

import dataclasses
import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agents.commands import stage2_search, train_commands
from agents.commands.strategy_search import SearchConfig
from agents.config import ConfigError
from agents.discovery import jump_black_box, stage2
from agents.discovery.jump_black_box import JumpBlackBoxSettings
from agents.rl import trainer as trainer_lib
from agents.rl.ppo import RunningNorm
from agents.tasks import jump, takeoff_state
from bds.novelty import novelty_reward
from bds.search import Failure, SearchError, SearchSettings, logged_evaluations, search
from jaxsim import rotations
from jaxsim.atomic import OutputError, hold_directory

from conftest import tiny_highjump_training
from test_cli import run as run_cli
from test_jump import _hold, _placed, _run

QUIET = lambda *_: None     # noqa: E731
STAGE1_BAR = 0.73           # the Stage-1 checkpoint's curriculum: the bar it had reached
STAGE1_SAMPLES = 123_456


def rotvec(axis, angle):
    axis = np.asarray(axis, float)
    return axis / np.linalg.norm(axis) * angle


def geodesic(a, b):
    """The angle of the rotation between rotation vectors a and b (scipy, independently)."""
    a, b = np.array(a, float), np.array(b, float)
    return (Rotation.from_rotvec(a).inv() * Rotation.from_rotvec(b)).magnitude()


# ------------------------------------------------------------------- r_novelty (eq. 3.12)

def test_the_novelty_reward_by_hand_with_the_geodesic_distance():
    identity = np.zeros(3)
    quarter = rotvec([1, 0, 0], np.pi / 4)
    r = lambda f, known, threshold=np.pi / 2: float(novelty_reward(  # noqa: E731
        jnp.asarray(f), jnp.asarray(known), threshold, "rotation"))
    # π/4 about x against the identity: clip((π/4) / (π/2), 0.01, 1) = 0.5.
    assert r(quarter, [identity]) == pytest.approx(0.5, rel=1e-6)
    # The same orientation: the floor 0.01.
    assert r(quarter, [quarter]) == pytest.approx(0.01)
    # Beyond d_threshold: 1 (3π/4 about y).
    assert r(rotvec([0, 1, 0], 3 * np.pi / 4), [identity]) == 1.0
    # The nearest of several: π/4 from the identity, π/8 from 3π/8 about x, and farther from π
    # about z: (π/8) / (π/2) = 0.25.
    known = [identity, rotvec([1, 0, 0], 3 * np.pi / 8), rotvec([0, 0, 1], np.pi)]
    assert geodesic(quarter, known[2]) > np.pi / 2
    assert r(quarter, known) == pytest.approx(0.25, rel=1e-6)
    # Not along one axis: from π/2 about z to π/2 about x is a turn of 2π/3.
    assert geodesic(rotvec([0, 0, 1], np.pi / 2), rotvec([1, 0, 0], np.pi / 2)) == \
        pytest.approx(2 * np.pi / 3)
    assert r(rotvec([0, 0, 1], np.pi / 2), [rotvec([1, 0, 0], np.pi / 2)], np.pi) == \
        pytest.approx(2 / 3, rel=1e-6)
    # Batch axes, under jit, and the same rule with the Euclidean distance of eq. 3.12 as written.
    batch = jnp.stack([jnp.asarray(quarter), jnp.asarray(identity)])
    np.testing.assert_allclose(jax.jit(novelty_reward, static_argnums=(2, 3))(
        batch, jnp.asarray([identity]), np.pi / 2, "rotation"), [0.5, 0.01], rtol=1e-6)
    assert float(novelty_reward(jnp.array([0.3, 0.4, 0.0]), jnp.zeros((1, 3)), 1.0)) == \
        pytest.approx(0.5)
    # The config's function: d_threshold = π/2 and the geodesic distance by default.
    settings = stage2.NoveltySettings(warm_start="stage1", known=(tuple(identity),))
    assert settings.threshold == np.pi / 2 and settings.distance == "rotation"
    novelty = stage2.novelty_function(settings)
    assert float(novelty({"cross_rotvec": jnp.asarray(quarter), "up_angle": 0.0})) == \
        pytest.approx(0.5, rel=1e-6)


# ------------------------------------------------------------------- [novelty] errors

def _tiny(tmp_path, novelty=None, name="stage2.toml", hidden=16, takeoff=None):
    text = tiny_highjump_training(hidden=hidden)
    if takeoff is not None:
        text += f"takeoff = {list(takeoff)}\n"
    if novelty is not None:
        text += "\n[novelty]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in novelty.items())
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("novelty, message", [
    ({"known": [[0, 0, 0]]}, r"\[novelty\]: warm_start must name the Stage-1 run directory"),
    ({"warm_start": "s1", "known": [[0, 0, 0], [0.5, 1.0]]},
     r"\[novelty\]: known\[1\] must be 3 numbers, a rotation vector .* got \[0.5, 1.0\]"),
    ({"warm_start": "s1", "known": [[0, 0, 0]], "distance": "manhattan"},
     r"\[novelty\]: distance: unknown feature distance 'manhattan'"),
    ({"warm_start": "s1", "known": [[0, 0, 0]], "threshold": 0.0},
     r"\[novelty\]: threshold must be a finite number > 0"),
    ({"warm_start": "s1"}, r"\[novelty\]: give the features of the policies found so far"),
    ({"warm_start": "s1", "known": [[0, 0, "a"]]},
     r"key 'novelty.known\[0\]\[2\]' must be a float"),
    ({"warm_start": "s1", "known": [[0, 0, 0]], "novel": 1}, r"unknown key 'novelty.novel'"),
])
def test_bad_novelty_sections_name_the_key(tmp_path, novelty, message):
    with pytest.raises(ConfigError, match=message):
        train_commands.load_config(_tiny(tmp_path, novelty))


def _stage1_files(directory, hidden=16, actions="pd"):
    """A Stage-1 run directory with a config.json and a (placeholder) checkpoint."""
    directory.mkdir(parents=True)
    config = train_commands.load_config(_tiny(directory.parent, hidden=hidden, name="s1.toml"),
                                        [f"highjump.actions={actions}"])
    (directory / train_commands.CONFIG).write_text(json.dumps(config.sections()))
    (directory / trainer_lib.CHECKPOINT).write_bytes(b"")
    return directory


def test_a_warm_start_that_cannot_be_used_names_novelty_warm_start(tmp_path, data_dir):
    train = lambda novelty, **kw: train_commands.train(  # noqa: E731
        _tiny(tmp_path, novelty, **kw), tmp_path / "run", data_dir=data_dir, echo=QUIET)
    missing = tmp_path / "nowhere"
    with pytest.raises(ConfigError, match=rf"novelty.warm_start: {missing} is not a training "
                                          "run directory"):
        train({"warm_start": str(missing), "known": [[0, 0, 0]]})
    bare = _stage1_files(tmp_path / "bare")
    (bare / trainer_lib.CHECKPOINT).unlink()
    with pytest.raises(ConfigError, match="novelty.warm_start: .* has no checkpoint"):
        train({"warm_start": str(bare), "known": [[0, 0, 0]]})
    other = _stage1_files(tmp_path / "other", hidden=8)
    with pytest.raises(ConfigError, match=r"novelty.warm_start: .* was trained with ppo.hidden "
                                          r"= \(8,\) and this config has \(16,\)"):
        train({"warm_start": str(other), "known": [[0, 0, 0]]})
    pvae = _stage1_files(tmp_path / "pvae", actions="pvae")
    with pytest.raises(ConfigError, match="was trained with highjump.actions = 'pvae'"):
        train({"warm_start": str(pvae), "known": [[0, 0, 0]]})
    assert not (tmp_path / "run").exists()                 # nothing written
    # A task without strategy features has no novelty to reward.
    reach = train_commands.build_config(
        {"run": {"task": "reach"}, "novelty": {"warm_start": "s1", "known": [[0, 0, 0]]}}, "c")
    with pytest.raises(ConfigError, match="no strategy features"):
        train_commands.make_env(reach)
    # A resumed Stage-2 run cannot change where it was warm-started from.
    run_dir = tmp_path / "stage2"
    run_dir.mkdir()
    config = train_commands.load_config(_tiny(tmp_path, {"warm_start": "a", "known": [[0, 0, 0]]}))
    (run_dir / train_commands.CONFIG).write_text(json.dumps(config.sections()))
    with pytest.raises(ConfigError, match="novelty.warm_start cannot change when a run is resumed"):
        train_commands.train(resume=run_dir, overrides=["novelty.warm_start=b"], echo=QUIET)
    # ... nor can a Stage-1 run become a Stage-2 one.
    (run_dir / train_commands.CONFIG).write_text(json.dumps(dataclasses.replace(
        config, novelty=None).sections()))
    with pytest.raises(ConfigError, match="novelty.warm_start cannot change"):
        train_commands.train(resume=run_dir, overrides=["novelty.warm_start=b",
                                                        "novelty.known=[[0, 0, 0]]"], echo=QUIET)


# ------------------------------------------------------------------- a small search

SUCCESS = {"up_angle": 0.2, "clearance": 0.05, "peak_com": 1.3}


def make_search(directory, outcomes, data_dir):
    """A jump search's directory as `takeoff search` leaves it: config.json, the log, and per
    evaluation train/config.json and result.json. `outcomes[i]` is (up angle, cross_rotvec,
    highest bar cleared) of a success, or None for a failure."""
    directory.mkdir(parents=True)
    train_toml = _tiny(directory, name="train.toml")
    settings = SearchSettings(strategy="random", budget=len(outcomes), feature_low=(0.0,),
                              feature_high=(3.14159,))
    config = SearchConfig(black_box="jump", search=settings, jump=JumpBlackBoxSettings(
        train=str(train_toml), samples=3 * 16, episodes=2))
    (directory / "config.json").write_text(json.dumps(dataclasses.asdict(config)))
    calls = iter(outcomes)

    def g(x):
        outcome = next(calls)
        return Failure("no jump") if outcome is None else np.array([outcome[0]])
    lower, upper = takeoff_state.BOUNDS["highjump"]
    search(g, lower, upper, settings, log=directory / "evaluations.jsonl")
    for record in logged_evaluations(directory / "evaluations.jsonl"):
        index, outcome = record["index"], outcomes[record["index"]]
        evaluation = jump_black_box.evaluation_dir(directory, index)
        (evaluation / "train").mkdir(parents=True)
        train = train_commands.load_config(train_toml, [f"highjump.takeoff={record['x']}"])
        (evaluation / "train" / train_commands.CONFIG).write_text(json.dumps(train.sections()))
        result = {"index": index, "x": record["x"], "task": "highjump", "outcome": "failure",
                  "reason": "no jump", "highest_cleared": None, "feature": None}
        if outcome is not None:
            up, cross, cleared = outcome
            result.update(outcome="success", reason=None, highest_cleared=cleared,
                          feature={**SUCCESS, "up_angle": up, "cross_rotvec": list(cross)})
        (evaluation / jump_black_box.RESULT).write_text(json.dumps(result))
    return directory


EVAL_0 = rotvec([0, 0, 1], np.pi / 4)
EVAL_2 = rotvec([0, 1, 0], -np.pi / 3)


@pytest.fixture(scope="module")
def one_strategy(tmp_path_factory, data_dir):
    """A search of three evaluations: 0 and 2 succeed with up angles 0.2 and 0.3 (one
    strategy; 2 cleared the higher bar, so it is the representative), 1 fails. Evaluation 2
    has a Stage-1 checkpoint: networks and optimiser state of their own (not this seed's
    initialisation), observation statistics, 123,456 samples and the bar at 0.73 m."""
    directory = make_search(tmp_path_factory.mktemp("stage2") / "search",
                            [(0.2, EVAL_0, 0.6), None, (0.3, EVAL_2, 0.73)], data_dir)
    stage1_run = jump_black_box.evaluation_dir(directory, 2) / "train"
    trainer = train_commands.make_trainer(_stage2_config(directory), data_dir)
    shapes = jax.eval_shape(trainer.init)
    zeros = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), shapes)
    dtype = shapes.runner.envs.obs.dtype
    ppo = trainer.ppo.init(jax.random.PRNGKey(7), dtype)
    ppo = dataclasses.replace(ppo, samples=jnp.asarray(STAGE1_SAMPLES, ppo.samples.dtype),
                              iteration=jnp.asarray(31, ppo.iteration.dtype))
    rng = np.random.default_rng(3)
    size = trainer.env.observation_size
    norm = RunningNorm(jnp.asarray(500.0, dtype), jnp.asarray(rng.normal(size=size), dtype),
                       jnp.asarray(rng.uniform(1, 2, size=size) * 500, dtype))
    curriculum = {**zeros.curriculum,
                  "difficulty": jnp.asarray(STAGE1_BAR, zeros.curriculum["difficulty"].dtype),
                  "accumulated": jnp.asarray(4.5, zeros.curriculum["accumulated"].dtype),
                  "raises": jnp.asarray(23, zeros.curriculum["raises"].dtype)}
    state = trainer_lib.TrainState(ppo, norm, zeros.runner, zeros.key, curriculum)
    trainer_lib.save_checkpoint(state, stage1_run)
    (stage1_run / trainer_lib.METRICS).write_text(json.dumps(
        {"iteration": 31, "samples": STAGE1_SAMPLES, "seconds": 60.0,
         trainer_lib.DIFFICULTY: STAGE1_BAR}) + "\n")
    return directory, state


def _stage2_config(search_dir, iterations=1):
    """The config `takeoff stage2` gives the first round from evaluation 2 of `search_dir`."""
    known = [p.cross_rotvec for p in stage2.found_policies(search_dir)]
    stage1_run = jump_black_box.evaluation_dir(search_dir, 2) / "train"
    return train_commands.build_config(
        stage2_search.stage2_sections(stage1_run, known, iterations), "stage2")


def test_the_known_features_and_the_stage1_strategies_of_a_search(one_strategy, tmp_path):
    directory, _ = one_strategy
    policies = stage2.found_policies(directory)
    assert [p.name for p in policies] == ["evaluation 0", "evaluation 2"]
    np.testing.assert_allclose([p.cross_rotvec for p in policies], [EVAL_0, EVAL_2])
    [strategy] = stage2.stage1_strategies(directory)
    assert strategy.evaluations == (0, 2) and strategy.representative == 2
    # A hand-written Stage-2 config may take them from the search directory.
    path = _tiny(tmp_path, {"warm_start": str(jump_black_box.evaluation_dir(directory, 2) /
                                              "train"),
                            "known": [[0.0, 0.0, 0.1]], "search": str(directory)})
    config = stage2.prepare(train_commands.load_config(path), path)
    np.testing.assert_allclose(config.novelty.known, [[0, 0, 0.1], EVAL_0, EVAL_2])


def test_a_warm_started_run_starts_from_the_stage1_policy_at_its_bar(one_strategy, data_dir,
                                                                     tmp_path):
    directory, stage1 = one_strategy
    config = _stage2_config(directory)
    trainer = train_commands.make_trainer(config, data_dir)
    lines = []
    state = stage2.warm_start(trainer, config, "stage2", echo=lines.append)
    # The networks, their optimisers, the observation statistics, the samples (σ) and the
    # curriculum are the Stage-1 checkpoint's, leaf for leaf; the iteration count starts at 0.
    for part in ("policy_params", "value_params", "policy_opt_state", "value_opt_state",
                 "samples"):
        a, b = getattr(state.ppo, part), getattr(stage1.ppo, part)
        assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
            np.testing.assert_array_equal(x, y)
    for x, y in zip(jax.tree_util.tree_leaves((state.norm, state.curriculum)),
                    jax.tree_util.tree_leaves((stage1.norm, stage1.curriculum))):
        np.testing.assert_array_equal(x, y)
    assert int(state.ppo.iteration) == 0 and int(stage1.ppo.iteration) == 31
    own_seed = trainer.ppo.init(jax.random.split(jax.random.PRNGKey(config.run.seed), 3)[0],
                                jnp.float64)       # what this run's seed alone would start from
    assert not all(np.array_equal(a, b) for a, b in zip(
        jax.tree_util.tree_leaves(own_seed.policy_params),
        jax.tree_util.tree_leaves(state.ppo.policy_params)))
    # The environments start at the Stage-1 bar, not at z_min.
    assert config.task.z_min == 0.5
    np.testing.assert_allclose(state.runner.envs.task["difficulty"], STAGE1_BAR, rtol=1e-6)
    assert "after 31 iterations (123,456 samples), difficulty 0.73" in lines[0]
    # Its environment's reward has the novelty against the search's policies.
    assert trainer.env.novelty is not None
    # A checkpoint that does not fit the networks its config.json says: named.
    broken = tmp_path / "broken"
    shutil.copytree(jump_black_box.evaluation_dir(directory, 2) / "train", broken)
    from agents.checkpoint import previous_path, write_msgpack
    (broken / trainer_lib.CHECKPOINT).unlink()
    write_msgpack(broken / trainer_lib.CHECKPOINT, [np.zeros(3)])
    assert not previous_path(broken / trainer_lib.CHECKPOINT).exists()
    with pytest.raises(ConfigError, match="novelty.warm_start: the checkpoint of .* does not "
                                          "fit this run's networks"):
        stage2.warm_start(trainer, dataclasses.replace(config, novelty=dataclasses.replace(
            config.novelty, warm_start=str(broken))), "stage2", echo=QUIET)


# ------------------------------------------------------------------- the reward (eq. 3.15)

def test_a_success_with_novelty_pays_the_stage1_reward_times_r_novelty(data_dir):
    highjump = jump.JumpEnv(jump.HighJumpSettings(actions="pd"), data_dir, dtype=jnp.float64)
    params, state, q = _placed(highjump, jump.BAR_DISTANCE + 1.4, 0.15, lying=True)
    # The root's orientation in the facing frame as placed (the crossing, one substep on, is
    # within a hair of it); known: it turned by π/4 about an oblique axis, and the identity.
    start = np.array(rotations.matrix_to_rotvec(
        highjump.heading.T @ rotations.quat_to_matrix(q[3:7])))
    turned = (Rotation.from_rotvec(start) * Rotation.from_rotvec(
        rotvec([1, 2, -1], np.pi / 4))).as_rotvec()
    settings = stage2.NoveltySettings(warm_start="stage1", known=(tuple(turned), (0, 0, 0)))
    novel = stage2.novelty_env(highjump, settings)
    state, steps = _run(novel, jax.jit(novel.step), params, state, _hold(highjump, q), 5)
    assert bool(state.terminated) and float(state.metrics["episode/success"]) == 1.0
    cross = np.asarray(state.task["cross_rotvec"])
    gaps = [geodesic(cross, turned), geodesic(cross, np.zeros(3))]
    assert gaps[0] == pytest.approx(np.pi / 4, abs=0.05) and gaps[1] > gaps[0] + 0.5
    r_novelty = float(np.clip(min(gaps) / (np.pi / 2), 0.01, 1.0))       # eq. 3.12
    stage1_reward, _ = highjump.reward(state.task, steps)                # eq. 3.2
    assert float(state.reward) == pytest.approx(float(stage1_reward) * r_novelty, rel=1e-9)
    assert float(state.reward) < float(stage1_reward) * 0.6


# ------------------------------------------------------------------- takeoff stage2

def test_stage2_trains_a_round_from_the_strategy_and_resumes_like_any_run(
        one_strategy, data_dir, tmp_path, monkeypatch):
    """One real round (one iteration) over the one-strategy search; its measurement stubbed
    (the tiny policy cannot jump), with the crossing π/4 from evaluation 2's: it repeats
    Stage-1 strategy 0. Then the round's run resumed by `takeoff train --resume`."""
    directory, stage1 = one_strategy
    out = tmp_path / "stage2"
    measured = []

    def measure(where, run_dir, episodes, data_dir=None, **fields):
        measured.append((where, run_dir, episodes, fields))
        cross = (Rotation.from_rotvec(EVAL_2) * Rotation.from_rotvec(
            rotvec([0, 0, 1], np.pi / 4))).as_rotvec()
        result = {**fields, "task": "highjump", "outcome": "success", "reason": None,
                  "highest_cleared": STAGE1_BAR,
                  "feature": {**SUCCESS, "cross_rotvec": cross.tolist()}}
        (where / jump_black_box.RESULT).write_text(json.dumps(result))
        return result
    monkeypatch.setattr(jump_black_box, "measure", measure)
    lines = []
    rows = stage2_search.run(directory, iterations=1, rounds=1, out=out, data_dir=data_dir,
                             echo=lines.append)
    run_dir = out / "000" / "train"
    [(where, measured_dir, episodes, fields)] = measured
    assert (where, measured_dir, episodes) == (out / "000", run_dir, 2)
    assert fields["stage"] == 2 and fields["evaluation"] == 2 and fields["round"] == 0
    config = train_commands.load_run_config(run_dir)
    assert config.novelty.warm_start == str((jump_black_box.evaluation_dir(directory, 2) /
                                             "train").resolve())
    np.testing.assert_allclose(config.novelty.known, [EVAL_0, EVAL_2])
    assert config.novelty.threshold == np.pi / 2 and config.run.iterations == 1
    np.testing.assert_allclose(fields["x"], config.task.takeoff)
    [record] = trainer_lib.read_metrics(run_dir)
    assert record["samples"] == STAGE1_SAMPLES + 16                    # σ goes on from Stage 1
    assert record[trainer_lib.DIFFICULTY] == pytest.approx(STAGE1_BAR, rel=1e-6)
    [row] = rows
    assert row["novel"] is False and row["nearest"] == "evaluation 2 (Stage-1 strategy 0)"
    assert row["distance"] == pytest.approx(np.pi / 4, rel=1e-6)
    assert "1 round, 0 novel, 1 repeat, 0 failed" in lines[-2]
    assert "repeats evaluation 2 (Stage-1 strategy 0) (0.79 rad)" in lines[-1]
    # Run again: the round has its result, so nothing is trained or measured.
    assert stage2_search.run(directory, out=out, data_dir=data_dir, echo=QUIET) == rows
    assert len(measured) == 1
    # The round's run resumes like any run: on from its checkpoint (not warm-started again).
    _, state = train_commands.train(resume=run_dir, overrides=["run.iterations=2"],
                                    data_dir=data_dir, echo=QUIET)
    assert [r["iteration"] for r in trainer_lib.read_metrics(run_dir)] == [1, 2]
    assert int(state.ppo.samples) == STAGE1_SAMPLES + 32
    assert int(state.ppo.iteration) == 2


RETRAINED_TURN = 0.1   # rad: how far a retrained Stage-1 policy's crossing is from the logged one


def retrained_crossing(logged):
    """The crossing of a Stage-1 policy trained again (`_stand_in_measure`): the logged one
    turned by `RETRAINED_TURN` about the root's x axis."""
    turn = Rotation.from_rotvec(rotvec([1, 0, 0], RETRAINED_TURN))
    return (Rotation.from_rotvec(logged) * turn).as_rotvec()


FELL = {"outcome": "failure", "reason": "fell", "highest_cleared": None, "feature": None}


def _stand_in_measure(round_result):
    """A `jump_black_box.measure` that measures nothing: a Stage-1 policy trained again
    (`retrained`) clears the bar, crossing `RETRAINED_TURN` from the orientation the search
    logged; a round's outcome fields are `round_result(fields)`. Each writes its result.json,
    as measure does."""
    def measure(where, run_dir, episodes, data_dir=None, **fields):
        if fields.get("retrained"):
            result = {**json.loads((where.parent / jump_black_box.RESULT).read_text()), **fields}
            turned = retrained_crossing(result["feature"]["cross_rotvec"])
            result["feature"] = {**result["feature"], "cross_rotvec": list(turned)}
        else:
            result = {**fields, "task": "highjump", **round_result(fields)}
        (where / jump_black_box.RESULT).write_text(json.dumps(result))
        return result
    return measure


def _fake_training(calls):
    """A `train_commands.train` that trains nothing: it writes the run's config.json, a metrics
    line saying all its iterations are done and a checkpoint file, and records how it was
    called."""
    def train(config_path=None, out_dir=None, overrides=(), resume=None, data_dir=None,
              echo=print, cluster=None):
        calls.append(("resume", resume) if resume is not None else ("start", out_dir))
        if resume is None:
            config = train_commands.load_config(config_path, overrides)
            out_dir.mkdir(parents=True, exist_ok=True)
            (out_dir / train_commands.CONFIG).write_text(json.dumps(config.sections()))
            (out_dir / trainer_lib.CHECKPOINT).write_bytes(b"")
        run_dir = Path(resume or out_dir)
        iterations = train_commands.load_run_config(run_dir).run.iterations
        (run_dir / trainer_lib.METRICS).write_text(
            json.dumps({"iteration": iterations, "samples": 16 * iterations, "seconds": 1.0})
            + "\n")
        return None, None
    return train


def test_stage2_rounds_grow_the_known_set_and_a_killed_stage2_goes_on(tmp_path, data_dir,
                                                                      monkeypatch):
    """Two strategies × two rounds with the training and measurement stubbed: the rounds go
    round by round, each novel against every policy found before it (Stage 1's and the earlier
    rounds'), the summary says which are novel and which repeat what, and a rerun after a kill
    skips finished rounds and resumes the one that was training. The Stage-1 policies are not
    there (a search carried from another machine): each is trained again first, once, with
    the search's black box settings."""
    eval_3 = rotvec([1, 0, 0], 2.5)
    directory = make_search(tmp_path / "search", [(0.2, EVAL_0, 0.6), None, (0.3, EVAL_2, 0.73),
                                                  (2.8, eval_3, 0.55)], data_dir)
    novel_cross = rotvec([0, 1, 0], 2.0)                             # far from all three
    crossings = {0: novel_cross,                                     # round 1, strategy 0
                 1: (Rotation.from_rotvec(eval_3) * Rotation.from_rotvec(   # near evaluation 3
                     rotvec([0, 1, 0], 0.3))).as_rotvec(),
                 2: (Rotation.from_rotvec(novel_cross) * Rotation.from_rotvec(  # near stage2 000
                     rotvec([0, 0, 1], 0.5))).as_rotvec(),
                 3: None}                                            # fails
    assert min(geodesic(novel_cross, f) for f in (EVAL_0, EVAL_2, eval_3)) > np.pi / 2
    calls, measured = [], []
    for evaluation in range(4):               # carried from another machine: no training runs
        shutil.rmtree(jump_black_box.evaluation_dir(directory, evaluation) / "train")

    def round_result(fields):
        measured.append(fields["index"])
        cross = crossings.get(fields["index"])                  # (added rounds fail)
        if cross is None:
            return FELL
        return {"outcome": "success", "reason": None, "highest_cleared": 0.7,
                "feature": {**SUCCESS, "cross_rotvec": list(cross)}}
    monkeypatch.setattr(jump_black_box, "measure", _stand_in_measure(round_result))
    monkeypatch.setattr(train_commands, "train", _fake_training(calls))
    out = tmp_path / "out"
    lines = []
    rows = stage2_search.run(directory, rounds=2, out=out, echo=lines.append)
    plan = json.loads((out / stage2_search.PLAN).read_text())
    # ⌈jump.samples / 3 / samples per iteration⌉ = ⌈48 / 3 / 16⌉ = 1 iteration per round.
    assert plan["rounds"] == 2 and plan["iterations"] == 1
    assert [(r["evaluation"], r["strategy"], r["round"]) for r in plan["runs"]] == \
        [(2, 0, 0), (3, 1, 0), (2, 0, 1), (3, 1, 1)]
    known = [[k["policy"] for k in json.loads((out / f"{i:03d}" / stage2_search.KNOWN)
                                              .read_text())] for i in range(4)]
    # Each start's policy was trained again before its first round, and its own crossing joins
    # the known set after the logged one (Stage-1 evaluation 0's policy was never needed).
    stage1 = ["evaluation 0", "evaluation 2", "evaluation 2 (retrained)", "evaluation 3"]
    stage1_all = stage1 + ["evaluation 3 (retrained)"]
    assert known == [stage1, stage1_all + ["stage2 000"],
                     stage1_all + ["stage2 000", "stage2 001"],
                     stage1_all + ["stage2 000", "stage2 001", "stage2 002"]]
    configs = [train_commands.load_run_config(out / f"{i:03d}" / "train") for i in range(4)]
    np.testing.assert_allclose(configs[2].novelty.known[len(stage1_all)], novel_cross)
    np.testing.assert_allclose(configs[0].novelty.known[2], retrained_crossing(EVAL_2), atol=1e-12)
    assert [c.task.takeoff for c in configs[:2]] == [
        tuple(json.loads((jump_black_box.evaluation_dir(directory, e) / "result.json")
                         .read_text())["x"]) for e in (2, 3)]
    assert [(r["outcome"], r.get("novel"), r.get("nearest")) for r in rows] == [
        ("success", True, "evaluation 0 (Stage-1 strategy 0)"),
        ("success", False, "evaluation 3 (Stage-1 strategy 1)"),
        ("success", False, "stage2 000"),
        ("failure", None, None)]
    assert rows[0]["distance"] == pytest.approx(min(geodesic(novel_cross, f) for f in
                                                    (EVAL_0, EVAL_2, retrained_crossing(EVAL_2),
                                                     eval_3)), rel=1e-6)
    assert rows[2]["distance"] == pytest.approx(0.5, rel=1e-6)
    assert "4 rounds, 1 novel, 2 repeats, 1 failed" in lines[-5]
    assert lines[-4].startswith("000  round 1  from evaluation 2 (strategy 0)  NOVEL")
    assert json.loads((out / stage2_search.SUMMARY).read_text())[0]["novel"] is True
    stage1_runs = [jump_black_box.evaluation_dir(directory, e) / "train" for e in (2, 3)]
    assert calls == [("start", stage1_runs[0]), ("start", out / "000" / "train"),
                     ("start", stage1_runs[1]), ("start", out / "001" / "train"),
                     ("start", out / "002" / "train"), ("start", out / "003" / "train")]
    text = "\n".join(lines)
    for evaluation, run_dir, bar in zip((2, 3), stage1_runs, (0.73, 0.55)):
        assert (f"Stage-1 evaluation {evaluation}'s policy is not in {directory}: training it "
                "again from its x with the search's settings") in text
        assert (f"Stage-1 evaluation {evaluation} trained again clears {bar:.2f} m (first "
                f"training: {bar:.2f} m), its crossing {RETRAINED_TURN:.2f} rad from the one "
                "the search logged") in text
        assert json.loads((run_dir.parent / stage2_search.RETRAINED / "result.json")
                          .read_text())["retrained"] is True
        retrained = train_commands.load_run_config(run_dir)      # the black box's overrides
        assert list(retrained.task.takeoff) == json.loads((run_dir.parent / "result.json")
                                                          .read_text())["x"]
        assert retrained.run.iterations == 3                     # ⌈jump.samples 48 / 16⌉
        assert retrained.run.stop_difficulty == retrained.task.z_freeze

    # Killed while round 003 was being measured (its training finished, no result), after 002
    # had written its config but before it trained: the rerun starts 002 from its config as
    # written (its known set as decided then), measures 003 without training it again, and
    # leaves 000 and 001 alone. (A round part way through its iterations resumes: the shared
    # rule train_commands.train_or_resume, tested with the sweep and the jump black box.)
    (out / "003" / jump_black_box.RESULT).unlink()
    (out / "002" / jump_black_box.RESULT).unlink()
    shutil.rmtree(out / "002" / "train")
    known_002 = (out / "002" / stage2_search.KNOWN).read_text()
    calls.clear()
    measured.clear()
    assert stage2_search.run(directory, out=out, echo=QUIET) == rows
    assert calls == [("start", out / "002" / "train")]
    assert measured == [2, 3]
    assert (out / "002" / stage2_search.KNOWN).read_text() == known_002
    with pytest.raises(ConfigError, match="holds a Stage 2 of 2 rounds, and --rounds 1 asks "
                                          "for fewer"):
        stage2_search.run(directory, rounds=1, out=out, echo=QUIET)
    # A third round per strategy is added after the plan's own, against all found before it.
    calls.clear()
    lines.clear()
    rows = stage2_search.run(directory, rounds=3, out=out, echo=lines.append)
    assert lines[0] == f"adding rounds 3–3 to the Stage 2 in {out}"
    plan = json.loads((out / stage2_search.PLAN).read_text())
    assert plan["rounds"] == 3 and [(r["index"], r["evaluation"], r["round"]) for r in
                                    plan["runs"][4:]] == [(4, 2, 2), (5, 3, 2)]
    assert calls == [("start", out / "004" / "train"), ("start", out / "005" / "train")]
    known = [k["policy"] for k in json.loads((out / "004" / stage2_search.KNOWN).read_text())]
    assert known == stage1_all + ["stage2 000", "stage2 001", "stage2 002"]     # 003 failed
    assert len(rows) == 6


def test_a_stage2_another_process_holds_is_refused_before_it_writes(tmp_path, data_dir):
    directory = make_search(tmp_path / "search", [(0.2, EVAL_0, 0.6)], data_dir)
    out = tmp_path / "out"
    with hold_directory(out, "Stage 2"):
        with pytest.raises(OutputError, match=rf"{out}: Stage 2 is in use by process "):
            stage2_search.run(directory, rounds=1, out=out, echo=lambda *_: None)
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


def test_a_strategy_whose_representative_lost_its_policy_starts_from_one_that_has_it(
        tmp_path, data_dir, monkeypatch):
    """A search carried to another machine keeps results, not policies: where the
    representative's checkpoint is gone, the strategy's rounds start from the member with a
    policy that cleared the highest bar, and say so; a strategy with no policy anywhere keeps
    its representative."""
    eval_3 = rotvec([1, 0, 0], 2.5)
    directory = make_search(tmp_path / "search", [(0.2, EVAL_0, 1.0), (0.25, EVAL_0, 1.0),
                                                  (0.3, EVAL_2, 1.0), (2.8, eval_3, 1.0)],
                            data_dir)
    for index in (1, 2):                                  # finished runs: their policies
        run_dir = jump_black_box.evaluation_dir(directory, index) / "train"
        (run_dir / trainer_lib.CHECKPOINT).write_bytes(b"")
        iterations = train_commands.load_run_config(run_dir).run.iterations
        (run_dir / trainer_lib.METRICS).write_text(json.dumps(
            {"iteration": iterations, "samples": 16 * iterations, "seconds": 1.0}) + "\n")
    (jump_black_box.evaluation_dir(directory, 1) / jump_black_box.RESULT).write_text(
        json.dumps({**json.loads((jump_black_box.evaluation_dir(directory, 1) /
                                  jump_black_box.RESULT).read_text()), "highest_cleared": 0.9}))
    [strategy, other] = stage2.stage1_strategies(directory)
    assert strategy.evaluations == (0, 1, 2) and strategy.representative == 0
    assert other.evaluations == (3,) and other.representative == 3
    monkeypatch.setattr(jump_black_box, "measure", _stand_in_measure(lambda fields: FELL))
    monkeypatch.setattr(train_commands, "train", _fake_training([]))
    lines = []
    stage2_search.run(directory, rounds=1, out=tmp_path / "out", echo=lines.append)
    plan = json.loads((tmp_path / "out" / stage2_search.PLAN).read_text())
    assert [(r["evaluation"], r["strategy"]) for r in plan["runs"]] == [(2, 0), (3, 1)]
    assert (f"Stage-1 strategy 0: evaluation 0's policy is not in {directory}, so its rounds "
            "start from evaluation 2's (bar 1.00 m)") in lines
    assert not any("strategy 1:" in line for line in lines)


def test_stage2_sigma_makes_every_round_explore_at_that_constant_sigma(tmp_path, data_dir,
                                                                      monkeypatch, capsys):
    """--sigma: each round's config explores at that σ from its first iteration to its last
    (sigma_start = sigma_end), the plan keeps it, and a resume asking for another is refused.
    Without it a round keeps Stage 1's σ schedule."""
    directory = make_search(tmp_path / "search", [(0.2, EVAL_0, 1.0)], data_dir)
    stage1 = train_commands.load_run_config(jump_black_box.evaluation_dir(directory, 0) / "train")
    assert stage1.ppo.sigma_start != stage1.ppo.sigma_end       # an annealed schedule
    monkeypatch.setattr(jump_black_box, "measure", _stand_in_measure(lambda fields: FELL))
    monkeypatch.setattr(train_commands, "train", _fake_training([]))
    lines = []
    stage2_search.run(directory, rounds=2, out=tmp_path / "noisy", sigma=0.4, echo=lines.append)
    assert any(line.endswith(f"of 1 iteration at σ 0.4 → {tmp_path / 'noisy'}") for line in lines)
    assert json.loads((tmp_path / "noisy" / stage2_search.PLAN).read_text())["sigma"] == 0.4
    for index in (0, 1):
        ppo = train_commands.load_run_config(tmp_path / "noisy" / f"{index:03d}" / "train").ppo
        assert (ppo.sigma_start, ppo.sigma_end) == (0.4, 0.4)
        assert ppo.sigma_horizon == stage1.ppo.sigma_horizon
    with pytest.raises(ConfigError, match="holds a Stage 2 of 2 rounds × 1 iterations at σ "
                                          "0.4, and --sigma 0.2 asks for another"):
        stage2_search.run(directory, out=tmp_path / "noisy", sigma=0.2, echo=QUIET)
    stage2_search.run(directory, rounds=1, out=tmp_path / "annealed", echo=QUIET)
    ppo = train_commands.load_run_config(tmp_path / "annealed" / "000" / "train").ppo
    assert (ppo.sigma_start, ppo.sigma_end) == (stage1.ppo.sigma_start, stage1.ppo.sigma_end)
    for bad in ("0", "-0.1", "nan", "inf", "wide"):
        code, _, err = run_cli(["stage2", str(directory), "--sigma", bad], capsys)
        assert code != 0 and f"must be a finite number > 0; got '{bad}'" in err


def test_a_stage1_run_that_stopped_on_its_own_is_used_as_it_is_and_a_part_one_trained_on(
        tmp_path, data_dir, monkeypatch):
    """A Stage-1 run that stopped on its own, by its own stored settings, is used as it is —
    here one the search gave up on at its first leg (iteration 1; the budget gives 3) whose
    policy still cleared the bar — and nothing is trained. A run stopped part way is trained
    on by the search's black box; when that goes nowhere, or the policy does not clear the bar,
    Stage 2 stops saying so, before the round's config is written."""
    directory = make_search(tmp_path / "search", [(0.2, EVAL_0, 1.0)], data_dir)
    run_dir = jump_black_box.evaluation_dir(directory, 0) / "train"
    config = json.loads((run_dir / train_commands.CONFIG).read_text())
    config["run"]["iterations"] = 1
    (run_dir / train_commands.CONFIG).write_text(json.dumps(config))
    (run_dir / trainer_lib.CHECKPOINT).write_bytes(b"")
    (run_dir / trainer_lib.METRICS).write_text(json.dumps(
        {"iteration": 1, "samples": 16, "seconds": 1.0, "env/episode/success": 0.0}) + "\n")
    trained, gives_up = [], []
    monkeypatch.setattr(jump_black_box.JumpBlackBox, "train",
                        lambda self, where, x: trained.append(where) or gives_up[0])
    monkeypatch.setattr(jump_black_box, "measure", _stand_in_measure(lambda fields: FELL))
    monkeypatch.setattr(train_commands, "train", _fake_training([]))        # the round's
    stage2_search.run(directory, rounds=1, out=tmp_path / "as_it_is", echo=QUIET)
    assert trained == [] and not (run_dir.parent / stage2_search.RETRAINED).exists()
    config["run"]["iterations"] = 3                                # now iteration 1 of 3
    (run_dir / train_commands.CONFIG).write_text(json.dumps(config))
    monkeypatch.setattr(jump_black_box, "measure",
                        lambda where, run_dir, episodes, data_dir=None, **fields:
                        {**fields, **FELL})
    for give_up, message in (("it never crossed", "Stage-1 evaluation 0 trained again went "
                                                  r"nowhere \(it never crossed\)"),
                             (None, "Stage-1 evaluation 0 trained again does not clear the bar "
                                    r"\(fell\)")):
        gives_up[:] = [give_up]
        with pytest.raises(SearchError, match=message):
            stage2_search.run(directory, rounds=1, out=tmp_path / "out", echo=QUIET)
        assert trained[-1] == run_dir
        assert not (tmp_path / "out" / "000" / stage2_search.RUN_CONFIG).exists()


def test_stage2_needs_a_jump_search_with_a_success(tmp_path, data_dir, capsys):
    failed = make_search(tmp_path / "failed", [None], data_dir)
    with pytest.raises(SearchError, match="no evaluation of the search succeeded"):
        stage2_search.run(failed, echo=QUIET)
    code, _, err = run_cli(["stage2", str(tmp_path / "nowhere")], capsys)
    assert code != 0 and "takeoff stage2: " in str(code) + err
    assert "not a strategy-search directory" in str(code) + err
    landscape = tmp_path / "landscape"
    landscape.mkdir()
    (landscape / "config.json").write_text(json.dumps({"black_box": "landscape"}))
    with pytest.raises(SearchError, match="Stage 2 needs a jump search"):
        stage2_search.run(landscape, echo=QUIET)
    # A log that says an evaluation succeeded whose result.json says otherwise.
    broken = make_search(tmp_path / "broken", [(0.2, EVAL_0, 0.6)], data_dir)
    (jump_black_box.evaluation_dir(broken, 0) / "result.json").unlink()
    with pytest.raises(SearchError, match="has this evaluation succeed, but it has no "
                                          "result.json"):
        stage2.found_policies(broken)
