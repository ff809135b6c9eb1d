"""BDS optimisers, the search loop (resume, batching, errors) and `takeoff search`."""

import dataclasses
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.commands import strategy_search
from agents.commands.cli import main
from agents.config import ConfigError
from jaxsim.atomic import hold_directory
from jaxsim.executor import LocalProcesses
from bds.landscapes import LandscapeSettings, StrategyLandscape
from bds.optimize import direct, maximize_lbfgs
from bds import feasibility
from bds.search import (Failure, SearchError, SearchSettings, logged_evaluations, search,
                        success_model)
from jaxsim.runlog import LogWarning
from test_cli import run as run_cli

# Standard global-optimisation test functions (Dixon & Szegő 1978; minima as in Jones et al. 1993).


def branin(x):
    x1, x2 = x[:, 0], x[:, 1]
    return ((x2 - 5.1 / (4 * np.pi ** 2) * x1 ** 2 + 5 / np.pi * x1 - 6) ** 2
            + 10 * (1 - 1 / (8 * np.pi)) * np.cos(x1) + 10)


HARTMANN_A = np.array([[3, 10, 30], [0.1, 10, 35], [3, 10, 30], [0.1, 10, 35]])
HARTMANN_C = np.array([1, 1.2, 3, 3.2])
HARTMANN_P = 1e-4 * np.array([[3689, 1170, 2673], [4699, 4387, 7470], [1091, 8732, 5547],
                              [381, 5743, 8828]])


def hartmann3(x):
    inner = np.sum(HARTMANN_A * (x[:, None, :] - HARTMANN_P) ** 2, axis=-1)
    return -np.sum(HARTMANN_C * np.exp(-inner), axis=-1)


SHEKEL_A = np.array([[4, 4, 4, 4], [1, 1, 1, 1], [8, 8, 8, 8], [6, 6, 6, 6], [3, 7, 3, 7]], float)
SHEKEL_C = np.array([0.1, 0.2, 0.2, 0.4, 0.4])


def shekel5(x):
    return -np.sum(1 / (np.sum((x[:, None, :] - SHEKEL_A) ** 2, axis=-1) + SHEKEL_C), axis=-1)


@pytest.mark.parametrize("fun, lower, upper, minimum", [
    (branin, [-5, 0], [10, 15], 0.397887),
    (hartmann3, [0, 0, 0], [1, 1, 1], -3.86278),
    (shekel5, [0] * 4, [10] * 4, -10.1532),
])
def test_direct_finds_global_minima_of_standard_functions(fun, lower, upper, minimum):
    result = direct(fun, lower, upper, max_evaluations=300)
    assert result.evaluations <= 400
    assert abs(result.value - minimum) <= 1e-4 * abs(minimum), result
    assert np.all(result.x >= lower) and np.all(result.x <= upper)
    np.testing.assert_allclose(fun(result.x[None])[0], result.value)


def test_direct_rejects_bad_bounds():
    with pytest.raises(ValueError, match="upper > lower"):
        direct(branin, [0, 0], [1, 0])


def test_lbfgs_finds_a_box_constrained_maximum_on_a_corner_and_inside():
    def corner(x):             # largest at (1, 0)
        return x[:, 0] - x[:, 1]

    def inside(x):             # a bump at (0.3, 0.7)
        return -jnp.sum((x - jnp.array([0.3, 0.7])) ** 2, axis=-1)
    point, value = maximize_lbfgs(corner, 2, jax.random.PRNGKey(0), starts=4, candidates=64)
    np.testing.assert_allclose(point, [1.0, 0.0], atol=1e-4)
    point, value = maximize_lbfgs(inside, 2, jax.random.PRNGKey(0), starts=4, candidates=16)
    np.testing.assert_allclose(point, [0.3, 0.7], atol=1e-4)


FAST = dict(gp_restarts=2, gp_steps=60, direct_evaluations=120, mc_samples=32, lbfgs_starts=4)


def landscape_and_counter():
    landscape = StrategyLandscape(LandscapeSettings(dim=3, strategies=5, seed=1))
    calls = []

    def g(x):
        calls.append(np.array(x))
        return landscape(x)
    return g, calls


def test_search_follows_algorithm_1_and_stays_in_bounds():
    g, calls = landscape_and_counter()
    settings = SearchSettings(budget=9, initial=3, explore=2, diverse=1, seed=5, **FAST)
    result = search(g, [0, 0, 0], [1, 1, 1], settings)
    assert result.kinds == ["initial"] * 3 + ["explore", "explore", "diverse"] * 2
    assert len(calls) == 9 and result.x.shape == (9, 3) and result.features.shape == (9, 1)
    assert np.all(result.x >= 0) and np.all(result.x <= 1)
    # Exploration picks go where there are no data: away from every earlier point.
    for i in (3, 4):
        gaps = np.linalg.norm(result.x[:i] - result.x[i], axis=1)
        assert gaps.min() > 0.2


