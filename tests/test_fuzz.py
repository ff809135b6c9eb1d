"""Malformed input, generated: configs, character / motion / motion-capture / dataset files and
run files (checkpoints, run configs, metrics and search logs), each made invalid on purpose —
cut short, bytes flipped, a NaN or an infinity, a number far too large, a value of the wrong
type, an empty file, a directory in the file's place. Every case must end in one of the
project's own errors, with a message naming the file (or the config key); a traceback of any
other kind, or a load that succeeds, fails the case.

The cases are built from the reference data and the repository's configs when the test module
is collected, so their number is known up front (`test_the_fuzz_runs_enough_cases`)."""

import json
import shutil
import tomllib
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from agents import config as config_io
from agents import sweep
from agents.checkpoint import CheckpointError, fill, read_msgpack, write_msgpack
from agents.commands import sensitivity_command, strategy_search, train_commands
from agents.config import ConfigError
from agents.datadir import data_dir_from
from agents.pose import pose_dataset, pvae
from agents.pose.pose_dataset import DatasetError
from agents.rl import trainer as trainer_lib
from bds.search import SearchError, SearchSettings, search
from jaxsim import characters, motion
from jaxsim.model import ModelError
from jaxsim.motion import MotionFileError
from jaxsim.runlog import LogError

ROOT = Path(__file__).resolve().parents[1]
DATA = data_dir_from()
PROJECT_ERRORS = (ConfigError, CheckpointError, DatasetError, ModelError, MotionFileError,
                  SearchError, LogError)


# ---- How a file is spoiled -------------------------------------------------------------------

def cut(fraction):
    """The file cut short at `fraction` of its bytes."""
    def spoil(data: bytes) -> bytes:
        return data[:max(1, int(len(data) * fraction))]
    spoil.__name__ = f"cut at {fraction:.0%}"
    return spoil


def flip(fraction, count=64):
    """`count` bytes overwritten at `fraction` of the file, as a disk fault would."""
    def spoil(data: bytes) -> bytes:
        start = min(int(len(data) * fraction), max(len(data) - count, 0))
        garbage = bytes((37 * i + 201) % 256 for i in range(count))
        return data[:start] + garbage + data[start + count:]
    spoil.__name__ = f"{count} bytes flipped at {fraction:.0%}"
    return spoil


def replace_nth(pattern, new, n=0):
    """The `n`-th match of the regular expression `pattern` replaced by `new`."""
    import re

    def spoil(data: bytes) -> bytes:
        text = data.decode()
        matches = list(re.finditer(pattern, text))
        assert len(matches) > n, f"no match {n} of {pattern!r}"
        m = matches[n]
        return (text[:m.start()] + new + text[m.end():]).encode()
    spoil.__name__ = f"{pattern!r} #{n} → {new!r}"
    return spoil


def empty(_):
    return b""


def binary(_):
    return bytes(range(256)) * 8


ALWAYS = [empty, binary, cut(0.5)]
NUMBER = r"-?\d+\.\d+(e-?\d+)?"


# ---- The cases: (id, build(tmp) -> path, load(path)) -----------------------------------------

def file_cases(kind, source, spoilers, load):
    cases = [(f"{kind}: {s.__name__}", source, s, load) for s in spoilers]
    cases.append((f"{kind}: a directory", source, "directory", load))
    return cases


def _humanoid():
    return characters.humanoid()


def load_character(path):
    characters.load_deepmimic(path)


def load_motion(path):
    motion.load_motion(path, _humanoid())


def load_asf(path):
    motion.load_asf(path)


ASF = DATA / "cmu" / "02" / "02.asf"


def load_amc(path):
    motion.load_amc(path, motion.load_asf(ASF))


def load_bvh(path):
    motion.load_bvh(path, length_scale=0.056444)


def load_dataset(path):
    pose_dataset.load(path, _humanoid())


