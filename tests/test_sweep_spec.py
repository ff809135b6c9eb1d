"""A config's [sweep] table expanded into members (`agents.sweep_spec`): grid counts and order,
random draws reproducible from the seed and in range, grids crossed with draws, and bad tables
refused naming the key; members applied to a real config as overrides."""

import tomllib

import numpy as np
import pytest

from agents.commands import train_commands
from agents.config import ConfigError
from agents.sweep_spec import expand, overrides


def table(text):
    return tomllib.loads(text)["sweep"]


def test_a_grid_is_every_combination_the_first_key_slowest():
    members = expand(table("""
[sweep]
ppo.clip = [0.1, 0.2, 0.3]
"world.gravity" = [-9.81, -3.7]
"""), "s.toml")
    assert len(members) == 6
    assert members[:2] == [{"ppo.clip": 0.1, "world.gravity": -9.81},
                           {"ppo.clip": 0.1, "world.gravity": -3.7}]
    assert members[-1] == {"ppo.clip": 0.3, "world.gravity": -3.7}
    assert len({tuple(m.values()) for m in members}) == 6


def test_draws_are_reproducible_in_range_and_follow_the_seed():
    text = """
[sweep]
ppo.policy_lr = {log_uniform = [1e-5, 1e-3]}
highjump.z_min = {uniform = [0.4, 0.6]}
run.seed = {choice = [3, 5, 7]}
samples = 400
seed = %d
"""
    members = expand(table(text % 1), "s.toml")
    assert members == expand(table(text % 1), "s.toml")
    assert members != expand(table(text % 2), "s.toml")
    assert len(members) == 400
    lr = np.array([m["ppo.policy_lr"] for m in members])
    z = np.array([m["highjump.z_min"] for m in members])
    assert lr.min() >= 1e-5 and lr.max() <= 1e-3 and z.min() >= 0.4 and z.max() <= 0.6
    # log-uniform: the log spreads evenly (a quarter of the draws in each quarter of its range)
    quarters = np.histogram(np.log10(lr), bins=4, range=(-5, -3))[0]
    assert (np.abs(quarters - 100) < 35).all(), quarters
    assert np.histogram(z, bins=4, range=(0.4, 0.6))[0].min() > 65
    assert {m["run.seed"] for m in members} == {3, 5, 7}


def test_a_grid_crossed_with_draws_repeats_the_same_draws_at_each_grid_point():
    members = expand(table("""
[sweep]
ppo.clip = [0.1, 0.2]
highjump.z_min = {uniform = [0.4, 0.6]}
samples = 3
"""), "s.toml")
    assert len(members) == 6
    first = [m["highjump.z_min"] for m in members[:3]]
    assert first == [m["highjump.z_min"] for m in members[3:]]
    assert [m["ppo.clip"] for m in members] == [0.1] * 3 + [0.2] * 3
    # adding a grid key does not change the draws
    alone = expand(table("[sweep]\nhighjump.z_min = {uniform = [0.4, 0.6]}\nsamples = 3\n"),
                   "s.toml")
    assert [m["highjump.z_min"] for m in alone] == first