def test_resume_after_a_crash_evaluates_nothing_twice(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(budget=8, initial=3, explore=1, diverse=1, batch=2, seed=2,
                              **FAST)
    landscape = StrategyLandscape(LandscapeSettings(dim=2, strategies=4, seed=3))
    evaluated, crashed = [], []

    def crashing(x):
        if len(evaluated) == 5 and not crashed:
            crashed.append(True)
            raise RuntimeError("simulated crash")
        evaluated.append(np.array(x))
        return landscape(x)

    with pytest.raises(RuntimeError, match="simulated crash"):
        search(crashing, [0, 0], [2, 1], settings, log=log)
    # Simulate a write cut off by the crash: a half line at the end of the log.
    with open(log, "a") as f:
        f.write('{"event": "evaluation", "ind')
    first_part = len(evaluated)
    with pytest.warns(LogWarning, match=r"its last line was cut off .*search\.jsonl\.torn"):
        result = search(crashing, [0, 0], [2, 1], settings, log=log)
    assert (tmp_path / "search.jsonl.torn").read_text() == '{"event": "evaluation", "ind\n'
    resumed = evaluated[first_part:]
    assert first_part == 5 and len(resumed) == 3
    points = np.array(evaluated)
    assert len({tuple(p) for p in points}) == 8          # every point evaluated exactly once
    assert {tuple(p) for p in result.x} == {tuple(p) for p in points}
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert sum(r["event"] == "evaluation" for r in logged) == 8
    # The same search in one go, without a crash, makes the same picks.
    fresh = search(landscape, [0, 0], [2, 1], settings)
    np.testing.assert_allclose(fresh.x, result.x, atol=1e-9)


def test_batched_search_plans_distinct_points_per_round():
    g, calls = landscape_and_counter()
    settings = SearchSettings(budget=8, initial=4, explore=2, diverse=2, batch=4, seed=1,
                              **FAST)
    result = search(g, [0, 0, 0], [1, 1, 1], settings)
    second_round = result.x[4:]
    gaps = np.linalg.norm(second_round[:, None] - second_round[None], axis=-1)
    assert gaps[np.triu_indices(4, 1)].min() > 0.05     # the fantasies spread the round out
    assert result.kinds[4:] == ["explore", "explore", "diverse", "diverse"]


def test_random_search_uses_the_same_interface():
    g, _ = landscape_and_counter()
    result = search(g, [0, 0, 0], [1, 1, 1], SearchSettings(strategy="random", budget=6))
    assert result.kinds == ["random"] * 6


@pytest.mark.parametrize("lower, upper, message", [
    ([0, 0], [1], "same length"),
    ([0, 1], [1, 1], "dimension 1 has lower 1.0 and upper 1.0"),
    ([0, float("nan")], [1, 1], "finite"),
    ([], [], "non-empty"),
])
def test_bad_bounds_give_clear_errors(lower, upper, message):
    with pytest.raises(ValueError, match=message):
        search(lambda x: 0.0, lower, upper, SearchSettings(budget=1))


def test_bad_settings_and_bad_black_box_outputs():
    with pytest.raises(ValueError, match="strategy must be one of bds, random"):
        SearchSettings(strategy="grid")
    with pytest.raises(ValueError, match="initial .* must be at least batch"):
        SearchSettings(initial=2, batch=4)
    with pytest.raises(ValueError, match="seed must be non-negative; got -1"):
        SearchSettings(seed=-1)
    with pytest.raises(ValueError, match="lbfgs_starts must be at most 1024 .*; got 1025"):
        SearchSettings(lbfgs_starts=1025)
    with pytest.raises(ValueError, match="workers must be at least 1; got 0"):
        search(lambda x: 0.0, [0], [1], SearchSettings(budget=1), workers=0)
    with pytest.raises(ValueError, match="evaluation 0 at x = .* returned nan"):
        search(lambda x: float("nan"), [0], [1], SearchSettings(budget=2))
    with pytest.raises(ValueError, match="evaluation 1 .* returned 2 numbers; earlier evaluations "
                                         "returned 1"):
        search(lambda x: [1.0] if x[0] < 0.5 else [1.0, 2.0], [0], [1],
               SearchSettings(strategy="random", budget=3, seed=2))


def test_feature_range_errors_and_a_resumed_search_with_one(tmp_path):
    with pytest.raises(ValueError, match="feature_low/feature_high: .*dimension 0 has lower 1.0"):
        SearchSettings(feature_low=(1.0,), feature_high=(0.0,))
    with pytest.raises(ValueError, match="feature_low/feature_high: .*same length"):
        SearchSettings(feature_low=(0.0,), feature_high=())
    with pytest.raises(ValueError, match="give 2 components, but the black box returns features "
                                         "of 1"):
        search(lambda x: x[0], [0], [1], SearchSettings(strategy="random", budget=2,
                                                        feature_low=(0, 0), feature_high=(1, 1)))
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(budget=5, initial=4, explore=1, diverse=0, seed=3,
                              feature_low=(0.0,), feature_high=(1.0,), **FAST)
    first = search(lambda x: x[0] ** 2, [0, 0], [1, 1], settings, log=log)
    calls = []
    again = search(lambda x: calls.append(x) or x[0] ** 2, [0, 0], [1, 1], settings, log=log)
    assert calls == [] and np.array_equal(first.x, again.x)
    # A log written before the feature range existed resumes under the default settings.
    older = tmp_path / "older.jsonl"
    settings = SearchSettings(strategy="random", budget=2)
    search(lambda x: x[0], [0], [1], settings, log=older)
    lines = older.read_text().splitlines()
    header = json.loads(lines[0])
    del header["feature_low"], header["feature_high"]
    older.write_text("\n".join([json.dumps(header), *lines[1:]]) + "\n")
    search(lambda x: calls.append(x) or x[0], [0], [1], settings, log=older)
    assert calls == []


def crash_at_the_start_of_round_two(fault):
    """A black box (x[0]) that fails once, at the fifth call, as `fault` says, and the list of
    the points it evaluated successfully."""
    evaluated, failed = [], []

    def g(x):
        if len(evaluated) == 4 and not failed:
            failed.append(True)
            if fault == "wrong length":
                return [0.0, 0.0]
            raise {"error": RuntimeError, "interrupt": KeyboardInterrupt}[fault]("simulated crash")
        evaluated.append(tuple(x))
        return x[0]
    return g, evaluated


@pytest.mark.parametrize("fault, raised, message", [
    ("error", RuntimeError, "simulated crash"),
    ("interrupt", KeyboardInterrupt, "simulated crash"),
    ("wrong length", ValueError, "returned 2 numbers; earlier evaluations returned 1"),
])
def test_a_failure_inside_a_round_keeps_its_finished_evaluations_and_repeats_none(
        tmp_path, fault, raised, message):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(strategy="random", budget=8, batch=4, seed=4)
    g, evaluated = crash_at_the_start_of_round_two(fault)
    with pytest.raises(raised, match=message):
        search(g, [0, 0], [1, 1], settings, log=log)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert sum(r["event"] == "evaluation" for r in logged) == len(evaluated)
    result = search(g, [0, 0], [1, 1], settings, log=log)
    assert len(evaluated) == len(set(evaluated)) == 8      # none twice, none lost
    assert {tuple(x) for x in result.x} == set(evaluated)


@dataclasses.dataclass(frozen=True)
class FailsOnceAt:
    """x[0] as a black box worker processes can be sent: it raises once, at the point
    `fail_at`, and notes each point it evaluated in folder/evaluated."""
    folder: Path
    fail_at: tuple

    def __call__(self, x):
        failed = self.folder / "failed"
        if np.allclose(x, self.fail_at) and not failed.exists():
            failed.touch()
            raise RuntimeError("simulated crash")
        with open(self.folder / "evaluated", "a") as evaluated:
            evaluated.write(json.dumps(list(x)) + "\n")
        return x[0]

    def evaluated(self):
        return [tuple(json.loads(line)) for line in (self.folder / "evaluated").open()]


def test_a_failure_in_a_worker_process_keeps_the_rounds_finished_evaluations(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(strategy="random", budget=8, batch=4, seed=4)
    second_round = search(lambda x: x[0], [0, 0], [1, 1], settings).x[4:]
    g = FailsOnceAt(tmp_path, tuple(second_round[1]))
    with LocalProcesses(2) as executor:
        with pytest.raises(RuntimeError, match="simulated crash"):
            search(g, [0, 0], [1, 1], settings, log=log, executor=executor)
        logged = [json.loads(line) for line in log.read_text().splitlines()]
        indices = [r["index"] for r in logged if r["event"] == "evaluation"]
        assert len(indices) == len(g.evaluated()) and 5 not in indices
        assert indices == sorted(indices)                     # in pick order, however they ran
        result = search(g, [0, 0], [1, 1], settings, log=log, executor=executor)
    assert len(g.evaluated()) == len(set(g.evaluated())) == 8      # none twice, none lost
    assert {tuple(x) for x in result.x} == set(g.evaluated())


def test_two_worker_processes_write_the_log_one_worker_writes(tmp_path):
    settings = SearchSettings(budget=4, initial=2, explore=1, diverse=1, batch=2, seed=3, **FAST)
    landscape = StrategyLandscape(LandscapeSettings(dim=2, strategies=4, seed=3))
    logs = {}
    for workers in (1, 2):
        log = tmp_path / f"workers{workers}.jsonl"
        search(landscape, [0, 0], [1, 1], settings, log=log, workers=workers)
        logs[workers] = [json.loads(line) for line in log.read_text().splitlines()]
    # The same records in the same order, with the same keys and types; only the time differs.
    assert [[(key, type(value)) for key, value in record.items()] for record in logs[2]] == \
        [[(key, type(value)) for key, value in record.items()] for record in logs[1]]
    for record in logs[1] + logs[2]:
        record.pop("seconds", None)
    assert logs[2] == logs[1]
    assert [r["index"] for r in logs[2] if r["event"] == "evaluation"] == [0, 1, 2, 3]
    assert [r["kind"] for r in logs[2] if r["event"] == "evaluation"] == \
        ["initial", "initial", "explore", "diverse"]


def test_a_resumed_search_with_a_smaller_budget_stops_at_it(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(strategy="random", budget=8, batch=4, seed=4)
    search(lambda x: x[0], [0, 0], [1, 1], settings, log=log)
    # Keep the second round's plan but none of its evaluations, as a crash at its start would.
    lines = [line for line in log.read_text().splitlines()
             if json.loads(line).get("index", 0) < 4]
    log.write_text("\n".join(lines) + "\n")
    calls = []
    result = search(lambda x: calls.append(x) or x[0], [0, 0], [1, 1],
                    dataclasses.replace(settings, budget=6), log=log)
    assert len(calls) == 2 and len(result.x) == 6
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["index"] for r in logged if r["event"] == "evaluation"] == [0, 1, 2, 3, 4, 5]


def test_the_rotation_distance_needs_features_of_three_numbers():
    settings = SearchSettings(budget=2, initial=2, distance="rotation")
    with pytest.raises(ValueError, match="distance 'rotation' compares rotation vectors of 3 "
                                         "numbers, but the black box returns features of 2"):
        search(lambda x: [x[0], x[1]], [0, 0], [1, 1], settings)
    search(lambda x: [x[0], x[1], 0.0], [0, 0], [1, 1], settings)


def test_a_whole_last_line_without_its_newline_gets_one_before_the_next_record(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(strategy="random", budget=2)
    search(lambda x: x[0], [0], [1], settings, log=log)
    log.write_text(log.read_text().rstrip("\n"))
    calls = []
    search(lambda x: calls.append(x) or x[0], [0], [1], dataclasses.replace(settings, budget=3),
           log=log)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(calls) == 1
    assert [r["index"] for r in logged if r["event"] == "evaluation"] == [0, 1, 2]


@pytest.mark.parametrize("cut", ["", '{"ev', '{"event": "start", "lower": [0.0], "upp'])
def test_a_log_cut_off_in_its_header_starts_afresh(tmp_path, cut):
    log = tmp_path / "search.jsonl"
    log.write_text(cut)
    settings = SearchSettings(strategy="random", budget=2)
    if cut:                         # the cut-off text is set aside, and the user told so
        with pytest.warns(LogWarning, match="its last line was cut off"):
            result = search(lambda x: x[0], [0], [1], settings, log=log)
        assert (tmp_path / "search.jsonl.torn").read_text() == cut + "\n"
    else:
        result = search(lambda x: x[0], [0], [1], settings, log=log)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert logged[0]["event"] == "start" and logged[0]["lower"] == [0.0]
    assert [r["x"] for r in logged if r["event"] == "evaluation"] == result.x.tolist()


@pytest.mark.parametrize("text", ["hello", '{"event": "evaluation"}\n', '{"a": 1}\n{"b"'])
def test_a_file_that_is_not_a_search_log_is_refused_and_left_as_it_was(tmp_path, text):
    log = tmp_path / "notes.jsonl"
    log.write_text(text)
    with pytest.raises(SearchError, match="not a search log"):
        search(lambda x: x[0], [0], [1], SearchSettings(strategy="random", budget=2), log=log)
    assert log.read_text() == text


def test_a_log_from_other_settings_is_refused(tmp_path):
    log = tmp_path / "search.jsonl"
    search(lambda x: x[0], [0], [1], SearchSettings(strategy="random", budget=2), log=log)
    with pytest.raises(SearchError, match="different search: its seed is 0, the settings give 1"):
        search(lambda x: x[0], [0], [1], SearchSettings(strategy="random", budget=2, seed=1),
               log=log)


def test_positional_features_keep_the_regions_and_follow_where_a_strategy_lies():
    spread = StrategyLandscape(LandscapeSettings(seed=5))
    positional = StrategyLandscape(LandscapeSettings(seed=5, features="positional"))
    x = np.random.default_rng(0).uniform(size=(4000, 4))
    assert np.array_equal(spread.label(x), positional.label(x))

    def affine_residual(landscape):
        design = np.hstack([landscape.centres, np.ones((len(landscape.centres), 1))])
        fit = np.linalg.lstsq(design, landscape.features, rcond=None)[0]
        return np.abs(design @ fit - landscape.features).max()

    # Positional features are one affine function of the regions' centres, spanning [0, 1];
    # spread features are not (8 strategies, 5 coefficients).
    assert affine_residual(positional) < 1e-12 < 0.05 < affine_residual(spread)
    assert positional.features.min() == 0.0 and positional.features.max() == 1.0


CONFIGS = Path(__file__).parents[1] / "configs"


def write_config(tmp_path, text):
    path = tmp_path / "search.toml"
    path.write_text(text)
    return path


def test_takeoff_search_runs_resumes_and_summarises(tmp_path, capsys):
    config = write_config(tmp_path, """
black_box = "landscape"
[search]
strategy = "bds"
budget = 6
initial = 3
gp_restarts = 2
gp_steps = 50
direct_evaluations = 100
[landscape]
dim = 2
strategies = 4
large = 1
""")
    out_dir = tmp_path / "run"
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir)], capsys)
    assert code == 0, out
    assert "[  6/6] explore" in out and "distinct strategies in 6 evaluations" in out
    assert json.loads((out_dir / "config.json").read_text())["search"]["budget"] == 6
    # More budget on the command line: the search resumes and adds only the new evaluations.
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir),
                            "--set", "search.budget=8"], capsys)
    assert code == 0
    assert "resuming from" in out and "[  7/8]" in out and "[  6/8]" not in out
    # The stored config reads back as the search ran it (the resumed budget included).
    stored = strategy_search.load_search_config(out_dir)
    assert stored.search.budget == 8 and stored.landscape.strategies == 4
    with pytest.raises(ConfigError, match=re.escape(f"{tmp_path / 'config.json'}: missing")):
        strategy_search.load_search_config(tmp_path)