def data_cases():
    character = DATA / "deepmimic" / "characters" / "humanoid3d.txt"
    clip = DATA / "deepmimic" / "motions" / "humanoid3d_walk.txt"
    amc = DATA / "cmu" / "02" / "02_01.amc"
    bvh = DATA / "cmu-bvh" / "131_01.bvh"
    cases = []
    cases += file_cases("character", character, ALWAYS + [
        cut(0.1), cut(0.9), flip(0.3), flip(0.7),
        replace_nth(r'"Mass"\s*:\s*' + NUMBER, '"Mass": NaN'),
        replace_nth(r'"Mass"\s*:\s*' + NUMBER, '"Mass": -3.0'),
        replace_nth(r'"AttachY"\s*:\s*' + NUMBER, '"AttachY": Infinity', 2),
        replace_nth(r'"Param0"\s*:\s*' + NUMBER, '"Param0": "thick"', 1),
        replace_nth(r'"Param0"\s*:\s*' + NUMBER, '"Param0": 1e999', 3),
        replace_nth(r'"Type"\s*:\s*"spherical"', '"Type": "wobbly"'),
        replace_nth(r'"Parent"\s*:\s*0', '"Parent": 99'),
        replace_nth(r'"Joints"', '"Jointz"'),
        replace_nth(r'"Shape"\s*:\s*"capsule"', '"Shape": 7'),
    ], load_character)
    cases += file_cases("motion", clip, ALWAYS + [
        cut(0.2), cut(0.8), flip(0.4), flip(0.9),
        replace_nth(NUMBER, "NaN", 5), replace_nth(NUMBER, "Infinity", 40),
        replace_nth(NUMBER, '"fast"', 17), replace_nth(NUMBER, "1e999", 60),
        replace_nth(r"\[\s*" + NUMBER + r"\s*,", "[-0.5,", 0),      # a negative frame time
        replace_nth(r'"Frames"', '"Framez"'), replace_nth(r",\s*" + NUMBER + r"\s*\]", "]", 3),
    ], load_motion)
    cases += file_cases("asf", ASF, ALWAYS + [
        cut(0.3), cut(0.7), flip(0.5),
        replace_nth(r"length\s+" + NUMBER, "length nan", 2),
        replace_nth(r"length\s+" + NUMBER, "length -4.0", 4),
        replace_nth(r"length\s+" + NUMBER, "length long", 3),
        replace_nth(r"direction\s+\S+", "direction inf", 1),
        replace_nth(r":bonedata", ":bonedatum"),
    ], load_asf)
    cases += file_cases("amc", amc, ALWAYS + [
        flip(0.5),
        replace_nth(NUMBER, "nan", 30), replace_nth(NUMBER, "inf", 300),
        replace_nth(NUMBER, "wobble", 1000), replace_nth(r"\nlfemur [^\n]*", "\nlfemur 1", 7),
        replace_nth(r"\nrfemur ", "\nrfemurx ", 2),
    ], load_amc)
    cases += file_cases("bvh", bvh, ALWAYS + [
        cut(0.02), flip(0.01), flip(0.6),
        replace_nth(r"Frames:\s*\d+", "Frames: many"),
        replace_nth(r"Frame Time:\s*\S+", "Frame Time: -0.1"),
        replace_nth(r"OFFSET\s+" + NUMBER, "OFFSET nan", 3),
        replace_nth(NUMBER, "nan", 400), replace_nth(NUMBER, "wobble", 900),
        replace_nth(r"CHANNELS 3", "CHANNELS 4", 2),
    ], load_bvh)
    return cases


def npz_cases():
    """Pose datasets: a small valid one, spoiled."""
    def build(tmp):
        n = 6
        model = _humanoid()
        from agents.pose import pose_features
        layout = pose_features.PoseLayout.of(model)
        path = tmp / "source.npz"
        pose_dataset.save(pose_dataset.PoseDataset(
            features=np.zeros((n, layout.feature_size), np.float32),
            targets=np.zeros((n, layout.target_size), np.float32),
            poses=np.zeros((n, model.nq), np.float32), clip_index=np.zeros(n, np.int32),
            clip_names=np.array(["a"])), path)
        return path
    return file_cases("pose dataset", build, ALWAYS + [cut(0.1), cut(0.9), flip(0.2),
                                                       flip(0.6, 512)], load_dataset)


# Checkpoints: a small pytree written by the trainer's writer, read as the trainer reads it.
TEMPLATE = {"policy": {"w": jnp.zeros((8, 4), jnp.float32), "b": jnp.zeros(4, jnp.float32)},
            "step": jnp.zeros((), jnp.int32)}


