"""The README as a newcomer uses it: every Python block and every command line of it runs as
written, made small by a few overrides (fewer iterations, environments and epochs; a smaller
batch; a data folder with a few clips of each kind), in a fresh folder beside which the configs
and benchmarks are linked. Anything a user types from the README that fails fails here."""

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")

# Python blocks, smaller: (what the README says, what the test runs)
PYTHON_SMALLER = [("4096", "16"), ("(600, 1)", "(30, 1)"), ("1600", "60"),
                  ("budget=20", "budget=6")]
SMALL_RUN = ["--set", "run.iterations=1", "--set", "run.envs=8", "--set",
             "run.steps_per_iteration=8", "--set", "ppo.minibatch_size=32",
             "--set", "ppo.hidden=[16, 16]"]
# Command lines, smaller: appended to the line whose start is the key (the longest that fits).
COMMAND_SMALLER = {
    "takeoff search": ["--set", "search.budget=5"],
    "takeoff pvae dataset": ["--data-dir", "{small_data}"],
    "takeoff pvae train": ["--set", "train.epochs=1"],
    "takeoff train configs/reach.toml": ["--set", "run.iterations=2"],
    "takeoff train configs/": SMALL_RUN,
    "takeoff train --resume": ["--set", "run.iterations=2"],
    "takeoff eval": ["--episodes", "2"],
    "takeoff sweep configs/sweep_highjump_body.toml": [
        "--set", "sweep.physics.leg_length_scale={linspace = [0.8, 1.2, 4]}"],
    "takeoff sensitivity": ["--set", "sensitivity.seconds=0.2"],
    "python benchmarks/jump.py report": ["--episodes", "2"],
}
NOT_RUN = ("pip install", "TAKEOFF_DATA=")     # setting up, and the test suite itself


def blocks(language):
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def command_lines():
    """The README's shell lines (continuations joined, comments dropped) that it asks a user
    to run."""
    lines = []
    for block in blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words and not line.startswith(NOT_RUN):
                lines.append(words)
    return lines


def smaller(words, small_data):
    text = " ".join(words)
    key = max((k for k in COMMAND_SMALLER if text.startswith(k)), key=len, default=None)
    extra = [] if key is None else COMMAND_SMALLER[key]
    return words + [w.replace("{small_data}", str(small_data)) for w in extra]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, data_dir):
    """A fresh folder with the configs and benchmarks linked, a small data folder (one CMU
    clip per subject, a DeepMimic walk and flip), and an environment whose data default is the
    reference data and whose compilations are cached across the commands."""
    home = tmp_path_factory.mktemp("readme")
    for name in ("configs", "benchmarks"):
        (home / name).symlink_to(ROOT / name)
    small = home / "small_data"
    for subject in ("01", "02", "03"):
        (small / "cmu" / subject).mkdir(parents=True)
        for name in (f"{subject}.asf", f"{subject}_01.amc"):
            (small / "cmu" / subject / name).symlink_to(data_dir / "cmu" / subject / name)
    (small / "deepmimic" / "motions").mkdir(parents=True)
    for clip in ("humanoid3d_walk.txt", "humanoid3d_backflip.txt"):   # the flip: repeat_clips
        (small / "deepmimic" / "motions" / clip).symlink_to(
            data_dir / "deepmimic" / "motions" / clip)
    env = {**os.environ, "TAKEOFF_DATA": str(data_dir),
           "JAX_COMPILATION_CACHE_DIR": str(home / "jax_cache"),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("JAX_ENABLE_X64", None)
    return home, small, env


def run(words, home, env):
    result = subprocess.run(words, cwd=home, env=env, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, (f"{' '.join(words)} failed ({result.returncode}):\n"
                                    f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    return result.stdout


def test_the_readme_has_what_this_test_runs():
    assert len(blocks("python")) >= 4 and len(command_lines()) >= 15


def test_every_python_block_runs(workspace, data_dir):
    """The blocks in order, as one session (later blocks use earlier names)."""
    home, _, env = workspace
    code = "\n".join(blocks("python")).replace("../shared/data", str(data_dir))
    for said, small in PYTHON_SMALLER:
        assert said in code, f"the README no longer says {said!r}: update PYTHON_SMALLER"
        code = code.replace(said, small)
    (home / "readme_blocks.py").write_text(code)
    run([sys.executable, "readme_blocks.py"], home, env)
    assert (home / "cartwheel.png").stat().st_size > 1000
    assert (home / "my_search.jsonl").exists()


def test_every_command_line_runs_in_order(workspace):
    home, small, env = workspace
    for words in command_lines():
        words = smaller(words, small)
        if words[0] != "takeoff":
            words = [sys.executable if words[0] == "python" else words[0], *words[1:]]
        run(words, home, env)
    # the float32 high jump's gradients, finite and agreeing with the finite differences
    study = json.loads((home / "runs/sensitivity_highjump/sensitivity.json").read_text())
    assert all(row["agrees"] for row in study["rows"]), study["rows"]
    for made in ("humanoid.xml", "poses.npz", "runs/pvae/pvae.msgpack", "walk.gif", "jump.gif",
                 "runs/imitate_walk/learning_curve.png", "runs/report/flop_peak.png",
                 "runs/report/flop_above_below.png"):
        assert (home / made).exists(), made
