"""The gallery of a strategy search: `takeoff gallery SEARCH_DIR` (thesis §3.7.1: Figs. 3.2–3.4 show
the strategies found, Tables 3.3–3.4 their take-off states).

One self-contained HTML page, `gallery.html`, beside a folder `gallery/` of the pictures it links
(relative links, so the page and its folder can be moved or committed together):

- a summary table like Table 3.3: one row per distinct strategy with its first evaluation's
  take-off state x and feature, the highest bar any of its evaluations cleared, and its
  evaluations;
- a contact sheet (`gallery/contact_sheet.png`): every evaluation's peak pose on one image;
- per evaluation: its index, kind (initial / explore / diverse / random, with the chance of
  success the search's success model gave a model-based pick, when its log has one), x with its
  named components (`agents.tasks.takeoff_state`), the feature (degrees and radians), the
  highest bar cleared, success or failure (with the reason), the peak pose along the bar and
  seen from above and below it (Fig. 3.4; `gallery/NNN_peak.png`), an animated GIF of the
  evaluated episode (`gallery/NNN.gif`), its strategy, and its result.json;
- an evaluation without result.json yet is "in progress", with the bar its training has
  reached (train/metrics.jsonl); a planned one without a directory yet is "waiting";
- Stage 2's evaluations (`SEARCH/stage2/NNN/`, the same files), when there are any, in a section
  of their own, read by the same code; and a section for each other `takeoff stage2` output
  directory named with `--stage2 DIR` (e.g. the rounds of `takeoff stage2 --sigma S --out
  SEARCH/stage2_sigma`), its evaluations named, linked and drawn with the directory's name.

Which evaluations are the same strategy is `bds.strategies.group`, the rule `takeoff search`'s
summary counts by: Stage 1 by the search's feature (the up angle at the bar crossing) with the
search config's `same_strategy` threshold (default `bds.strategies.UP_ANGLE_THRESHOLD`, π/6,
justified there) and its feature distance, over the evaluations within its budget; Stage 2 by
the 3-D root orientation at the crossing with the rotation distance and
`bds.strategies.ROTATION_THRESHOLD` (π/2, the thesis's d_threshold), the Stage-1 policies first,
so that a Stage-2 run that repeats a Stage-1 strategy says which. The page says which threshold
it used and why.

Pictures are drawn from `episode.npz` (the poses of one evaluated episode) with the model and
world of the evaluation's training config (of another evaluation of the search when its own
training run is gone) — built with plain PD actions, since neither depends
on the action space and a P-VAE's decoder is not needed to draw — and redrawn only when the
episode is newer than the picture (`--redraw` draws them all again). Drawing needs the reference
data (`--data-dir`); without it the command fails saying so. GIFs keep at most `GIF_FRAMES`
frames of 230 × 230 pixels, well under 300 kB each, so that a gallery can be committed.
Everything read from files is HTML-escaped. The search directory is only read: with `--out`,
nothing is written in it, so the gallery of a running search can be drawn at any time.
"""

import dataclasses
import functools
import html
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agents.discovery import jump_black_box, stage2
from bds import strategies
from bds.search import SEARCH_LOG, SearchError, logged_evaluations
from jaxsim import runlog
from jaxsim.atomic import check_writable, write_text_atomic

PAGE = "gallery.html"
IMAGES = "gallery"
CONTACT_SHEET = "contact_sheet.png"
STAGE2 = stage2.STAGE2      # SEARCH/stage2, shown by default
SEARCH_FILES = ("config.json", SEARCH_LOG)
GIF_FRAMES = 24
GIF_SIZE = 2.3          # inches at 100 dpi
PEAK_PANEL = 2.0        # inches at 100 dpi: the peak views and the GIF fit beside the facts
SHEET_COLUMNS = 3

# x's components: (label as HTML, unit) by the names of agents.tasks.takeoff_state.
COMPONENTS = {"alpha": ("α", "rad"), "omega_x": ("ω<sub>x</sub>", "rad/s"),
              "omega_y": ("ω<sub>y</sub>", "rad/s"), "omega_z": ("ω<sub>z</sub>", "rad/s"),
              "v_z": ("v<sub>z</sub>", "m/s")}
STRATEGY_COLOURS = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3", "#937860",
                    "#da8bc3", "#8c8c8c", "#ccb974", "#64b5cd")


class GalleryError(ValueError):
    """A directory that is not a strategy search; the message names what is missing."""