def test_a_search_another_process_holds_is_refused_before_it_writes(tmp_path, capsys):
    out_dir = tmp_path / "run"
    with hold_directory(out_dir, "the search"):
        code, _, _ = run_cli(["search", str(CONFIGS / "search_landscape.toml"), "--out",
                              str(out_dir)], capsys)
    assert re.fullmatch(rf"takeoff search: {re.escape(str(out_dir))}: the search is in use by "
                        rf"process \d+ on .+; wait for it to end, or stop it, before starting "
                        rf"another process on it", code)
    assert sorted(p.name for p in out_dir.iterdir()) == [".lock"]


def test_takeoff_search_with_two_workers_and_a_resume_with_one(tmp_path, capsys):
    config = CONFIGS / "search_landscape.toml"
    out_dir = tmp_path / "run"
    small = ["--set", "search.initial=2", "--set", "search.batch=2",
             "--set", "search.gp_restarts=2", "--set", "search.gp_steps=50",
             "--set", "search.direct_evaluations=100"]
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir), "--workers", "2",
                            "--set", "search.budget=4", *small], capsys)
    assert code == 0, out
    assert "[  4/4] explore" in out and "distinct strategies in 4 evaluations" in out
    assert json.loads((out_dir / "config.json").read_text())["executor"]["workers"] == 2
    # Where the evaluations run is not part of the search: a resume may run them elsewhere.
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir),
                            "--set", "search.budget=5", *small], capsys)
    assert code == 0, out
    assert "resuming from" in out and "[  5/5]" in out and "[  4/5]" not in out
    logged = [json.loads(line) for line in (out_dir / "evaluations.jsonl").open()]
    assert [r["index"] for r in logged if r["event"] == "evaluation"] == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("text, message", [
    ("[search]\nbudgett = 3\n", "unknown key 'search.budgett'"),
    ("[search]\nbudget = 'many'\n", "key 'search.budget' must be an int; got 'many'"),
    ("[search]\nbudget = 0\n", r"\[search\]: budget must be at least 1"),
    ("black_box = 'oracle'\n", "black_box must be one of landscape"),
    ("[box]\nlower = [0, 0]\nupper = [1, 1]\n", r"\[box\] has 2 dimensions but landscape.dim has 4"),
    ("[box]\nlower = [0, 0, 0, 1]\nupper = [1, 1, 1, 1]\n", "dimension 3 has lower 1.0"),
    ("[search\n", "not valid TOML"),
    ("[landscape]\nfeatures = 'random'\n", "features must be one of spread, positional"),
    ("[search]\nfeature_low = [0]\nfeature_high = [-1]\n", r"\[search\]: feature_low/"),
    ("[search]\nseed = -1\n", r"\[search\]: seed must be non-negative; got -1"),
    ("[search]\nlbfgs_starts = 5000\n", r"\[search\]: lbfgs_starts must be at most 1024"),
    ("[landscape]\nseed = -2\n", r"\[landscape\]: seed must be non-negative; got -2"),
    ("[search]\nbudget = 2\ninitial = 2\ndistance = 'rotation'\n",
     r"\[search\] does not fit landscape.feature_dim = 1: distance 'rotation' compares rotation "
     "vectors of 3 numbers"),
    ("[search]\nbudget = 2\ninitial = 2\nfeature_low = [0, 0]\nfeature_high = [1, 1]\n",
     r"landscape.feature_dim = 1: feature_low/feature_high give 2 components"),
    ("[executor]\nbackend = 'dask'\n", r"\[executor\]: backend must be one of local, ray"),
    ("[executor]\nworkers = 0\n", r"\[executor\]: workers must be at least 1; got 0"),
    ("[executor]\naddress = 'auto'\n", r"\[executor\]: address \('auto'\) names a Ray cluster"),
    ("[executor]\nthreads = 2\n", "unknown key 'executor.threads'"),
])
def test_takeoff_search_config_errors_name_the_key(tmp_path, capsys, text, message):
    config = write_config(tmp_path, text)
    with pytest.raises(SystemExit, match=message) as error:
        main(["search", str(config), "--out", str(tmp_path / "run")])
    assert str(config) in str(error.value)


