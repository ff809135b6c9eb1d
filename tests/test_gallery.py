"""The gallery of a strategy search (`takeoff gallery`): one HTML page naming every evaluation,
with its pictures, outcome and strategy.

The search directory is made by the real search loop (`bds.search.search`, random picks, its
real log) over a stand-in black box that writes each evaluation's files in the format of
`agents.discovery.jump_black_box` without training: a failure, three successes of which two are
one strategy, and an evaluation still training when the search stopped (no result.json). Its
training config asks for P-VAE actions from a P-VAE run that does not exist: the gallery must
draw without one."""

import dataclasses
import html
import json
import math
import re
import shutil

import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="the render extra is part of the test extra")

from agents.commands import cli, stage2_search, strategy_search, train_commands  # noqa: E402
from agents.discovery import gallery, jump_black_box  # noqa: E402
from agents.tasks import takeoff_state  # noqa: E402
from bds import strategies  # noqa: E402
from bds.search import Failure, SearchSettings, search  # noqa: E402
from conftest import tiny_highjump_training  # noqa: E402
from jaxsim import runlog  # noqa: E402
from jaxsim.atomic import write_text_atomic  # noqa: E402

# What each evaluation comes out as: a failure (its reason has HTML in it, which the page must
# escape), up angles (rad) with the highest bar cleared, and one still training.
REASON = "the policy cleared 0 of 2 episodes at 0.50 m <b>& fell</b>"
OUTCOMES = [REASON, (0.20, 1.00), (2.60, 0.80), (0.35, 1.10), "training"]
IN_PROGRESS_BAR = 0.73
STAGE2_ROTVECS = [[0.0, 0.0, 0.25], [2.0, 0.0, 0.0]]     # Stage 1's are [0, 0, up angle]
OTHER_STAGE2 = "stage2_sigma"                               # `takeoff stage2 --out` elsewhere


class StillTraining(Exception):
    """What the stand-in black box raises for the evaluation that is still training."""


@dataclasses.dataclass
class StandIn:
    """g(x) with `evaluate(index, x)`, as the jump black box has, writing its files."""
    search_dir: object
    train_toml: str
    data_dir: object

    def evaluate(self, index, x):
        directory = jump_black_box.evaluation_dir(self.search_dir, index)
        train = directory / jump_black_box.TRAIN
        takeoff = [float(v) for v in x]
        config = train_commands.load_config(self.train_toml, [f"highjump.takeoff={takeoff}"])
        write_text_atomic(train / "config.json", json.dumps(config.sections()))
        for iteration in (1, 2):
            runlog.append(train / "metrics.jsonl", {
                "iteration": iteration, "samples": 16 * iteration, "seconds": 30.0 * iteration,
                "curriculum/difficulty": 0.5 + (IN_PROGRESS_BAR - 0.5) * (iteration - 1)})
        outcome = OUTCOMES[index]
        if outcome == "training":
            raise StillTraining
        env = gallery.drawing_env(train, self.data_dir)
        np.savez(directory / jump_black_box.EPISODE, poses=_flight(env, x), control_dt=1 / 30,
                 difficulty=0.5, takeoff=np.asarray(x))
        result = {"index": index, "x": list(x), "task": "highjump", "reached": 0.5,
                  "samples": 32, "minutes": 1.0, "iterations": 2, "episodes": 2,
                  "evaluated_at": 0.5}
        if isinstance(outcome, str):
            result.update(outcome="failure", reason=outcome, feature=None,
                          highest_cleared=None, cleared_share=0.0)
            write_text_atomic(directory / jump_black_box.RESULT, json.dumps(result))
            return Failure(outcome)
        up, height = outcome
        result.update(outcome="success", reason=None, highest_cleared=height,
                      cleared_share=1.0, feature={"up_angle": up,
                                                  "cross_rotvec": [0.0, 0.0, up],
                                                  "clearance": 0.1, "peak_com": 1.2})
        write_text_atomic(directory / jump_black_box.RESULT, json.dumps(result))
        return np.array([up])


def _flight(env, x):
    """Poses (4, nq): the take-off pose raised and carried towards the bar."""
    normal = np.asarray(env.geometry({"takeoff": jnp.asarray(x, env.q0.dtype),
                                      "difficulty": jnp.asarray(0.5, env.q0.dtype)})[0])
    poses = np.repeat(np.asarray(env.q0, float)[None], 4, axis=0)
    for k in range(4):
        poses[k, :3] += 0.4 * k * normal + [0.0, 0.3 * k * (3 - k), 0.0]
    return poses