@pytest.mark.parametrize("text, message", [
    ("[sweep]\nppo.clip = []\n", r"s.toml: sweep.ppo.clip is an empty list"),
    ("[sweep]\nppo.clip = 0.2\n", r"sweep.ppo.clip must be a list of values or a distribution"),
    ("[sweep]\nppo.clip = {uniform = [0.3, 0.1]}\nsamples = 2\n",
     r"sweep.ppo.clip.uniform must be \[low, high\] with low ≤ high"),
    ("[sweep]\nppo.clip = {uniform = [0.1, 'a']}\nsamples = 2\n",
     r"sweep.ppo.clip.uniform must be \[low, high\], two numbers"),
    ("[sweep]\nppo.policy_lr = {log_uniform = [0, 1e-3]}\nsamples = 2\n",
     r"sweep.ppo.policy_lr.log_uniform needs low > 0"),
    ("[sweep]\nrun.seed = {choice = []}\nsamples = 2\n", r"sweep.run.seed.choice must be a non-"),
    ("[sweep]\nppo.clip = {uniform = [0.1, 0.3], choice = [1]}\nsamples = 2\n",
     r"sweep.ppo.clip must name one distribution"),
    ("[sweep]\nppo.clip = {uniform = [0.1, 0.3]}\n", r"sweep.samples must say how many draws"),
    ("[sweep]\nppo.clip = [0.1]\nsamples = 4\n", r"sweep.samples = 4 is given, but no key is"),
    ("[sweep]\nppo.clip = {uniform = [0.1, 0.3]}\nsamples = 0\n",
     r"sweep.samples must be at least 1"),
    ("[sweep]\nppo.clip = {uniform = [0.1, 0.3]}\nsamples = 2\nseed = -1\n",
     r"sweep.seed must be a whole number ≥ 0"),
    ("[sweep]\nsamples = 2\n", r"\[sweep\] names no key to sweep"),
])
def test_bad_tables_name_the_key(text, message):
    with pytest.raises(ConfigError, match=message):
        expand(table(text), "s.toml")


def test_an_empty_table_and_a_sweep_too_large_are_refused():
    with pytest.raises(ConfigError, match=r"s.toml: \[sweep\] must be a table naming"):
        expand({}, "s.toml")
    tens = {key: list(range(10)) for key in "abcdef"}
    with pytest.raises(ConfigError, match=r"\[sweep\] makes 1,000,000 members, more than"):
        expand(tens, "s.toml")
    assert len(expand(dict(list(tens.items())[:5]), "s.toml")) == 100_000


def test_members_apply_to_a_config_and_an_unknown_key_is_named_there():
    members = expand(table("""
[sweep]
ppo.clip = [0.1, 0.25]
highjump.takeoff = [[1.65, 1.00, 0.88, -2.21]]
"""), "s.toml")
    configs = [train_commands.load_config("configs/highjump.toml", overrides(m))
               for m in members]
    assert [c.ppo.clip for c in configs] == [0.1, 0.25]
    assert all(c.task.takeoff == (1.65, 1.0, 0.88, -2.21) for c in configs)
    [member] = expand(table("[sweep]\nppo.klip = [0.1]\n"), "s.toml")
    with pytest.raises(ConfigError, match="unknown key 'ppo.klip'"):
        train_commands.load_config("configs/highjump.toml", overrides(member))
    # an unknown distribution reads as a namespace: the config refuses the key it makes
    [member] = expand(table("[sweep]\nppo.clip = {normal = [0.1]}\n"), "s.toml")
    with pytest.raises(ConfigError, match="ppo.clip.normal=0.1"):
        train_commands.load_config("configs/highjump.toml", overrides(member))


def test_linspace_and_logspace_make_grid_keys():
    members = expand(table("""
[sweep]
physics.leg_length_scale = {linspace = [0.8, 1.2, 5]}
physics.gravity_scale = {logspace = [0.1, 10.0, 3]}
"""), "s.toml")
    assert len(members) == 15
    assert [m["physics.leg_length_scale"] for m in members[::3]] == pytest.approx(
        [0.8, 0.9, 1.0, 1.1, 1.2])
    assert [m["physics.gravity_scale"] for m in members[:3]] == pytest.approx([0.1, 1.0, 10.0])


@pytest.mark.parametrize("spec, message", [
    ("{linspace = [0.8, 1.2]}", r"sweep\.k\.linspace must be \[low, high, n\]"),
    ("{linspace = [0.8, 1.2, 2.5]}", "a whole number of values"),
    ("{linspace = [0.8, 1.2, 0]}", "n ≥ 1"),
    ("{logspace = [0.0, 1.0, 3]}", r"sweep\.k\.logspace needs ends > 0"),
    ("{linspace = [0.0, 1.0, 1000000]}", "more than 100,000"),
])
def test_bad_ranges_are_refused_naming_the_key(spec, message):
    with pytest.raises(ConfigError, match=message):
        expand(table(f"[sweep]\nk = {spec}\n"), "s.toml")