def test_a_jump_search_s_box_replaces_the_take_off_bounds_and_must_have_their_dimension():
    """The narrower box of docs/discovery/README.md ("A search in the narrower box"), given on
    the command line as there; without it the search box is the task's take-off bounds."""
    from agents import config as config_io
    from agents.commands.strategy_search import SearchConfig
    from agents.tasks import takeoff_state
    config_path = CONFIGS / "highjump_bds.toml"
    default = config_io.load(config_path, SearchConfig, [])
    for bound, expected in zip(default.bounds(), takeoff_state.HIGHJUMP_BOUNDS):
        np.testing.assert_array_equal(bound, expected)
    narrower = config_io.load(config_path, SearchConfig, [
        "box.lower=[-0.5235987755982988, -3.0, -1.0, -2.4]",
        "box.upper=[2.0943951023931953, 1.0, 1.0, -0.5]"])
    lower, upper = narrower.bounds()
    np.testing.assert_array_equal(lower, [-np.pi / 6, -3.0, -1.0, -2.4])
    np.testing.assert_array_equal(upper, [2 * np.pi / 3, 1.0, 1.0, -0.5])
    with pytest.raises(config_io.ConfigError,
                       match=r"\[box\] has 3 dimensions but the highjump take-off state x has 4"):
        config_io.load(config_path, SearchConfig, ["box.lower=[0, 0, 0]", "box.upper=[1, 1, 1]"])


