"""The `takeoff` command line: help, `characters`, `mjcf`, and errors a user can act on."""

import importlib
import xml.etree.ElementTree as ET

import pytest

from agents.commands.cli import main


def run(argv, capsys):
    """main(argv) → (exit code, stdout, stderr); SystemExit is an exit, not a failure."""
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def test_help_lists_the_subcommands(capsys):
    code, out, _ = run(["--help"], capsys)
    assert code == 0
    assert "characters" in out and "mjcf" in out
    assert "usage: takeoff" in out


def test_no_command_prints_help(capsys):
    code, out, _ = run([], capsys)
    assert code == 0
    assert "characters" in out and "mjcf" in out


def test_characters_lists_the_builtin_characters(capsys):
    code, out, _ = run(["characters"], capsys)
    assert code == 0
    rows = {line.split()[0]: line.split() for line in out.splitlines()[1:] if line.strip()}
    # name, links, nq, DoF, path DoF, mass, height
    assert rows["humanoid"][1:5] == ["15", "43", "34", "13"]
    assert float(rows["humanoid"][5]) == pytest.approx(45.0)
    assert float(rows["humanoid"][6]) == pytest.approx(1.619, abs=1e-3)
    assert rows["quadruped"][3:5] == ["72", "24"]
    assert [rows[f"snake:{n}"][3] for n in (10, 22, 63)] == ["36", "72", "195"]


def test_characters_reads_a_deepmimic_file(data_dir, capsys):
    path = data_dir / "deepmimic" / "characters" / "dog3d.txt"
    code, out, _ = run(["characters", str(path)], capsys)
    assert code == 0
    row = out.splitlines()[1].split()
    assert row[0] == "dog3d.txt"
    assert row[1:4] == ["23", "83", "64"]


def test_mjcf_writes_a_file_that_parses(tmp_path, capsys):
    out_file = tmp_path / "s.xml"
    code, out, _ = run(["mjcf", "snake:3", "--out", str(out_file)], capsys)
    assert code == 0
    assert str(out_file) in out
    root = ET.parse(out_file).getroot()
    assert root.tag == "mujoco" and root.get("model") == "snake_3"
    assert len(root.findall(".//worldbody//body")) == 4
    assert len(root.findall(".//joint[@type='ball']")) == 3
    assert list(tmp_path.iterdir()) == [out_file]     # no temporary file left behind


def test_mjcf_to_standard_output(capsys):
    code, out, _ = run(["mjcf", "humanoid"], capsys)
    assert code == 0
    root = ET.fromstring(out)
    assert len(root.findall(".//worldbody//body")) == 15


@pytest.mark.parametrize("command", [["characters", "unicorn"], ["mjcf", "unicorn"]])
def test_unknown_character_exits_with_a_message_naming_it(command, capsys):
    with pytest.raises(SystemExit) as info:
        main(command)
    message = str(info.value.code)
    assert info.value.code != 0
    assert "unicorn" in message
    assert "humanoid" in message        # and says what is known


@pytest.mark.parametrize("spec", ["snake:abc", "snake:0", "quadruped:2"])
def test_bad_character_argument_exits_with_a_message_naming_it(spec, capsys):
    """Bug (reported): `snake:abc` escapes as a bare ValueError from int(), `snake:0` as the
    builder's ValueError, and `quadruped:2` passes 2 as the builder's first parameter (its
    dtype) and escapes as a TypeError from JAX."""
    with pytest.raises(SystemExit) as info:
        main(["mjcf", spec])
    assert info.value.code != 0
    assert spec in str(info.value.code)


def test_eval_needs_at_least_one_episode(tmp_path, capsys):
    """Bug (reported): `--episodes 0` was accepted and ended in an IndexError."""
    code, _, err = run(["eval", str(tmp_path), "--episodes", "0"], capsys)
    assert code == 2
    assert "--episodes: must be a whole number ≥ 1; got '0'" in err


def test_eval_renders_only_to_a_gif(tmp_path, capsys):
    code, _, err = run(["eval", str(tmp_path), "--render", "out.mp4"], capsys)
    assert code == 2
    assert "--render: the animation is written as a GIF; got 'out.mp4'" in err


@pytest.mark.parametrize("command, module, function", [
    (["train", "run.toml"], "train_commands", "train"),
    (["eval", "run"], "train_commands", "evaluate"),
    (["pvae", "train", "pvae.toml"], "pvae_commands", "train"),
])
def test_an_error_that_is_not_the_user_s_keeps_its_traceback(command, module, function,
                                                             monkeypatch):
    """Bug (reported): the commands caught every ValueError, so a genuine bug ended as a
    one-line message without its traceback. Only the project's own errors are reported."""
    def broken(*args, **kwargs):
        raise ValueError("a bug, not a user error")

    monkeypatch.setattr(importlib.import_module(f"agents.commands.{module}"), function, broken)
    with pytest.raises(ValueError, match="a bug"):
        main(command)
