"""Data-parallel training (`agents.rl.parallel`): the environments split over two local devices,
or over two processes of one `jax.distributed` run on localhost (`takeoff train --processes 2`),
compute what one device computes, to float32 rounding; the rollout runs on each device's own
environments; a multi-process run's checkpoint resumes in one process; Ctrl-C stops every
process with a checkpoint; what cannot be split or joined is refused with the numbers.

The device count of a JAX process is fixed when its backend starts, and a process joins one
distributed run, so the runs are fresh Python processes (float32, as a user runs them), which
share a compilation cache."""

import gc
import json
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import jax
import numpy as np
import pytest

from agents.checkpoint import read_msgpack
from agents.commands import cli, launch
from agents.rl import parallel

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "configs/reach.toml"
# reach with 16 environments (8 per device or process) stepped 4 at a time (so each device
# chunks its own 8), tiny networks, four minibatches
SMALL = ["run.iterations=2", "run.envs=16", "run.steps_per_iteration=16",
         "run.checkpoint_every=2", "run.chunk=4", "ppo.hidden=[16, 16]",
         "ppo.minibatch_size=64"]

# One process: the 2-device run first (its request gives the CPU backend two devices), then
# the 1-device run, the reference of every comparison here; and what the 2-device programs
# communicate.
TWO_DEVICES = r"""
import json, re, sys
import jax
from agents.commands import train_commands
from agents.rl import parallel

out, overrides = sys.argv[1], sys.argv[2:]
quiet = lambda *_: None
two, state = train_commands.train("configs/reach.toml", f"{out}/two", [*overrides, "run.devices=2"],
                                  echo=quiet)
train_commands.train("configs/reach.toml", f"{out}/one", overrides, echo=quiet)

def collectives(text):
    '''{operation: [the computations of the compiled program that hold it]}'''
    found, computation = {}, None
    for line in text.splitlines():
        if line and not line[0].isspace() and line.rstrip().endswith("{"):
            computation = "ENTRY" if line.startswith("ENTRY") else line.split()[0]
        for op in ("all-gather", "all-reduce", "all-to-all", "collective-permute",
                   "reduce-scatter"):
            if re.search(rf"\b{op}(-start)?\(", line):
                found.setdefault(op, []).append(computation)
    return found

state = parallel.lay_out(state, two.state_sharding)
collected = two.collect(state)
print(json.dumps({
    "devices": len(jax.devices()),
    "rollout": collectives(two._compiled[None].lower(state, two.env_params).compile().as_text()),
    "update": collectives(two._learn_compiled.lower(
        *parallel.lay_out((state, collected), two._learn_inputs)).compile().as_text()),
    "update_devices": len(two.update_layout.mesh.devices.ravel()),
    "env_shards": [list(s.data.shape) for s in state.runner.envs.obs.addressable_shards],
}))
"""


def environment(cache):
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(cache),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    for name in ("JAX_ENABLE_X64", "XLA_FLAGS", "JAX_NUM_CPU_DEVICES"):
        env.pop(name, None)
    return env


