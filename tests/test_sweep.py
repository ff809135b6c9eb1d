"""`takeoff sweep` (`agents.sweep`): an evaluation sweep's members, run in one call, equal each
member's config run alone; keys that cannot be vmapped are refused by name; a training sweep
killed (SIGKILL) part way resumes without training a finished member again; the report has a
row per member."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents import sweep, sweep_spec
from agents.commands import train_commands
from agents.config import ConfigError
from agents.tasks import jump, physics
from jaxsim.atomic import OutputError, hold_directory
from conftest import tiny_highjump_training


@pytest.fixture(scope="module")
def jump_run(tmp_path_factory, data_dir):
    """A one-iteration high-jump run (PD actions): a policy to evaluate."""
    folder = tmp_path_factory.mktemp("sweep_jump")
    config = folder / "tiny.toml"
    config.write_text(tiny_highjump_training(1))
    run_dir = folder / "run"
    train_commands.train(config, run_dir, data_dir=data_dir, echo=lambda *_: None)
    return run_dir


def test_vmapped_members_equal_each_member_run_alone(tmp_path, jump_run, data_dir):
    """Leg length × gravity (the [physics] factors), the take-off x and its vertical velocity
    (task parameters) as one rollout of members × episodes environments: each member's outcomes
    are those of the run's policy evaluated alone under that member's config (float32: to
    1e-6)."""
    config = tmp_path / "sweep.toml"
    config.write_text(f"""