def build_checkpoint(tmp):
    path = tmp / "source.msgpack"
    import jax
    write_msgpack(path, [np.asarray(x) + 1 for x in jax.tree_util.tree_leaves(TEMPLATE)])
    return path


def load_checkpoint(path):
    fill(TEMPLATE, read_msgpack(path, "a checkpoint"), path, "the test's template")


def build_wrong_checkpoint(tmp):
    path = tmp / "source.msgpack"
    write_msgpack(path, [np.zeros((8, 5), np.float32), np.zeros(4), np.zeros(())])
    return path


def checkpoint_cases():
    cases = file_cases("checkpoint", build_checkpoint,
                       ALWAYS + [cut(f) for f in (0.05, 0.3, 0.7, 0.95, 0.99)]
                       + [flip(f, n) for f in (0.1, 0.4, 0.6, 0.9) for n in (1, 64)],
                       load_checkpoint)
    cases.append(("checkpoint: written for other settings", build_wrong_checkpoint, None,
                  load_checkpoint))
    return cases


# Run configs (config.json) and the two JSON-lines logs.

def build_run_config(tmp):
    path = tmp / "source.json"
    config = train_commands.load_config(ROOT / "configs" / "reach.toml")
    path.write_text(json.dumps(config.sections(), indent=2))
    return path


def load_run_config(path):
    train_commands.build_config(config_io.read_stored(path), str(path))


def build_metrics(tmp):
    path = tmp / "source" / trainer_lib.METRICS
    path.parent.mkdir()
    path.write_text("".join(json.dumps({"iteration": i, "samples": 16 * i, "seconds": 0.5 * i,
                                        "return": 1.0 * i}) + "\n" for i in range(1, 6)))
    return path


def load_metrics(path):
    trainer_lib.read_metrics(path.parent)


SEARCH = SearchSettings(strategy="random", budget=4)


def build_search_log(tmp):
    path = tmp / "source.jsonl"
    search(lambda x: [x[0], x[1] ** 2], [0, 0], [1, 2], SEARCH, log=path)
    return path


def load_search_log(path):
    search(lambda x: [x[0], x[1] ** 2], [0, 0], [1, 2],
           SearchSettings(strategy="random", budget=5), log=path)


def run_file_cases():
    cases = []
    cases += file_cases("run config", build_run_config, ALWAYS + [
        cut(0.9), replace_nth(r'"envs": \d+', '"envs": NaN'),
        replace_nth(r'"envs": \d+', '"envs": "many"'),
        replace_nth(r'"clip": [^,\n]+', '"clip": Infinity'),
        replace_nth(r'"run": \{', '"run": [{'), replace_nth(r'"task": "reach"', '"task": 5'),
        replace_nth(r'"seed": \d+', '"seed": 1e12'),
        replace_nth(r'"hidden": \[', '"hidden": ["wide", '),
    ], load_run_config)
    cases += file_cases("metrics log", build_metrics, [
        flip(0.3, 8), replace_nth(r'"return": 2\.0', '"return": NaN'),
        replace_nth(r'"return": 3\.0', '"return": Infinity'),
        replace_nth(r'\{"iteration": 2', '[{"iteration": 2'),
        replace_nth(r'"iteration": 3', '"iteration": "three"'),
        replace_nth(r'\n', '\n\x00\x01garbage\n', 1), binary,
        replace_nth(r'"seconds": 1\.0', '"seconds": 1e999'),
        replace_nth(r'"seconds": 1\.5, ', ''),
        replace_nth(r'"samples": 64', '"samples": -64'),
    ], load_metrics)
    cases += file_cases("search log", build_search_log, [
        flip(0.4, 16), binary,
        replace_nth(r'"feature": \[' + NUMBER, '"feature": [NaN', 0),
        replace_nth(r'"feature": \[' + NUMBER, '"feature": [1e999', 1),
        replace_nth(r'"feature": \[' + NUMBER + ", " + NUMBER + r"\]", '"feature": [0.5]', 2),
        replace_nth(r'"x": \[' + NUMBER, '"x": [7.5', 0),
        replace_nth(r'"x": \[' + NUMBER, '"x": ["left"', 1),
        replace_nth(r'"index": 1', '"index": -1'),
        replace_nth(r'"event": "plan"', '"event": "lunch"'),
        replace_nth(r'"event": "start"', '"event": "begin"'),
        replace_nth(r'"seed": 0', '"seed": 3'),
        replace_nth(r'"first_index": 0', '"first_index": "zero"'),
        replace_nth(r'"kinds": \["random"', '"kinds": ["lucky"'),
        replace_nth(r'"points": \[', '"points": [], "was": ['),
        replace_nth(r'"points": \[\[', '"points": [[7.0, '),
    ], load_search_log)
    return cases