@dataclass
class Evaluation:
    """One evaluation of a search as the gallery shows it."""

    stage: int                       # 1 or 2
    index: int
    directory: Path | None           # its evaluation directory (None: it has none)
    kind: str                        # initial / explore / diverse / random / stage 2 / ?
    x: list | None
    status: str                      # success / failure / in progress / waiting
    feature: list | None = None      # what its strategy is grouped by (None: no strategy)
    result: dict | None = None       # result.json
    reason: str | None = None        # why it failed
    progress: dict | None = None     # in progress: its training's last metrics record
    strategy: int = -1               # its group (bds.strategies.group); −1: none
    peak: str | None = None          # the pictures, relative to the page
    gif: str | None = None
    notes: list = field(default_factory=list)      # why no pictures, why not counted, …
    repeats: list = field(default_factory=list)    # Stage 2: the Stage-1 evaluations it repeats
    success_probability: float | None = None       # the success model's chance when picked
    source: str = ""                 # Stage 2: its directory's name (`_source_name`)
    verdict: dict | None = None      # Stage 2: eq. 3.12's (`stage2.round_verdict`), if known

    @property
    def name(self) -> str:
        if self.stage == 1:
            return f"Evaluation {self.index:03d}"
        return f"Stage 2 evaluation {self.index:03d}" + (
            "" if self.source == STAGE2 else f" ({self.source})")

    @property
    def anchor(self) -> str:
        """Its id in the page: eval-NNN in Stage 1, SOURCE-eval-NNN in Stage 2."""
        return f"{self.source}-eval-{self.index:03d}" if self.source else f"eval-{self.index:03d}"

    @property
    def stem(self) -> str:
        """Its pictures' file name without suffix: NNN in Stage 1, SOURCE_NNN in Stage 2."""
        return f"{self.source}_{self.index:03d}" if self.source else f"{self.index:03d}"

    @property
    def short_name(self) -> str:
        """Its name on the contact sheet."""
        return f"{self.source} {self.index:03d}" if self.source else f"{self.index:03d}"


@dataclass
class Section:
    """The evaluations of one stage, grouped into strategies."""

    title: str
    evaluations: list
    threshold: float
    distance: str
    feature_name: str                # what is grouped, in words
    why: str                         # why this threshold, in words
    task: str | None = None          # "highjump", "obstacle" or None (a landscape)
    label: str = "strategy"          # what its groups are called (a word ending in -y)


# ---------------------------------------------------------------------------------- reading

def _numbered_dirs(directory: Path) -> dict:
    """{index: path} of the subdirectories of `directory` named by a number (NNN)."""
    if not directory.is_dir():
        return {}
    return {int(p.name): p for p in directory.iterdir() if p.is_dir() and p.name.isdigit()}


def _train_config(directory: Path) -> dict | None:
    """An evaluation's training config (train/config.json) as stored, or None."""
    path = directory / jump_black_box.TRAIN / "config.json"
    if not path.exists():
        return None
    from agents import config as config_io
    return config_io.read_stored(path)


def _training_progress(directory: Path) -> dict | None:
    """The last record of an evaluation's training log (None: it logged nothing yet)."""
    from agents.rl import trainer as trainer_lib
    run_dir = directory / jump_black_box.TRAIN
    if not (run_dir / trainer_lib.METRICS).exists():
        return None
    records = trainer_lib.read_metrics(run_dir)
    return records[-1] if records else None


def _evaluation(stage, index, directory, kind, x, record=None) -> Evaluation:
    """The evaluation at `index` from its directory's files and its log `record` (either may
    be missing)."""
    result = jump_black_box.read_result(directory) if directory is not None else None
    if result is not None:
        x = result.get("x", x)
        status = "success" if result.get("outcome") == "success" else "failure"
        reason = result.get("reason")
        up = (result.get("feature") or {}).get("up_angle") if status == "success" else None
        feature = None if up is None else [up]
        return Evaluation(stage, index, directory, kind, x, status, feature, result, reason)
    if record is not None:                   # a black box that keeps no files (a landscape)
        status = "success" if record["feature"] is not None else "failure"
        return Evaluation(stage, index, directory, kind, record["x"], status,
                          record["feature"], reason=record["failure"])
    if directory is None:
        return Evaluation(stage, index, None, kind, x, "waiting")
    train = _train_config(directory)
    if train is not None and x is None:
        task = train.get("run", {}).get("task")
        x = train.get(task, {}).get("takeoff") or None
    return Evaluation(stage, index, directory, kind, x, "in progress",
                      progress=_training_progress(directory))


def _planned(log: Path) -> dict:
    """{index: (kind, x, chance of success when picked or None)} of every point the search
    log planned."""
    from bds.gp import from_unit
    records = runlog.read(log).records
    if not records or records[0].get("event") != "start":
        return {}
    lower, upper = (np.asarray(records[0][k], float) for k in ("lower", "upper"))
    planned = {}
    for record in records:
        if record.get("event") == "plan":
            chances = record.get("success_probability") or [None] * len(record["points"])
            for k, (point, kind, chance) in enumerate(zip(record["points"], record["kinds"],
                                                          chances)):
                x = from_unit(np.asarray(point, float), lower, upper)
                planned[record["first_index"] + k] = (kind, [float(v) for v in x], chance)
    return planned