@pytest.fixture(scope="module")
def search_dir(tmp_path_factory, data_dir):
    root = tmp_path_factory.mktemp("gallery")
    train_toml = root / "train.toml"
    train_toml.write_text(tiny_highjump_training(
        actions='actions = "pvae"\npvae = "runs/no_such_pvae"'))
    out = root / "search"
    config = strategy_search.SearchConfig(
        black_box="jump",
        search=SearchSettings(strategy="random", budget=len(OUTCOMES), feature_low=(0.0,),
                              feature_high=(math.pi,)),
        jump=jump_black_box.JumpBlackBoxSettings(train=str(train_toml), samples=32,
                                                 episodes=2))
    write_text_atomic(out / "config.json", json.dumps(dataclasses.asdict(config)))
    lower, upper = takeoff_state.BOUNDS["highjump"]
    with pytest.raises(StillTraining):
        search(StandIn(out, str(train_toml), data_dir), lower, upper, config.search,
               log=out / "evaluations.jsonl")
    # as a search with the success model would have logged it for evaluation 002's pick
    log = out / "evaluations.jsonl"
    log.write_text(re.sub(r'("first_index": 2, .*"success_probability": )\[null\]',
                          r"\1[0.42]", log.read_text()))
    # Stage 2: a run that repeats Stage 1's evaluation 001 and a novel one, in their own folder
    first = jump_black_box.evaluation_dir(out, 1)
    for index, rotvec in enumerate(STAGE2_ROTVECS):
        stage2 = out / gallery.STAGE2 / f"{index:03d}"
        (stage2 / jump_black_box.TRAIN).mkdir(parents=True)
        for name in (jump_black_box.EPISODE, f"{jump_black_box.TRAIN}/config.json"):
            (stage2 / name).write_bytes((first / name).read_bytes())
        result = json.loads((first / jump_black_box.RESULT).read_text())
        result.update(index=index, kind="novelty")
        result["feature"]["cross_rotvec"] = rotvec
        (stage2 / jump_black_box.RESULT).write_text(json.dumps(result))
        known = [{"policy": f"evaluation {i}", "cross_rotvec": [0.0, 0.0, OUTCOMES[i][0]]}
                 for i in (1, 2, 3)]                          # Stage 1's, as `takeoff stage2`
        known += [{"policy": f"stage2 {i:03d}", "cross_rotvec": STAGE2_ROTVECS[i]}
                  for i in range(index)]                      # and the rounds before
        (stage2 / stage2_search.KNOWN).write_text(json.dumps(known))
    (out / gallery.STAGE2 / stage2_search.PLAN).write_text("{}")
    # another Stage-2 directory (`takeoff stage2 --out`) whose one round is stage2/001 again
    shutil.copytree(out / gallery.STAGE2 / "001", out / OTHER_STAGE2 / "000")
    (out / OTHER_STAGE2 / stage2_search.PLAN).write_text("{}")
    return out