RANDOM_SEARCH = """
black_box = "landscape"
[search]
strategy = "random"
budget = 4
[landscape]
dim = 2
strategies = 6
large = 1
"""


@pytest.mark.parametrize("overrides, key, stored, given", [
    (["landscape.seed=1"], "landscape.seed", "0", "1"),
    (["search.seed=3", "search.budget=6"], "search.seed", "0", "3"),
    (["box.lower=[0, 0]", "box.upper=[1, 2]"], "box.lower", r"\[\]", r"\[0.0, 0.0\]"),
])
def test_a_resumed_takeoff_search_refuses_another_config_and_keeps_its_own(
        tmp_path, capsys, overrides, key, stored, given):
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    assert run_cli(["search", str(config), "--out", str(out_dir)], capsys)[0] == 0
    before = (out_dir / "config.json").read_text()
    log_before = (out_dir / "evaluations.jsonl").read_text()
    with pytest.raises(SystemExit, match=f"{key} = {stored}, but the config gives {given}; a "
                                         "resumed search may change only search.budget"):
        main(["search", str(config), "--out", str(out_dir),
              *(arg for override in overrides for arg in ("--set", override))])
    assert (out_dir / "config.json").read_text() == before
    assert (out_dir / "evaluations.jsonl").read_text() == log_before