def read_search(search_dir, stage2_dirs=()) -> tuple[dict, list]:
    """(the search's config, its sections: Stage 1; Stage 2 when there is a stage2/ folder;
    and one Stage-2 section for each of `stage2_dirs`, other `takeoff stage2` output
    directories). A GalleryError names what is missing from a directory that is not a search,
    or not a Stage-2 directory."""
    search_dir = Path(search_dir)
    if not search_dir.is_dir():
        raise GalleryError(f"{search_dir} is not a directory; give the run directory of a "
                           "`takeoff search`")
    missing = [name for name in SEARCH_FILES if not (search_dir / name).is_file()]
    if missing:
        raise GalleryError(f"{search_dir} is not a strategy search directory: it has no "
                           f"{' and no '.join(missing)} (a `takeoff search` run directory "
                           f"holds {' and '.join(SEARCH_FILES)})")
    from agents import config as config_io
    config = config_io.read_stored(search_dir / "config.json")
    if not isinstance(config.get("search"), dict) or "black_box" not in config:
        raise GalleryError(f"{search_dir / 'config.json'} is not a search config: it has no "
                           "black_box and [search] (is this a training run directory?)")
    stage1 = _stage1(search_dir, config)
    sections = [stage1]
    for directory, source in _stage2_sources(search_dir, stage2_dirs):
        sections.append(_stage2(_numbered_dirs(directory), config, stage1, source))
    return config, sections


def _stage2_sources(search_dir: Path, stage2_dirs) -> list:
    """[(directory, its name in the gallery)] of the Stage-2 sections: SEARCH/stage2 when it
    has rounds, then each of `stage2_dirs` (a directory named twice is shown once). A
    GalleryError names one that is not a `takeoff stage2` output directory, and two whose
    names (`_source_name`) are one, as their cards and pictures would be."""
    default = search_dir / STAGE2
    sources = {default.resolve(): (default, STAGE2)} if _numbered_dirs(default) else {}
    for directory in map(Path, stage2_dirs):
        if not (directory / stage2.PLAN).is_file():
            raise GalleryError(f"{directory} is not a Stage-2 directory: it has no "
                               f"{stage2.PLAN} (a `takeoff stage2 --out DIR` output "
                               f"directory holds {stage2.PLAN} and its rounds NNN/)")
        if directory.resolve() in sources:
            continue
        name = _source_name(directory)
        clash = next((d for d, n in sources.values() if n == name), None)
        if clash is not None:
            raise GalleryError(f"the Stage-2 directories {clash} and {directory} would both be "
                               f"named {name!r} in the gallery, and their pictures would "
                               "overwrite each other's: rename one of them")
        sources[directory.resolve()] = (directory, name)
    return list(sources.values())