@pytest.fixture(scope="module")
def written(search_dir, data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("gallery_out")
    path = gallery.write_gallery(search_dir, out, data_dir, echo=lambda *_: None,
                                 stage2_dirs=[search_dir / OTHER_STAGE2])
    return out, path.read_text()


def _card(page, anchor):
    match = re.search(rf"<section class='card [^']*' id='{anchor}'>(.*?)</section>", page, re.S)
    assert match, f"no card {anchor}"
    return match.group(1)


def test_the_page_names_every_evaluation(search_dir, written):
    _, page = written
    for index in range(len(OUTCOMES)):
        assert f"Evaluation {index:03d}" in page
        _card(page, f"eval-{index:03d}")
    for index in range(len(STAGE2_ROTVECS)):
        assert f"Stage 2 evaluation {index:03d}" in page
        _card(page, f"stage2-eval-{index:03d}")


def test_outcomes_failure_reason_and_in_progress(written):
    _, page = written
    failure = _card(page, "eval-000")
    assert "failure" in failure and html.escape(REASON) in failure
    assert "<b>& fell" not in page                     # everything from files is escaped
    training = _card(page, "eval-004")
    assert "in progress" in training and f"{IN_PROGRESS_BAR:.2f} m" in training
    assert "<img" not in training
    success = _card(page, "eval-002")
    assert "success" in success and "0.80 m" in success
    assert "P[success] = 0.42" in success and "P[success]" not in failure
    assert f"{math.degrees(2.60):.1f}°" in success and "2.600 rad" in success
    for label in ("α", "ω<sub>x</sub>", "ω<sub>z</sub>", "v<sub>z</sub>"):
        assert label in success


def test_linked_pictures_exist_and_gifs_are_small(written):
    out, page = written
    links = re.findall(r"(?:src|href)='([^'#]+)'", page)
    assert links
    for link in links:
        assert not link.startswith("/") and (out / link).is_file(), link
    for index in range(4):                      # every evaluation with an episode
        card = _card(page, f"eval-{index:03d}")
        assert f"gallery/{index:03d}_peak.png" in card and f"gallery/{index:03d}.gif" in card
        assert (out / f"gallery/{index:03d}.gif").stat().st_size < 300_000
    assert "gallery/contact_sheet.png" in page


def test_strategies_are_grouped_as_bds_strategies_groups(search_dir, written):
    _, page = written
    features = [None if isinstance(o, str) else [o[0]] for o in OUTCOMES]
    labels = strategies.group(features, strategies.UP_ANGLE_THRESHOLD)
    assert list(labels) == [-1, 0, 1, 0, -1]
    for index, label in enumerate(labels):
        card = _card(page, f"eval-{index:03d}")
        assert (f"strategy {label}</span>" in card) == (label >= 0)
    assert "href='#eval-001'>001</a>)" in _card(page, "eval-003")   # the same as 001
    assert "2 distinct strategies" in page
    assert "5 evaluations (3 successes, 1 failure, 1 in progress)" in page
    summary = re.search(r"<table class='summary'>(.*?)</table>", page, re.S).group(1)
    assert summary.count("<tr>") == 3                     # a header and two strategies
    assert "1.10 m" in summary                            # strategy 0's best is 003's bar


def test_an_evaluation_measured_again_says_so_and_keeps_the_logged_grouping(
        search_dir, written, data_dir, tmp_path):
    """Evaluation 003 retrained and measured again (a lost policy): its card says its
    result.json is not what the search logged, and it is still grouped by the log's value."""
    import shutil
    copy = tmp_path / "search"
    shutil.copytree(search_dir, copy)
    path = jump_black_box.evaluation_dir(copy, 3) / jump_black_box.RESULT
    result = json.loads(path.read_text())
    result["feature"]["up_angle"] = 0.9
    path.write_text(json.dumps(result))
    page = gallery.write_gallery(copy, tmp_path / "out", data_dir,
                                 echo=lambda *_: None).read_text()
    card = _card(page, "eval-003")
    assert (f"up angle {math.degrees(0.9):.1f}°) is not the measurement the search logged "
            f"({math.degrees(0.35):.1f}°") in card
    assert "href='#eval-001'>001</a>)" in card                 # still 001's strategy
    assert "measured again" not in _card(written[1], "eval-003")


def test_pictures_are_not_redrawn_and_the_search_is_only_read(search_dir, written, data_dir):
    out, _ = written
    before = {p: p.stat().st_mtime_ns for p in (out / "gallery").glob("*.gif")}
    listing = sorted(p.relative_to(search_dir) for p in search_dir.rglob("*"))
    gallery.write_gallery(search_dir, out, data_dir, echo=lambda *_: None)
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert sorted(p.relative_to(search_dir) for p in search_dir.rglob("*")) == listing


def test_an_evaluation_whose_training_run_is_gone_is_drawn_with_another_ones_config(
        search_dir, data_dir, tmp_path):
    carried = tmp_path / "carried"                 # results and episodes, no training run
    shutil.copytree(search_dir, carried)
    shutil.rmtree(jump_black_box.evaluation_dir(carried, 1) / jump_black_box.TRAIN)
    out = tmp_path / "out"
    page = gallery.write_gallery(carried, out, data_dir, echo=lambda *_: None).read_text()
    card = _card(page, "eval-001")
    assert "no pictures" not in card
    for name in ("001_peak.png", "001.gif"):
        assert f"gallery/{name}" in card and (out / "gallery" / name).stat().st_size > 0


def test_a_search_without_any_training_run_is_drawn_with_its_own_training_config(
        search_dir, data_dir, tmp_path):
    """As docs/discovery keeps its searches: results and episodes, no training runs at all."""
    carried = tmp_path / "carried"
    shutil.copytree(search_dir, carried)
    for run in list(carried.rglob(jump_black_box.TRAIN)):
        shutil.rmtree(run)
    out = tmp_path / "out"
    page = gallery.write_gallery(carried, out, data_dir, echo=lambda *_: None).read_text()
    assert "no pictures" not in _card(page, "eval-001")
    assert (out / "gallery" / "001_peak.png").stat().st_size > 0
    assert (out / "gallery" / "stage2_000.gif").stat().st_size > 0
    # Its training config gone too: a note on each card, and the page still written.
    config = json.loads((carried / "config.json").read_text())
    config["jump"]["train"] = str(tmp_path / "no_such.toml")
    (carried / "config.json").write_text(json.dumps(config))
    said = []
    page = gallery.write_gallery(carried, tmp_path / "bare", data_dir, redraw=True,
                                 echo=said.append).read_text()
    assert "no pictures" in _card(page, "eval-001")
    assert any("no training config to draw" in line and "no_such.toml" in line for line in said)


def test_a_directory_that_is_not_a_search_is_named(tmp_path, capsys):
    with pytest.raises(gallery.GalleryError, match="config.json and no evaluations.jsonl"):
        gallery.write_gallery(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"run": {"task": "highjump"}}))
    (tmp_path / "evaluations.jsonl").write_text("")
    with pytest.raises(SystemExit, match="takeoff gallery: .*not a search config"):
        cli.main(["gallery", str(tmp_path)])