def test_a_resumed_takeoff_search_checks_its_config_json(tmp_path, capsys):
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    assert run_cli(["search", str(config), "--out", str(out_dir)], capsys)[0] == 0
    # A config.json from before a setting existed: that setting counts as its default.
    stored = json.loads((out_dir / "config.json").read_text())
    del stored["landscape"]["features"]
    (out_dir / "config.json").write_text(json.dumps(stored))
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir),
                            "--set", "search.budget=5"], capsys)
    assert code == 0 and "[  5/5]" in out
    (out_dir / "config.json").unlink()
    with pytest.raises(SystemExit, match="holds a search's log or evaluations but no config.json"):
        main(["search", str(config), "--out", str(out_dir), "--set", "search.budget=6"])


def test_a_search_whose_first_evaluation_was_killed_unlogged_checks_its_config(tmp_path, capsys):
    """A first evaluation killed before its log line leaves no log (the search removes an
    empty one) but its training's directory: a rerun under another config must not resume
    that training as if it were this config's."""
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    assert run_cli(["search", str(config), "--out", str(out_dir)], capsys)[0] == 0
    (out_dir / "evaluations.jsonl").unlink()
    assert not strategy_search.started(out_dir)
    (out_dir / "evaluations" / "000" / "train").mkdir(parents=True)
    assert strategy_search.started(out_dir)
    with pytest.raises(SystemExit, match="search.seed = 0, but the config gives 3"):
        main(["search", str(config), "--out", str(out_dir), "--set", "search.seed=3"])
    code, out, _ = run_cli(["search", str(config), "--out", str(out_dir)], capsys)
    assert code == 0