def _source_name(directory: Path) -> str:
    """A Stage-2 directory's name in the gallery, part of its cards' ids and its pictures'
    file names: the directory's name, every character but letters, digits, '.', '_' and '-'
    made a '-' (so that it needs no escaping in a link)."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", directory.resolve().name)


def _stage1(search_dir: Path, config: dict) -> Section:
    """The search's own evaluations, grouped as its summary groups them (`takeoff search`:
    the features of its log within its budget, by its threshold and distance)."""
    log = search_dir / SEARCH_LOG
    records = {r["index"]: r for r in logged_evaluations(log)}
    planned = _planned(log)
    dirs = _numbered_dirs(search_dir / jump_black_box.EVALUATIONS)
    budget = config["search"].get("budget")
    evaluations = []
    for index in sorted(set(records) | set(planned) | set(dirs)):
        record = records.get(index)
        kind, x, chance = planned.get(index, ("?", None, None))
        if record is not None:
            kind, x = record["kind"], record["x"]
        evaluation = _evaluation(1, index, dirs.get(index), kind, x, record)
        evaluation.success_probability = chance
        if record is not None:
            evaluation.feature = record["feature"]
            measured = ((evaluation.result or {}).get("feature") or {}).get("up_angle")
            if (record["feature"] is not None and measured is not None
                    and not math.isclose(measured, record["feature"][0], abs_tol=1e-6)):
                evaluation.notes.append(
                    f"its result.json (up angle {math.degrees(measured):.1f}°) is not the "
                    f"measurement the search logged ({math.degrees(record['feature'][0]):.1f}°, "
                    "which groups it): the evaluation was trained and measured again")
        if budget is not None and index >= budget:
            evaluation.feature = None
            evaluation.notes.append(f"beyond the search's budget of {budget} evaluations: "
                                    "not counted among its strategies")
        evaluations.append(evaluation)
    same = float(config.get("same_strategy") or 0.0)
    if config["black_box"] == "jump":
        feature_name = ("the up angle (between the root's facing direction and the up axis "
                        "where the centre of mass crosses the bar plane)")
    else:
        feature_name = "the black box's feature"
    if same:
        why = f"the search config's same_strategy = {same:g}"
    else:
        why = ("bds.strategies.UP_ANGLE_THRESHOLD: the high-jump strategies differ in how the "
               "athlete faces while crossing — up (the Fosbury flop, near 0°), sideways (the "
               "western roll and side jumps, near 90°), down (the straddle and the dives, near "
               "180°) — and 30° splits [0°, 180°] into six such bands: two crossings 30° apart "
               "look alike, 60° apart they do not")
    section = Section("Stage 1: take-off states", evaluations,
                      same or strategies.UP_ANGLE_THRESHOLD,
                      config["search"].get("distance", "euclidean"), feature_name, why,
                      _task(evaluations, config))
    labels = strategies.group([ev.feature for ev in evaluations], section.threshold,
                              section.distance)
    for evaluation, label in zip(evaluations, labels):
        evaluation.strategy = int(label)
    return section


def _cross_rotvec(evaluation: Evaluation):
    """The 3-D root orientation at the crossing of a successful evaluation (None: none)."""
    feature = (evaluation.result or {}).get("feature")
    if evaluation.status == "success" and isinstance(feature, dict):
        return feature.get("cross_rotvec")
    return None


def _stage2(dirs: dict, config: dict, stage1: Section, source: str) -> Section:
    """The Stage-2 runs (NNN) of the Stage-2 directory named `source` in the gallery,
    grouped by the 3-D root orientation together with the Stage-1 policies before them (those
    counted among the search's strategies), so that a run that repeats a Stage-1 strategy says
    which."""
    evaluations = [_evaluation(2, index, path, "stage 2", None) for index, path in
                   sorted(dirs.items())]
    for evaluation in evaluations:
        evaluation.source = source
        evaluation.feature = _cross_rotvec(evaluation)
        if evaluation.feature is not None:
            evaluation.verdict = stage2.round_verdict(evaluation.directory, evaluation.result)
        if evaluation.result is not None:
            evaluation.kind = str(evaluation.result.get("kind", "stage 2"))
    title = "Stage 2: novel policies" + ("" if source == STAGE2 else f" ({source})")
    section = Section(
        title, evaluations, strategies.ROTATION_THRESHOLD, "rotation",
        "the root's 3-D orientation where the centre of mass crosses the bar plane (a rotation "
        "vector)",
        "bds.strategies.ROTATION_THRESHOLD, the thesis's d_threshold = π/2 (§3.6.2), the "
        "distance at which the novelty reward stops rewarding more difference; Stage-1 "
        "policies come first in the order, so a Stage-2 run that repeats one joins its group",
        _task(evaluations, config) or stage1.task, label="3-D strategy")
    known = [ev for ev in stage1.evaluations if ev.strategy >= 0 and _cross_rotvec(ev)]
    labels = strategies.group([_cross_rotvec(ev) for ev in known]
                              + [ev.feature for ev in evaluations],
                              section.threshold, section.distance)
    for evaluation, label in zip(evaluations, labels[len(known):]):
        evaluation.strategy = int(label)
        evaluation.repeats = [ev for ev, l in zip(known, labels) if l == label >= 0]
    return section


def _task(evaluations, config) -> str | None:
    """The jump task the evaluations trained ("highjump", "obstacle"), or None."""
    if config.get("black_box") != "jump":
        return None
    for evaluation in evaluations:
        if evaluation.result is not None and evaluation.result.get("task"):
            return evaluation.result["task"]
        if evaluation.directory is not None:
            train = _train_config(evaluation.directory)
            if train is not None:
                return train.get("run", {}).get("task")
    return None


# ---------------------------------------------------------------------------------- pictures

def drawing_env(train_dir, data_dir=None, config=None):
    """The environment that draws an evaluation whose training run is `train_dir` (or whose
    training config is `config`; None when its task has no world to draw): built from that
    config with plain PD actions and without its take-off x, since neither the model nor the
    world depends on the action space (a P-VAE run need not be at hand) and the world is drawn
    for each episode's own x. Evaluations of one search share it."""
    from agents.commands import train_commands
    from agents.datadir import data_dir_from
    if config is None:
        config = train_commands.load_run_config(train_dir)
    task = config.task
    if hasattr(task, "actions"):
        task = dataclasses.replace(task, actions="pd", takeoff=())
    return _env(config.run.task, task, data_dir_from(data_dir))


@functools.lru_cache(maxsize=4)
def _env(name, settings, data_dir):
    from agents.tasks import registry
    entry = registry.get(name)
    env = entry.make_env(settings, data_dir if entry.needs_data else None)
    return env if hasattr(env, "world_for") else None


def _fresh(picture: Path, source: Path) -> bool:
    return picture.exists() and picture.stat().st_mtime >= source.stat().st_mtime


def stand_in_config(search_config: dict, sections):
    """The training config that draws the evaluations whose own training run is gone (a search
    carried between machines, as docs/discovery's, keeps its episodes and results, not its
    training runs): that of the first evaluation that still has one, else the search's own
    `[jump]` training config (its file as it is now, with the search's overrides); None for
    another black box. One search's evaluations train from one config and differ only in their
    take-off x, which `drawing_env` leaves out."""
    from agents.commands import train_commands
    runs = (evaluation.directory / jump_black_box.TRAIN for section in sections
            for evaluation in section.evaluations if evaluation.directory is not None)
    run = next((run for run in runs if _has_config(run)), None)
    if run is not None:
        return train_commands.load_run_config(run)
    jump = search_config.get("jump")
    if search_config.get("black_box") != "jump" or not isinstance(jump, dict):
        return None
    return train_commands.load_config(jump["train"], jump.get("set", []))


def _has_config(run: Path) -> bool:
    return (run / "config.json").exists()


def draw(evaluation: Evaluation, images: Path, data_dir=None, echo=print, redraw=False,
         stand_in=None):
    """Draw (or keep, when newer than its episode, unless `redraw`) an evaluation's peak views
    and GIF in `images`; set their links, or a note saying why there are none. `stand_in`, a
    training config of the same search (`stand_in_config`), draws it when its own run is
    gone."""
    from agents.discovery import pictures
    from agents.commands.cli import run_errors
    from agents.datadir import DataDirError
    if evaluation.directory is None:
        return
    episode = evaluation.directory / jump_black_box.EPISODE
    if not episode.exists():
        if evaluation.status in ("success", "failure"):
            evaluation.notes.append(f"no pictures: {episode.name} is missing")
        return
    peak, gif = images / f"{evaluation.stem}_peak.png", images / f"{evaluation.stem}.gif"
    if redraw or not (_fresh(peak, episode) and _fresh(gif, episode)):
        try:
            run = evaluation.directory / jump_black_box.TRAIN
            config = stand_in if stand_in is not None and not _has_config(run) else None
            env = drawing_env(run, data_dir, config)
        except DataDirError:
            raise                      # no pictures at all: the user names the data directory
        except run_errors() as error:
            evaluation.notes.append(f"no pictures: {error}")
            echo(f"  {evaluation.name}: no pictures: {error}")
            return
        if env is None:
            evaluation.notes.append("no pictures: its task has no world to draw")
            return
        poses, control_dt, task = jump_black_box.read_episode(evaluation.directory, env.q0.dtype)
        echo(f"  drawing {evaluation.name} ({len(poses)} steps)")
        if redraw or not _fresh(peak, episode):
            pictures.peak_above_below(env, poses, task, peak, panel_size=PEAK_PANEL,
                                      control_dt=control_dt)
        if redraw or not _fresh(gif, episode):
            pictures.episode_animation(env, poses, task, gif, control_dt, GIF_FRAMES, GIF_SIZE)
    evaluation.peak = f"{IMAGES}/{peak.name}"
    evaluation.gif = f"{IMAGES}/{gif.name}"


def contact_sheet(sections, out_dir: Path, path: Path):
    """Every evaluation's peak views on one PNG, captioned with its index, outcome and
    strategy; an evaluation without pictures gets a captioned empty cell."""
    from jaxsim import render
    shown = [ev for section in sections for ev in section.evaluations
             if ev.status != "waiting"]
    plt = render.pyplot()
    columns = min(SHEET_COLUMNS, max(len(shown), 1))
    rows = max(1, math.ceil(len(shown) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 2.2 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, evaluation in zip(axes.ravel(), shown):
        if evaluation.peak is not None:
            ax.imshow(plt.imread(out_dir / evaluation.peak))
        else:
            ax.text(0.5, 0.5, evaluation.status, ha="center", va="center", color="#777777",
                    transform=ax.transAxes)
        colour = (STRATEGY_COLOURS[evaluation.strategy % len(STRATEGY_COLOURS)]
                  if evaluation.strategy >= 0 else "#333333")
        ax.set_title(_caption(evaluation), fontsize=8, color=colour)
    if not shown:
        axes[0, 0].text(0.5, 0.5, "no evaluations yet", ha="center", va="center")
    render.save_figure(fig, path)


def _caption(evaluation: Evaluation) -> str:
    """One line about an evaluation, for the contact sheet."""
    name = f"{evaluation.short_name} {evaluation.kind}"
    if evaluation.status == "success":
        height = (evaluation.result or {}).get("highest_cleared")
        up = ((evaluation.result or {}).get("feature") or {}).get("up_angle")
        words = [f"{math.degrees(up):.0f}° up"] if up is not None else []
        words += [f"{height:.2f} m"] if height is not None else []
        strategy = f"strategy {evaluation.strategy} " if evaluation.strategy >= 0 else ""
        return f"{name}: {strategy}({', '.join(words)})"
    if evaluation.status == "in progress":
        bar = _progress_bar(evaluation)
        return f"{name}: in progress{f', bar {bar:.2f} m' if bar is not None else ''}"
    return f"{name}: {evaluation.status}"


def _progress_bar(evaluation: Evaluation):
    """The bar height an in-progress evaluation's training has reached (None: not known)."""
    from agents.rl.trainer import DIFFICULTY
    return (evaluation.progress or {}).get(DIFFICULTY)


# ---------------------------------------------------------------------------------- the page

def e(value) -> str:
    """`value` as HTML text."""
    return html.escape(str(value), quote=True)


def _number(value, digits=2) -> str:
    return "—" if value is None else e(f"{value:.{digits}f}")


def _components(task, size) -> list:
    """The (label HTML, unit) of each of x's `size` components."""
    from agents.tasks import takeoff_state
    names = {"highjump": takeoff_state.HIGHJUMP_FEATURES,
             "obstacle": takeoff_state.OBSTACLE_FEATURES}.get(task)
    if names is None or len(names) != size:
        return [(f"x<sub>{k + 1}</sub>", "") for k in range(size)]
    return [COMPONENTS.get(name, (e(name), "")) for name in names]


def _x_cells(x, size) -> str:
    if x is None:
        return f"<td colspan='{size}'>—</td>"
    return "".join(f"<td>{_number(v)}</td>" for v in x)


def _x_list(x, task) -> str:
    if x is None:
        return "unknown"
    return ", ".join(f"{label} = {_number(v)}{(' ' + unit) if unit else ''}"
                     for (label, unit), v in zip(_components(task, len(x)), x))


def _feature_summary(evaluation: Evaluation, section: Section) -> str:
    """The grouped feature in words: an angle in degrees and radians (Stage 1 of a jump), a
    rotation vector (Stage 2), else its numbers."""
    feature = evaluation.feature
    if feature is None:
        return "—"
    if section.distance == "rotation":
        rotvec = np.asarray(feature, float)
        return (f"({', '.join(f'{v:.2f}' for v in rotvec)}) rad, "
                f"{math.degrees(np.linalg.norm(rotvec)):.0f}° of rotation")
    if section.task is not None:
        return ", ".join(f"{math.degrees(v):.1f}° ({v:.3f} rad)" for v in feature)
    return ", ".join(f"{v:.3f}" for v in feature)


def _feature_text(evaluation: Evaluation, section: Section) -> str:
    """The feature of an evaluation card: the up angle in degrees and radians, and the other
    measures of the bar crossing that result.json holds."""
    feature = (evaluation.result or {}).get("feature")
    if not isinstance(feature, dict) or "up_angle" not in feature:
        return e(_feature_summary(evaluation, section))
    up = feature["up_angle"]
    parts = [f"up angle {math.degrees(up):.1f}° ({up:.3f} rad)"]
    if feature.get("cross_rotvec") is not None:
        rotvec = np.asarray(feature["cross_rotvec"], float)
        parts.append(f"root orientation at the crossing ({', '.join(f'{v:.2f}' for v in rotvec)})"
                     f" rad, {math.degrees(np.linalg.norm(rotvec)):.0f}° of rotation")
    for key, words in (("clearance", "clearance"), ("peak_com", "peak centre of mass")):
        if feature.get(key) is not None:
            parts.append(f"{words} {feature[key]:.2f} m")
    return e("; ".join(parts))


def _strategy_badge(evaluation: Evaluation, section: Section) -> str:
    if evaluation.strategy < 0:
        return ""
    colour = STRATEGY_COLOURS[evaluation.strategy % len(STRATEGY_COLOURS)]
    return (f"<span class='badge' style='background:{colour}'>{e(section.label)} "
            f"{evaluation.strategy}</span>")


def _links(evaluations) -> str:
    return ", ".join(f"<a href='#{ev.anchor}'>{ev.index:03d}</a>" for ev in evaluations)


def _status_text(evaluation: Evaluation) -> str:
    result = evaluation.result or {}
    if evaluation.status == "success":
        return (f"<span class='ok'>success</span>: cleared "
                f"{_number(result.get('highest_cleared'))} m")
    if evaluation.status == "failure":
        return f"<span class='fail'>failure</span>: {e(evaluation.reason or 'no reason given')}"
    if evaluation.status == "waiting":
        return "<span class='wait'>waiting</span>: planned, not started"
    progress = evaluation.progress
    if not progress:
        return ("<span class='wait'>in progress</span>: no result.json yet, its training has "
                "logged nothing")
    bar = _progress_bar(evaluation)
    success = progress.get("env/episode/success")
    return (f"<span class='wait'>in progress</span>: no result.json yet; its training has the "
            f"bar at {_number(bar)} m after {int(progress.get('samples', 0)):,} samples "
            f"({progress.get('seconds', 0.0) / 60:.0f} min, iteration "
            f"{int(progress.get('iteration', 0))}"
            + (f"; {100 * success:.0f}% of its last iteration's episodes cleared the bar"
               if isinstance(success, (int, float)) else "") + ")")


def _strategy_text(evaluation: Evaluation, section: Section, members: dict) -> str:
    same = [m for m in members.get(evaluation.strategy, []) if m is not evaluation]
    text = f"{e(section.label)} {evaluation.strategy}"
    text += f" (the same as {_links(same)})" if same else " (alone)"
    if evaluation.stage == 2:
        text += (f"; its group holds Stage-1 evaluation {_links(evaluation.repeats)}"
                 if evaluation.repeats else "; its group holds no Stage-1 policy")
        text += f"; <b>{_novelty_text(evaluation)}</b>"
    return text


def _novelty_text(evaluation: Evaluation) -> str:
    """Eq. 3.12's verdict on a Stage-2 run, as `takeoff stage2`'s summary gives it: against
    every policy it was trained to differ from, not only its group's first."""
    verdict = evaluation.verdict
    if verdict is None:
        return "eq. 3.12: unknown (no known.json)"
    what = "novel" if verdict["novel"] else "repeats"
    return (f"eq. 3.12: {what} ({e(verdict['nearest'])}, the nearest of the policies it was "
            f"trained against, is {verdict['distance']:.2f} rad away; π/2 = "
            f"{verdict['threshold']:.2f})")


def _card(evaluation: Evaluation, section: Section, members: dict) -> str:
    result = evaluation.result or {}
    kind = evaluation.kind
    if evaluation.success_probability is not None:
        kind += f" (the success model gave it P[success] = {evaluation.success_probability:.2f})"
    rows = [("kind", e(kind)),
            ("x", _x_list(evaluation.x, section.task)),
            ("feature", _feature_text(evaluation, section)),
            ("highest bar cleared", f"{_number(result.get('highest_cleared'))} m"
             if result.get("highest_cleared") is not None else "—")]
    if evaluation.strategy >= 0:
        rows.append(("strategy", _strategy_text(evaluation, section, members)))
    if result:
        rows.append(("training", e(
            f"{int(result.get('samples', 0)):,} samples, {result.get('minutes', 0.0):.0f} min, "
            f"{result.get('iterations', '?')} iterations; the curriculum reached "
            f"{result.get('reached', float('nan')):.2f} m; evaluated at "
            f"{result.get('evaluated_at', float('nan')):.2f} m, "
            f"{100 * result.get('cleared_share', 0.0):.0f}% of the episodes cleared")))
    facts = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)
    figures = ""
    if evaluation.peak:
        figures += (f"<figure><a href='{e(evaluation.peak)}'><img src='{e(evaluation.peak)}' "
                    f"alt='peak pose of {e(evaluation.name)}' loading='lazy'></a><figcaption>"
                    f"peak pose: along the bar, from above, from below</figcaption></figure>")
    if evaluation.gif:
        figures += (f"<figure><img src='{e(evaluation.gif)}' alt='episode of "
                    f"{e(evaluation.name)}' loading='lazy'><figcaption>the evaluated episode"
                    f"</figcaption></figure>")
    figures += "".join(f"<p class='note'>{e(note)}</p>" for note in evaluation.notes)
    raw = ""
    if evaluation.result is not None:
        raw = (f"<details><summary>result.json</summary><pre>"
               f"{e(json.dumps(evaluation.result, indent=2))}</pre></details>")
    status_class = evaluation.status.replace(" ", "-")
    return (f"<section class='card {status_class}' id='{evaluation.anchor}'>"
            f"<h3>{e(evaluation.name)} {_strategy_badge(evaluation, section)}</h3>"
            f"<p class='status'>{_status_text(evaluation)}</p>"
            f"<div class='body'><table class='facts'>{facts}</table>"
            f"<div class='figures'>{figures}</div></div>{raw}</section>")


def _summary_table(section: Section, members: dict) -> str:
    """Table 3.3 / 3.4: one row per distinct strategy, with its first evaluation's x and
    feature."""
    if not members:
        return "<p>No strategy yet: no evaluation has succeeded.</p>"
    size = max((len(ev.x) for ev in section.evaluations if ev.x is not None), default=0)
    components = _components(section.task, size)
    has_stage2 = any(ev.stage == 2 for ev in section.evaluations)
    head = (f"<tr><th>{e(section.label)}</th><th>first found</th>"
            + "".join(f"<th>{label}{f' ({unit})' if unit else ''}</th>"
                      for label, unit in components)
            + "<th>feature</th><th>highest bar cleared</th><th>evaluations</th>"
            + ("<th>its first by eq. 3.12</th>" if has_stage2 else "") + "</tr>")
    body = []
    for group in members.values():
        first = group[0]
        heights = [h for h in ((g.result or {}).get("highest_cleared") for g in group)
                   if h is not None]
        verdict_cell = ""
        if has_stage2:
            verdict = first.verdict
            if verdict is None:
                verdict_cell = "<td>?</td>"
            else:
                what = "novel" if verdict["novel"] else f"repeats {e(verdict['nearest'])}"
                verdict_cell = f"<td>{what} ({verdict['distance']:.2f} rad)</td>"
        body.append(f"<tr><td>{_strategy_badge(first, section)}</td>"
                    f"<td><a href='#{first.anchor}'>{first.index:03d}</a> ({e(first.kind)})</td>"
                    f"{_x_cells(first.x, size)}<td>{e(_feature_summary(first, section))}</td>"
                    f"<td>{_number(max(heights)) + ' m' if heights else '—'}</td>"
                    f"<td>{len(group)}: {_links(group)}</td>{verdict_cell}</tr>")
    return f"<table class='summary'>{head}{''.join(body)}</table>"


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _plural(label: str, n: int) -> str:
    """A section's label ("strategy", "3-D strategy") for n of them."""
    return label if n == 1 else label[:-1] + "ies"


def _section_html(section: Section) -> str:
    members = {}
    for evaluation in section.evaluations:
        if evaluation.strategy >= 0:
            members.setdefault(evaluation.strategy, []).append(evaluation)
    counts = {status: sum(ev.status == status for ev in section.evaluations)
              for status in ("success", "failure", "in progress", "waiting")}
    plural = {"success": "successes", "failure": "failures"}   # "in progress", "waiting" stay
    tally = ", ".join(f"{n} {status if n == 1 else plural.get(status, status)}"
                      for status, n in counts.items() if n)
    degrees = (f" ({math.degrees(section.threshold):.0f}°)"
               if section.distance != "euclidean" or section.task else "")
    rule = (f"Evaluations are the same {e(section.label)} when their feature, "
            f"{e(section.feature_name)}, lies within {section.threshold:.4g}{degrees} "
            f"({e(section.distance)} distance) of the first evaluation of a strategy, taken in "
            f"the order they were made (bds.strategies.group). The threshold is "
            f"{e(section.why)}.")
    cards = "".join(_card(ev, section, members) for ev in section.evaluations)
    return (f"<h2>{e(section.title)}</h2>"
            f"<p>{_count(len(section.evaluations), 'evaluation')} ({e(tally or 'none')}); "
            f"<b>{len(members)} distinct {e(_plural(section.label, len(members)))}</b>.</p>"
            f"<p class='rule'>{rule}</p>"
            f"{_summary_table(section, members)}"
            f"<div class='cards'>{cards}</div>")


STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1400px; }
h1 { font-size: 1.5em; } h2 { border-bottom: 2px solid #ccc; margin-top: 1.5em; }
table.summary { border-collapse: collapse; margin: 0.8em 0; }
table.summary th, table.summary td { border: 1px solid #ccc; padding: 0.25em 0.6em;
  text-align: right; }
.cards { display: flex; flex-direction: column; gap: 0.8em; }
.card { border: 1px solid #ccc; border-left: 6px solid #999; padding: 0.4em 1em;
  border-radius: 4px; }
.card .body { display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }
.card table.facts { flex: 1 1 360px; max-width: 560px; }
.card.success { border-left-color: #55a868; } .card.failure { border-left-color: #c44e52; }
.card.in-progress, .card.waiting { border-left-color: #ccb974; background: #fcfbf4; }
.card h3 { margin: 0.2em 0; }
.badge { color: white; padding: 0.1em 0.5em; border-radius: 3px; font-size: 0.8em;
  white-space: nowrap; }
.ok { color: #2e7d32; font-weight: bold; } .fail { color: #c62828; font-weight: bold; }
.wait { color: #8d6e00; font-weight: bold; }
table.facts th { text-align: left; vertical-align: top; padding-right: 1em; font-weight: normal;
  color: #666; white-space: nowrap; }
.figures { display: flex; flex-wrap: wrap; gap: 0.5em; align-items: flex-end; }
figure { margin: 0.3em 0; } figure img { max-width: 100%; display: block; }
figcaption { font-size: 0.8em; color: #666; }
.rule, .note { font-size: 0.9em; color: #555; }
img.sheet { max-width: 100%; border: 1px solid #ddd; }
pre { font-size: 0.75em; background: #f6f6f6; padding: 0.5em; overflow-x: auto; }
"""


def page(search_dir, config: dict, sections: list, sheet: str | None) -> str:
    """The gallery page (HTML) of a search's sections."""
    search = config.get("search", {})
    heading = (f"Strategy search {e(search_dir)}: "
               f"{e(config.get('black_box'))} black box, {e(search.get('strategy', '?'))} "
               f"search, budget {e(search.get('budget', '?'))}")
    jump = config.get("jump", {}) if config.get("black_box") == "jump" else {}
    about = ""
    if jump:
        z_freeze = jump.get("z_freeze") or 0.0
        until = f"{z_freeze:.2f} m" if z_freeze else "its task's z_freeze"
        about = (f"<p>Each evaluation trains {e(jump.get('train'))} from its take-off state x "
                 f"(at most {int(jump.get('samples', 0)):,} samples, until the bar reaches "
                 f"{e(until)}) and measures its deterministic policy "
                 f"(agents.discovery.jump_black_box).</p>")
    sheet_html = (f"<h2>Contact sheet</h2><p><a href='{e(sheet)}'><img class='sheet' "
                  f"src='{e(sheet)}' alt='contact sheet of every evaluation'></a></p>"
                  if sheet else "")
    sections_html = "".join(_section_html(s) for s in sections)
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>{heading}</title><style>{STYLE}</style></head><body>"
            f"<h1>{heading}</h1>{about}{sections_html}{sheet_html}</body></html>\n")


def write_gallery(search_dir, out_dir=None, data_dir=None, echo=print, redraw=False,
                  stage2_dirs=()) -> Path:
    """Write the gallery of the search in `search_dir` (see the module docstring), with the
    Stage-2 directories `stage2_dirs` besides SEARCH/stage2, into `out_dir` (default: the
    search directory); returns the page's path. `redraw` draws every picture again, however
    new."""
    search_dir = Path(search_dir)
    config, sections = read_search(search_dir, stage2_dirs)
    out_dir = Path(out_dir) if out_dir is not None else search_dir
    images = out_dir / IMAGES
    check_writable(images, what="the gallery")
    images.mkdir(parents=True, exist_ok=True)
    try:
        stand_in = stand_in_config(config, sections)
    except (OSError, ValueError) as error:      # (a ConfigError is a ValueError)
        echo(f"  no training config to draw evaluations without a training run: {error}")
        stand_in = None
    for section in sections:
        for evaluation in section.evaluations:
            draw(evaluation, images, data_dir, echo, redraw, stand_in)
    sheet = None
    if any(ev.directory is not None for s in sections for ev in s.evaluations):
        contact_sheet(sections, out_dir, images / CONTACT_SHEET)
        sheet = f"{IMAGES}/{CONTACT_SHEET}"
    path = out_dir / PAGE
    write_text_atomic(path, page(search_dir, config, sections, sheet))
    return path


def errors():
    """The errors of `write_gallery` that are the user's to fix (a tuple for `except`)."""
    from agents.commands.cli import run_errors
    return (GalleryError, SearchError, *run_errors())