def test_stage2_runs_are_grouped_with_the_stage1_policies_they_repeat(written):
    _, page = written
    stage1 = [[0.0, 0.0, o[0]] for o in OUTCOMES if not isinstance(o, str)]     # 001, 002, 003
    labels = strategies.group(stage1 + STAGE2_ROTVECS, strategies.ROTATION_THRESHOLD,
                              "rotation")
    assert list(labels) == [0, 1, 0, 0, 2]
    repeats = _card(page, "stage2-eval-000")
    assert ("its group holds Stage-1 evaluation <a href='#eval-001'>001</a>, "
            "<a href='#eval-003'>003") in repeats
    # Eq. 3.12 against every policy it was trained against: the nearest of 000 is evaluation
    # 1, 0.05 rad off; of 001 (2 rad about x) evaluation 1 (0.2 rad about z), at
    # arccos((cos 2 + cos 0.2 + cos 2 cos 0.2 − 1) / 2) = 2.01 rad.
    assert "eq. 3.12: repeats (evaluation 1, the nearest of the policies it was trained " \
           "against, is 0.05 rad away; π/2 = 1.57)" in repeats
    novel = _card(page, "stage2-eval-001")
    assert "eq. 3.12: novel (evaluation 1, the nearest of the policies it was trained " \
           "against, is 2.01 rad away" in novel and "its group holds no Stage-1" in novel
    summary = re.findall(r"<table class='summary'>(.*?)</table>", page, re.S)[1]
    assert "repeats evaluation 1 (0.05 rad)" in summary and "novel (2.01 rad)" in summary


def test_another_stage2_directory_has_its_own_section_named_by_it(search_dir, written):
    out, page = written
    assert f"Stage 2: novel policies ({OTHER_STAGE2})" in page
    card = _card(page, f"{OTHER_STAGE2}-eval-000")
    assert f"Stage 2 evaluation 000 ({OTHER_STAGE2})" in card
    assert "eq. 3.12: novel" in card                            # as stage2/001, its copy
    assert f"gallery/{OTHER_STAGE2}_000.gif" in card
    assert (out / "gallery" / f"{OTHER_STAGE2}_000_peak.png").stat().st_size > 0
    assert "<h2>Stage 2: novel policies</h2>" in page               # SEARCH/stage2 still shown


def test_a_stage2_directory_that_is_not_one_or_shares_a_name_is_named(search_dir, tmp_path):
    with pytest.raises(SystemExit, match=f"takeoff gallery: {tmp_path} is not a Stage-2 "
                                         "directory: it has no plan.json"):
        cli.main(["gallery", str(search_dir), "--stage2", str(tmp_path)])
    # Two directories the gallery would name alike: by their names, one of them SEARCH/stage2
    # (always shown), or once the characters a link cannot hold are replaced.
    default = search_dir / gallery.STAGE2
    for first, second in ((search_dir / OTHER_STAGE2, tmp_path / OTHER_STAGE2),
                          (default, tmp_path / gallery.STAGE2),
                          (tmp_path / "stage2-sigma", tmp_path / "stage2 sigma")):
        for directory in (first, second):
            if not directory.exists():
                shutil.copytree(search_dir / OTHER_STAGE2, directory)
        with pytest.raises(gallery.GalleryError,
                           match=re.escape(f"{first} and {second} would both be named")):
            gallery.read_search(search_dir, [second] if first == default else [first, second])
    # SEARCH/stage2 named again is shown once.
    _, sections = gallery.read_search(search_dir, [search_dir / gallery.STAGE2])
    assert [s.title for s in sections] == ["Stage 1: take-off states", "Stage 2: novel policies"]