def run(words, cache, timeout=300):
    result = subprocess.run([sys.executable, *words], cwd=ROOT, env=environment(cache),
                            capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, (f"{' '.join(words)} failed ({result.returncode}):\n"
                                    f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    return result.stdout


def takeoff_train(*words):
    return ["-m", "agents.commands.cli", "train", *words]


def overrides(extra=()):
    return [word for o in [*SMALL, *extra] for word in ("--set", o)]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("jax_cache")


@pytest.fixture(scope="module")
def device_runs(tmp_path_factory, cache):
    """The run on two local devices and on one (the reference), and what the two-device
    programs communicate."""
    out = tmp_path_factory.mktemp("devices")
    stdout = run(["-c", TWO_DEVICES, str(out), *SMALL], cache)
    return out, json.loads(stdout.strip().splitlines()[-1])


def checkpoint_leaves(run_dir):
    return [np.asarray(leaf) for leaf in read_msgpack(Path(run_dir) / "checkpoint.msgpack",
                                                      "no checkpoint")]


def assert_same_run(run_dir, reference):
    """Every leaf of the two checkpoints (networks, optimiser states, observation statistics,
    the environments' states, keys, counters) and the logged metrics agree: whole numbers and
    keys exactly, floats to float32 rounding (sums taken in another order)."""
    leaves, expected = checkpoint_leaves(run_dir), checkpoint_leaves(reference)
    assert len(leaves) == len(expected)
    for leaf, want in zip(leaves, expected):
        assert leaf.shape == want.shape and leaf.dtype == want.dtype
        if leaf.dtype.kind == "f":
            np.testing.assert_allclose(leaf, want, rtol=1e-5, atol=1e-5)
        else:
            np.testing.assert_array_equal(leaf, want)
    records = [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text()
               .splitlines()]
    wanted = [json.loads(line) for line in (Path(reference) / "metrics.jsonl").read_text()
              .splitlines()]
    assert [r["iteration"] for r in records] == [r["iteration"] for r in wanted] == [1, 2]
    for record, want in zip(records, wanted):
        for key in ("reward", "policy_loss", "value_loss", "approx_kl", "env/distance"):
            np.testing.assert_allclose(record[key], want[key], rtol=1e-4, atol=1e-6)


def test_two_local_devices_compute_what_one_device_computes(device_runs):
    out, found = device_runs
    assert found["devices"] == 2
    assert_same_run(out / "two", out / "one")


def test_the_rollout_steps_each_device_s_own_environments_and_the_update_runs_on_one(
        device_runs):
    """Compiled for two devices in one process, the rollout communicates nothing (each device
    steps its half of the environments, in its own chunks), and the update runs on the first
    device alone (its matrix products use every core there), so it communicates nothing
    either."""
    _, found = device_runs
    assert found["env_shards"] == [[8, 10], [8, 10]]
    assert found["rollout"] == {}
    assert found["update_devices"] == 1 and found["update"] == {}


def test_two_processes_compute_what_one_computes_and_the_checkpoint_resumes_in_one(
        device_runs, cache, tmp_path):
    out, _ = device_runs
    run_dir = tmp_path / "two_processes"
    stdout = run(takeoff_train(CONFIG, "--out", str(run_dir), "--processes", "2",
                               *overrides()), cache)
    assert "split over 2 devices in 2 processes" in stdout
    assert stdout.count("iter     2/2") == 1                     # process 0 shows progress
    assert sorted(p.name for p in run_dir.iterdir()) == [      # process 0 held it
        ".lock", "checkpoint.msgpack", "config.json", "learning_curve.png", "metrics.jsonl"]
    assert_same_run(run_dir, out / "one")
    # An ordinary checkpoint: one process resumes it and goes on.
    run(takeoff_train("--resume", str(run_dir), "--set", "run.iterations=3"), cache)
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in records] == [1, 2, 3]
    assert records[-1]["samples"] == 3 * 16 * 16
    assert all(np.isfinite(leaf).all() for leaf in checkpoint_leaves(run_dir)
               if leaf.dtype.kind == "f")


def _running(run_dir) -> list:
    """The processes whose command line names run_dir."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            words = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if entry.name.isdigit() and str(run_dir).encode() in words:
            found.append(int(entry.name))
    return found


def test_ctrl_c_stops_every_process_with_a_checkpoint(cache, tmp_path):
    run_dir = tmp_path / "interrupted"
    launcher = subprocess.Popen(
        [sys.executable, *takeoff_train(CONFIG, "--out", str(run_dir), "--processes", "2",
                                        *overrides(["run.iterations=100000",
                                                    "run.checkpoint_every=1000"]))],
        cwd=ROOT, env=environment(cache), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)
    log = run_dir / "metrics.jsonl"
    try:
        deadline = time.monotonic() + 240
        while not (log.exists() and log.read_text().count("\n") >= 2):
            assert launcher.poll() is None, launcher.communicate()[0][-3000:]
            assert time.monotonic() < deadline, "no iteration logged in 4 minutes"
            time.sleep(0.2)
        launcher.send_signal(signal.SIGINT)
        logged_at_signal = log.read_text().count("\n")
        try:
            output, _ = launcher.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            launcher.kill()
            for pid in _running(run_dir):    # its children, in their own sessions, with it
                os.kill(pid, signal.SIGKILL)
            output = launcher.communicate()[0]
            launcher_lines = [line for line in output.splitlines()
                              if line.startswith("takeoff train:")]
            pytest.fail(f"the run did not stop within 2 minutes of Ctrl-C: {logged_at_signal} "
                        f"iterations logged at the signal, {log.read_text().count(chr(10))} "
                        f"at the kill; the launcher said {launcher_lines}; the output's end:\n"
                        + output[-3000:])
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 130, output[-3000:]
    assert "stopping all processes" in output and "interrupted: checkpoint at iteration" in output
    last = json.loads(log.read_text().splitlines()[-1])["iteration"]
    assert last >= 2
    counters = [int(leaf) for leaf in checkpoint_leaves(run_dir)
                if leaf.dtype == np.int32 and leaf.shape == ()]
    assert last in counters and last * 16 * 16 in counters      # its iterations and samples
    assert _running(run_dir) == []


def _stand_in(ready, handler="lambda *_: sys.exit(130)", seconds=30):
    """A stand-in for a `takeoff train` child: it sets `handler` for SIGINT and SIGTERM (by
    default it ends as an interrupted run does, 130), says so with a file in `ready`, and
    ends by itself after `seconds`, as a finished run does (0)."""
    code = ("import os, pathlib, signal, sys, time\n"
            f"signal.signal(signal.SIGINT, {handler})\n"
            f"signal.signal(signal.SIGTERM, {handler})\n"
            f"pathlib.Path({str(ready)!r}, str(os.getpid())).touch()\n"
            f"time.sleep({seconds})\n")
    return [sys.executable, "-c", code]


def _wait_until_ready(ready, count):
    deadline = time.monotonic() + 120
    while len(list(Path(ready).iterdir())) < count:
        assert time.monotonic() < deadline, "the stand-in children did not start in 2 minutes"
        time.sleep(0.05)


def test_a_ctrl_c_that_lands_in_a_garbage_collector_callback_still_stops_the_run(
        monkeypatch, tmp_path):
    """Python only prints an exception raised inside a gc callback, so a launcher that took
    Ctrl-C as KeyboardInterrupt lost one landing there and waited for its children forever;
    one whose handler only notes the signal passes it on."""
    monkeypatch.setattr(launch, "child_commands", lambda args, processes, port:
                        [_stand_in(tmp_path)] * processes)
    sent = []

    def sleep_after_a_ctrl_c_in_a_gc_callback(seconds):
        if not sent:                  # the launcher is waiting for its children: Ctrl-C now
            _wait_until_ready(tmp_path, 2)

            def callback(phase, info):
                if phase == "start" and not sent:
                    sent.append(True)
                    os.kill(os.getpid(), signal.SIGINT)
            gc.callbacks.append(callback)
            try:
                gc.collect()
            finally:
                gc.callbacks.remove(callback)
        time.sleep(seconds)

    monkeypatch.setattr(launch, "time", types.SimpleNamespace(
        sleep=sleep_after_a_ctrl_c_in_a_gc_callback, monotonic=time.monotonic))
    said = []
    started = time.monotonic()
    status = launch.launch([], 2, echo=lambda *words, **_: said.extend(words))
    assert sent and status == 130
    assert time.monotonic() - started < 25          # the children did not run out their time
    assert any("stopping all processes" in words for words in said)


def test_a_second_ctrl_c_kills_children_that_do_not_stop(tmp_path):
    children = [subprocess.Popen(_stand_in(tmp_path, "signal.SIG_IGN")) for _ in range(2)]
    _wait_until_ready(tmp_path, 2)
    started = time.monotonic()
    assert launch._wait(children, [], [signal.SIGINT, signal.SIGINT], print) == 130
    for child in children:
        child.wait(timeout=10)
        assert child.returncode == -signal.SIGKILL
    assert time.monotonic() - started < 10


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_children_that_stop_as_interrupted_give_the_run_their_status(tmp_path, stop):
    """The run's status is the children's 130 (an interrupted run) for either stop signal, not
    the launcher's own 128 + its number."""
    children = [subprocess.Popen(_stand_in(tmp_path)) for _ in range(2)]
    _wait_until_ready(tmp_path, 2)
    failed = []
    assert launch._wait(children, failed, [stop], print) == 130
    assert [child.returncode for child in children] == [130, 130]
    assert failed in ([0], [1])          # whichever child the launcher saw end first


def test_a_child_ended_by_the_signal_itself_gives_128_plus_its_number(tmp_path):
    children = [subprocess.Popen(_stand_in(tmp_path, "signal.SIG_DFL")) for _ in range(2)]
    _wait_until_ready(tmp_path, 2)
    assert launch._wait(children, [], [signal.SIGTERM], print) == 128 + signal.SIGTERM


def test_the_launcher_imports_no_jax(tmp_path):
    """`takeoff train --processes N` starts no JAX backend of its own (launch.py's promise)."""
    script = ("import sys\n"
              "from agents.commands import cli, launch\n"
              "launch.launch = lambda args, processes: print('jax' in sys.modules) or 0\n"
              f"cli.main(['train', {CONFIG!r}, '--out', {str(tmp_path / 'r')!r}, "
              "'--processes', '2'])\n")
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.stdout.strip() == "False", done.stdout + done.stderr


def test_environments_that_cannot_be_split_evenly_are_refused_naming_both_numbers():
    message = parallel.check_split(15, types.SimpleNamespace(size=2), 2)
    assert "run.envs = 15 cannot be split evenly over the run's 2 devices" in message
    assert "run.devices = 2" in message
    assert parallel.check_split(16, types.SimpleNamespace(size=2), 2) is None


def test_more_devices_than_the_process_has_are_refused_before_anything_runs(tmp_path):
    jax.devices()          # the backend has started (in a fresh process the run asks for 64)
    with pytest.raises(SystemExit, match=r"run\.devices = 64, but this process has \d+ cpu "
                                         r"device.*xla_force_host_platform_device_count=64"):
        cli.main(["train", CONFIG, "--out", str(tmp_path / "r"), "--set", "run.devices=64"])
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("flags, message", [
    (["--num-processes", "2"], "--num-processes goes with --coordinator"),
    (["--coordinator", "localhost:1234", "--processes", "2"], "give one or the other"),
    (["--coordinator", "localhost"], "--coordinator must be HOST:PORT or auto"),
    (["--coordinator", "localhost:1234", "--process-id", "0"], "needs --num-processes N"),
    (["--coordinator", "localhost:1234", "--num-processes", "2", "--process-id", "2"],
     r"--process-id must be 0 … 1 with --num-processes 2; got 2"),
    (["--coordinator", "auto", "--process-id", "1"], "drop --process-id"),
    (["--processes", "0"], "must be a whole number ≥ 1"),
])
def test_multi_process_flags_that_do_not_go_together_are_refused(tmp_path, capsys, flags,
                                                                 message):
    with pytest.raises(SystemExit) as error:
        cli.main(["train", CONFIG, "--out", str(tmp_path / "r"), *flags])
    said = str(error.value.code) + capsys.readouterr().err
    assert message in said.replace("'", "")
    assert not (tmp_path / "r").exists()