# Configs: every key of every config in configs/, given a value it must refuse.

def config_loader(name, data):
    """How the config file `name` (its table `data`) is read: `load(path, overrides=())` —
    the P-VAE's, a search's (it names its black box), a sweep's (it has a [sweep] table), a
    sensitivity study's or a training's."""
    if "sweep" in data:
        return sweep.load
    schema = (pvae.PVAEConfig if name == "pvae.toml"
              else strategy_search.SearchConfig if "black_box" in data
              else sensitivity_command.SensitivityConfig if "sensitivity" in data else None)
    if schema is None:
        return train_commands.load_config
    return lambda path, overrides=(): config_io.load(path, schema, overrides)


def leaves(table, prefix=""):
    for key, value in table.items():
        if isinstance(value, dict):
            yield from leaves(value, f"{prefix}{key}.")
        else:
            yield prefix + key, value


def bad_values(value):
    """Values the key of `value` must refuse: of the wrong type, and out of range."""
    if isinstance(value, bool):
        return ['"yes"']
    if isinstance(value, int):
        return ["1.5", "1000000000000"]
    if isinstance(value, float):
        return ['"fast"', "nan"]
    if isinstance(value, str):
        return ["3"]
    return ['"a list"']                                           # lists


def config_cases():
    cases = []
    for path in sorted((ROOT / "configs").glob("*.toml")):
        data = tomllib.loads(path.read_text())
        loader = config_loader(path.name, data)
        for key, value in leaves(data):
            for bad in bad_values(value):
                override = f"{key}={bad}"
                cases.append((f"{path.name}: {override}", path, ("override", override, key),
                               loader))
        first = next(iter(data))
        section = first if isinstance(data[first], dict) else None
        unknown = f"{section}.no_such_key=1" if section else "no_such_key=1"
        cases.append((f"{path.name}: {unknown}", path, ("override", unknown, "no_such_key"),
                      loader))
        for spoil in (empty, binary, replace_nth(r"=\s*[^\n]+", "= ", 2)):
            cases.append((f"{path.name}: {spoil.__name__}", path, spoil, loader))
        cases.append((f"{path.name}: a directory", path, "directory", loader))
    return cases


CASES = data_cases() + npz_cases() + checkpoint_cases() + run_file_cases() + config_cases()


def test_the_fuzz_runs_enough_cases():
    assert len(CASES) >= 200, len(CASES)
    assert len({name for name, *_ in CASES}) == len(CASES)


@pytest.mark.parametrize("name, source, spoil, load", CASES, ids=[c[0] for c in CASES])
def test_malformed_input_is_one_of_our_errors_naming_the_file_or_key(
        name, source, spoil, load, tmp_path):
    source = source(tmp_path) if callable(source) else Path(source)
    target = tmp_path / ("spoiled" + "".join(source.suffixes))
    if source.name == trainer_lib.METRICS:                      # a run's log has its own name
        target = tmp_path / "spoiled" / trainer_lib.METRICS
        target.parent.mkdir()
    names = [target.name]
    if spoil == "directory":
        target.mkdir()
        call = lambda: load(target)                               # noqa: E731
    elif isinstance(spoil, tuple):                                # a config override
        _, override, key = spoil
        shutil.copyfile(source, target)
        names = [key]
        call = lambda: load(target, [override])                   # noqa: E731
    else:
        target.write_bytes(source.read_bytes() if spoil is None else spoil(source.read_bytes()))
        call = lambda: load(target)                               # noqa: E731
    try:
        call()
    except PROJECT_ERRORS as error:
        message = str(error)
        assert any(n in message for n in names), f"{type(error).__name__}: {message}"
    else:
        pytest.fail(f"{name}: accepted silently")