[sweep]
evaluate = "{jump_run}"
episodes = 2
"physics.leg_length_scale" = {{linspace = [0.9, 1.1, 2]}}
physics.gravity_scale = [0.5, 1.0]
highjump.takeoff = [[-0.5, -3.0, 2.0, -2.4]]
highjump.vertical_velocity = [0.8, 1.4]
""")
    out = sweep.run(config, tmp_path / "out", data_dir=data_dir, echo=lambda *_: None)
    rows = [json.loads(line) for line in (out / sweep.ROWS).read_text().splitlines()]
    assert [r["member"] for r in rows] == list(range(8))
    # the outcomes vary with the members: longer legs stand higher, so the apex is higher
    assert rows[4]["peak_com"] > rows[0]["peak_com"] + 0.05
    assert rows[0]["peak_com"] != rows[1]["peak_com"]            # vertical velocity 0.8, 1.4
    assert rows[0]["peak_com"] != rows[2]["peak_com"]            # gravity 0.5, 1.0
    for row in rows[5:6]:                            # (legs 1.1, gravity 0.5, 1.4 m/s up)
        alone = train_commands.run_episodes(
            jump_run, 2, data_dir, echo=lambda *_: None, overrides=[
                f"physics.leg_length_scale={row['physics.leg_length_scale']}",
                f"physics.gravity_scale={row['physics.gravity_scale']}",
                "highjump.takeoff=[-0.5, -3.0, 2.0, -2.4]",
                f"highjump.vertical_velocity={row['highjump.vertical_velocity']}"])
        for name in ("peak_com", "return", "episode_length", "success"):
            values = alone.outcomes[name if name in ("return", "episode_length")
                                    else f"episode/{name}"]
            assert row[name] == pytest.approx(float(np.mean(values)), abs=1e-6), name
    table = list(csv.DictReader((out / "sweep.csv").open()))
    assert [t["member"] for t in table] == [str(i) for i in range(8)]
    summary = (out / "sweep.md").read_text()
    assert "# Sweep: 8 members" in summary and "| peak_com |" in summary
    assert (out / "sweep_heatmap.png").exists()
    rerun = []                           # a finished sweep run again evaluates nothing
    sweep.run(config, tmp_path / "out", data_dir=data_dir, echo=rerun.append)
    assert "8 done before" in rerun[0] and not any("evaluated" in line for line in rerun)


def test_in_float64_vmapped_members_equal_each_rollout_alone_to_a_few_ulp(data_dir):
    """The sweep's parameters of its members (leg length × take-off vertical speed,
    `sweep.member_params`) in one vmapped float64 rollout of the jump environment (the sweep's
    own path, above, runs in float32 only), against each member's rollout compiled alone. Not
    bit for bit: vmap changes XLA's fusion and summation order, which moves the last bits (a
    few 1e-15 m after 5 control steps, 300 substeps); 1e-12 bounds that."""
    env = jump.JumpEnv(jump.HighJumpSettings(actions="pd"), data_dir, dtype=jnp.float64)
    params = {**env.default_params(),
              "physics": physics.params_of(physics.PhysicsSettings(), jnp.float64)}
    members = sweep_spec.expand({"physics": {"leg_length_scale": [0.9, 1.1]},
                                 "highjump": {"vertical_velocity": [0.8, 1.4]}}, "test")
    columns = {key: np.asarray([m[key] for m in members]) for key in members[0]}
    stacked = jax.tree_util.tree_map(
        lambda x: jnp.broadcast_to(x, (len(members), *jnp.shape(x))), params)
    varied = sweep.member_params(types.SimpleNamespace(source="test"), columns, stacked)
    action = jnp.zeros(env.action_size, jnp.float64)

    def rollout(p):
        def step(state, _):
            state = env.step(p, state, action)
            return state, state.reward
        end, rewards = jax.lax.scan(step, env.reset(p, jax.random.PRNGKey(0)), None,
                                    length=5)
        return end.physics.q, rewards

    together_q, together_r = jax.jit(jax.vmap(rollout))(varied)
    alone = jax.jit(rollout)
    heights = []
    for i in range(len(members)):
        q, rewards = alone(jax.tree_util.tree_map(lambda x: x[i], varied))
        np.testing.assert_allclose(together_q[i], q, rtol=0, atol=1e-12)
        np.testing.assert_allclose(together_r[i], rewards, rtol=0, atol=1e-12)
        heights.append(float(q[1]))
    assert len({round(h, 6) for h in heights}) == 4       # every member moved differently


@pytest.mark.parametrize("key, values, message", [
    ("highjump.method", '["aba"]', "sweep.highjump.method cannot be vmapped"),
    ("ppo.hidden", "[[8]]", "sweep.ppo.hidden cannot be vmapped"),
    ("physics.leg_length_scale", "[-1.0]", "must be a finite number > 0"),
    ("physics.mass", "[1.0]", "sweep.physics.mass cannot be vmapped"),
])
def test_an_evaluation_sweep_refuses_what_it_cannot_vmap(tmp_path, jump_run, key, values,
                                                          message):
    config = tmp_path / "sweep.toml"
    config.write_text(f'[sweep]\nevaluate = "{jump_run}"\n"{key}" = {values}\n')
    with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace("(", r"\(")):
        sweep.load(config)


def _reach_sweep(tmp_path, iterations, table="run.seed = [0, 1, 2]\nvmap = false\n"):
    text = open("configs/reach.toml").read()
    for old, new in (("iterations = 200", f"iterations = {iterations}"),
                     ("envs = 64", "envs = 16"), ("hidden = [64, 64]", "hidden = [16]"),
                     ("minibatch_size = 256", "minibatch_size = 120"),
                     ("checkpoint_every = 50", "checkpoint_every = 1")):
        assert old in text
        text = text.replace(old, new)
    config = tmp_path / "reach_sweep.toml"
    config.write_text(text + "\n[sweep]\n" + table)
    return config


def test_a_killed_training_sweep_resumes_without_redoing_finished_members(tmp_path):
    """Members as separate runs (`vmap = false`), SIGKILL after member 0's row and during
    member 1's training: run again, member 0 is not trained again (its metrics file is
    untouched), member 1 goes on from its checkpoint, and every member has one row."""
    config = _reach_sweep(tmp_path, iterations=40)
    out = tmp_path / "out"
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax_cache"),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    command = [sys.executable, "-m", "agents.commands.cli", "sweep", str(config), "--out",
               str(out)]
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    member_1 = out / sweep.MEMBERS / "001" / "metrics.jsonl"
    deadline = time.monotonic() + 300
    while not (member_1.exists() and len(member_1.read_text().splitlines()) >= 3):
        assert process.poll() is None, process.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "member 1 did not train 3 iterations in 5 min"
        time.sleep(0.1)
    process.send_signal(signal.SIGKILL)
    process.wait()
    rows = (out / sweep.ROWS).read_text().splitlines()
    assert [json.loads(r)["member"] for r in rows] == [0]
    member_0 = out / sweep.MEMBERS / "000" / "metrics.jsonl"
    stamp = member_0.stat().st_mtime_ns, member_0.read_text()

    resumed = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "1 done before" in resumed.stdout
    rows = [json.loads(r) for r in (out / sweep.ROWS).read_text().splitlines()]
    assert sorted(r["member"] for r in rows) == [0, 1, 2]
    assert (member_0.stat().st_mtime_ns, member_0.read_text()) == stamp
    iterations = [json.loads(r)["iteration"] for r in member_1.read_text().splitlines()]
    assert iterations == list(range(1, 41))           # none repeated, none missing
    assert all(r["iteration"] == 40 for r in rows)


def test_a_rerun_with_another_table_is_refused(tmp_path):
    config = _reach_sweep(tmp_path, iterations=1)
    out = tmp_path / "out"
    sweep._claim(out, sweep.load(config))
    config.write_text(config.read_text().replace("[0, 1, 2]", "[0, 1]"))
    with pytest.raises(ConfigError, match="holds another sweep"):
        sweep.run(config, out)


def test_a_sweep_another_process_holds_is_refused_before_it_writes(tmp_path):
    config = _reach_sweep(tmp_path, iterations=1)
    out = tmp_path / "out"
    with hold_directory(out, "the sweep"):
        with pytest.raises(OutputError, match=rf"{out}: the sweep is in use by process "):
            sweep.run(config, out)
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


def test_seeds_trained_in_one_program_equal_the_trainings_run_alone(tmp_path):
    """Two seeds × two clips × two policy learning rates of the reach task as one vmapped
    training: each member's policy and metrics are those of `takeoff train` with its values
    (float32 programs: to 1e-5), and each member directory is a run `takeoff eval` reads."""
    from agents.rl import trainer as trainer_lib

    config = _reach_sweep(tmp_path, iterations=3, table=(
        "run.seed = [0, 3]\nppo.clip = [0.2, 0.05]\nppo.policy_lr = [3e-4, 1e-3]\n"))
    out = tmp_path / "out"
    lines = []
    sweep.run(config, out, echo=lines.append)
    assert any("training 8 members in one program" in line for line in lines), lines
    rows = [json.loads(r) for r in (out / sweep.ROWS).read_text().splitlines()]
    assert [r["member"] for r in rows] == list(range(8))
    returns = []
    for index in (0, 7):                  # (seed 0, clip 0.2, lr 3e-4), (3, 0.05, 1e-3)
        alone = tmp_path / f"alone_{index}"
        train_commands.train(out / sweep.BASE, alone, sweep_spec.overrides(
            {k: rows[index][k] for k in ("run.seed", "ppo.clip", "ppo.policy_lr")}),
            echo=lambda *_: None)
        member = out / sweep.MEMBERS / f"{index:03d}"
        trainer = train_commands.make_trainer(train_commands.load_run_config(member))
        states = [trainer_lib.load_checkpoint(trainer.init(), d, echo=lambda *_: None)
                  for d in (alone, member)]
        for a, b in zip(*(jax.tree_util.tree_leaves(s.ppo.policy_params) for s in states)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
        by_alone = trainer_lib.read_metrics(alone)[-1]
        by_member = trainer_lib.read_metrics(member)[-1]
        for name in ("return", "policy_loss", "value_loss", "episode_length"):
            assert by_member[name] == pytest.approx(by_alone[name], rel=1e-4, abs=1e-6), name
        returns.append(by_member["return"])
    assert returns[0] != returns[1]                     # the members differ
    summary = train_commands.evaluate(out / sweep.MEMBERS / "001", episodes=2,
                                      echo=lambda *_: None)[0]
    assert np.isfinite(summary["return"])


@pytest.mark.parametrize("table, overrides, why_not", [
    ("run.seed = [0, 1]\n", (), "run.devices is 0, and members share one program on one device"),
    ("run.seed = [0, 1]\n", ("run.devices=1",), None),
    ('"ppo.clip" = [0.1, 0.2]\n"highjump.gravity" = [[0, -9.8, 0], [0, -3.7, 0]]\n',
     ("run.devices=1",), None),
    ('"ppo.hidden" = [[8], [16]]\n', ("run.devices=1",),
     "ppo.hidden cannot differ between the members of one program"),
    ("run.seed = [0, 1]\nvmap = false\n", ("run.devices=1",), "vmap = false"),
])
def test_a_training_sweep_says_why_its_members_are_not_one_program(tmp_path, table, overrides,
                                                                   why_not):
    """The jump configs train on every core (`devices = 0`): a seed sweep of one trains its
    members one run each, and says so, until it asks for one device."""
    config = tmp_path / "highjump_sweep.toml"
    config.write_text(open("configs/highjump.toml").read() + "\n[sweep]\n" + table)
    reason = sweep.why_not_one_program(sweep.load(config, overrides))
    if why_not is None:
        assert reason is None
    else:
        assert why_not in reason