def test_takeoff_search_reports_a_damaged_log_and_lets_other_errors_through(
        tmp_path, capsys, monkeypatch):
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    assert run_cli(["search", str(config), "--out", str(out_dir)], capsys)[0] == 0
    log = out_dir / "evaluations.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    log.write_text("".join(lines[:2] + ["{not json\n"] + lines[3:]))
    with pytest.raises(SystemExit, match=f"{log}, line 3: not a log record"):
        main(["search", str(config), "--out", str(out_dir)])
    # Anything else is a bug: it keeps its traceback instead of becoming a one-line message.
    from agents.commands import strategy_search

    def broken(*args, **kwargs):
        raise ValueError("a bug")
    monkeypatch.setattr(strategy_search, "run", broken)
    with pytest.raises(ValueError, match="a bug"):
        main(["search", str(config), "--out", str(out_dir)])


def test_progress_after_a_resume_counts_the_strategies_already_found(tmp_path, capsys):
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    code, first, _ = run_cli(["search", str(config), "--out", str(out_dir),
                              "--set", "search.budget=6"], capsys)
    assert code == 0
    code, resumed, _ = run_cli(["search", str(config), "--out", str(out_dir),
                                "--set", "search.budget=12"], capsys)
    assert code == 0

    def progress(out):
        return re.findall(r"strategy (\d+)( \(new\))?  distinct (\d+)", out)
    lines = progress(first) + progress(resumed)
    assert len(lines) == 12
    # Across the two runs, each strategy is new exactly once and the count only grows.
    seen = set()
    for strategy, new, distinct in lines:
        assert bool(new) == (strategy not in seen)
        seen.add(strategy)
        assert int(distinct) == len(seen)
    # The first run found several strategies, so a resumed count that forgot them would differ.
    assert len({strategy for strategy, _, _ in progress(first)}) > 1


def test_a_logged_evaluation_that_is_not_finite_numbers_in_the_box_is_refused(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(strategy="random", budget=3)
    search(lambda x: [x[0], 1.0], [0], [1], settings, log=log)
    text = log.read_text()
    lines = text.splitlines(keepends=True)
    record = json.loads(lines[-1])
    for field, value, message in [("feature", "[NaN, 1.0]", "NaN is not a finite number"),
                                  ("feature", "[0.5]", r"feature \[0\.5\] is not 2 finite"),
                                  ("x", "[7.0]", r"x \[7\.0\] lies outside the search's box"),
                                  ("x", "[]", r"x \[\] is not 1 finite numbers"),
                                  ("index", "-1", "index -1 is not a whole number")]:
        bad = json.dumps({**record, field: "@"}).replace('"@"', value)
        log.write_text("".join(lines[:-1]) + bad + "\n")
        with pytest.raises(SearchError, match=message):
            search(lambda x: [x[0], 1.0], [0], [1], dataclasses.replace(settings, budget=4),
                   log=log)


def test_a_search_that_fails_before_its_first_evaluation_leaves_no_log(tmp_path):
    log = tmp_path / "my_search.jsonl"

    def broken(x):
        return undefined_feature(x)     # noqa: F821 — the README's NameError
    with pytest.raises(NameError):
        search(broken, [0, 0], [1, 5], SearchSettings(budget=4), log=log)
    assert not log.exists()
    # A log that holds evaluations stays, whatever fails next.
    search(lambda x: x[0], [0], [1], SearchSettings(strategy="random", budget=1), log=log)
    with pytest.raises(NameError):
        search(broken, [0], [1], SearchSettings(strategy="random", budget=2), log=log)
    assert log.exists()


def test_takeoff_search_refuses_a_directory_a_nan_setting_and_zero_workers(tmp_path, capsys):
    config = write_config(tmp_path, RANDOM_SEARCH)
    code, _, err = run_cli(["search", str(tmp_path)], capsys)
    assert code != 0 and "is a directory, not a config file" in str(code) + err
    with pytest.raises(SystemExit, match=r"'landscape\.noise' must be a finite number; got nan"):
        main(["search", str(config), "--set", "landscape.noise=nan"])
    code, _, err = run_cli(["search", str(config), "--workers", "0"], capsys)
    assert code == 2 and "--workers: must be a whole number ≥ 1" in err


def test_takeoff_search_names_a_damaged_evaluation_before_using_it(tmp_path, capsys):
    config = write_config(tmp_path, RANDOM_SEARCH)
    out_dir = tmp_path / "run"
    assert run_cli(["search", str(config), "--out", str(out_dir)], capsys)[0] == 0
    log = out_dir / "evaluations.jsonl"
    log.write_text(log.read_text().replace('"x": [', '"x": ["left", ', 1))
    with pytest.raises(SystemExit, match=r"evaluations\.jsonl, record \d+: the evaluation's x "):
        main(["search", str(config), "--out", str(out_dir), "--set", "search.budget=6"])


def _fails_left_of(edge):
    """A smooth 1-D feature that is a Failure wherever x[0] < edge."""
    def g(x):
        if x[0] < edge:
            return Failure(f"x[0] = {x[0]:.3f} is left of {edge}")
        return np.array([np.sin(4 * x[0]) + x[1]])
    return g


def test_failures_are_logged_without_a_feature_and_resume_as_they_were(tmp_path):
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(budget=8, initial=4, explore=1, diverse=1, seed=1, **FAST)
    g = _fails_left_of(0.5)
    result = search(g, [0, 0], [1, 1], settings, log=log)
    records = logged_evaluations(log)
    failed = [r for r in records if r["feature"] is None]
    assert failed and all(r["failure"].startswith("x[0] = ") and r["x"][0] < 0.5 for r in failed)
    assert all(r["failure"] is None and r["x"][0] >= 0.5 for r in records if r["feature"])
    assert [f is not None for f in result.failures] == [r["feature"] is None for r in records]
    assert np.isnan(result.features[[f is not None for f in result.failures]]).all()
    resumed = search(g, [0, 0], [1, 1], dataclasses.replace(settings, budget=10), log=log)
    np.testing.assert_array_equal(resumed.x[:8], result.x)
    assert resumed.failures[:8] == result.failures


def test_with_no_success_yet_the_model_picks_are_random_points():
    settings = SearchSettings(budget=6, initial=2, explore=1, diverse=1, seed=0, **FAST)
    result = search(_fails_left_of(2.0), [0, 0], [1, 1], settings)       # everything fails
    assert result.kinds == ["initial", "initial"] + ["random"] * 4
    assert all(result.failures)


def test_the_success_model_keeps_picks_out_of_the_failing_region():
    """Half the box fails (x[0] < 0.5). Weighting the picks by the chance of success
    (`feasibility`) must spend clearly fewer of the model-based picks there than Algorithm 1 as
    written, over the same eight seeds (measured: 18 of 64 against 37; the success model fitted
    without its hyperparameter priors, 17); with no failure yet the two plan the same points."""
    failing = _fails_left_of(0.5)
    def failed_picks(feasible):
        count = 0
        for seed in range(8):
            settings = SearchSettings(budget=12, initial=4, explore=2, diverse=2, seed=seed,
                                      feasibility=feasible, **FAST)
            result = search(failing, [0, 0], [1, 1], settings)
            count += sum(f is not None for f in result.failures[4:])
        return count
    plain, feasible = failed_picks(False), failed_picks(True)
    assert feasible < 0.6 * plain, (feasible, plain)
    succeeding = lambda x: np.array([np.sin(4 * x[0]) + x[1]])
    runs = [search(succeeding, [0, 0], [1, 1],
                   SearchSettings(budget=6, initial=3, explore=1, diverse=1, seed=2,
                                  feasibility=feasible, **FAST)).x for feasible in (False, True)]
    np.testing.assert_array_equal(runs[0], runs[1])


def test_the_plans_log_each_model_pick_s_chance_of_success(tmp_path):
    """Each logged plan gives its model-based picks the chance of success under the model fitted
    again here from the evaluations logged before them; random and initial picks, and picks
    before any failure (no model), have none. A chance outside [0, 1] is named on resume."""
    log = tmp_path / "search.jsonl"
    settings = SearchSettings(budget=9, initial=4, explore=1, diverse=1, seed=1, feasibility=True,
                              **FAST)
    g = _fails_left_of(0.5)
    search(g, [0, 0], [1, 1], settings, log=log)
    records = [json.loads(line) for line in log.read_text().splitlines()]
    plans = [r for r in records if r["event"] == "plan"]
    evaluations = [r for r in records if r["event"] == "evaluation"]
    checked = 0
    for plan in plans:
        first, (chance,), (kind,) = (plan["first_index"], plan["success_probability"],
                                     plan["kinds"])
        before = evaluations[:first]
        failed = [r["x"] for r in before if r["feature"] is None]
        if kind in ("initial", "random") or not failed:
            assert chance is None, plan
            continue
        model = success_model(settings, first,
                              np.array([r["x"] for r in before if r["feature"] is not None]),
                              np.array(failed))
        expected = feasibility.success_probability(model, jnp.asarray(plan["points"]))[0]
        assert chance == pytest.approx(float(expected), rel=1e-9), plan
        checked += 1
    assert checked >= 3
    log.write_text(log.read_text().replace('"success_probability": [0.',
                                           '"success_probability": [7.', 1))
    with pytest.raises(SearchError, match=r"record \d+: the plan's success_probability \[7\."):
        search(g, [0, 0], [1, 1], settings, log=log)
