"""Has the Stage-1 feature settled before z_freeze? Training a search's evaluations on, bar by bar.

The thesis stops each evaluation's training at z_freeze = 1.0 m "since the overall jumping
strategy usually remains unchanged after a given level of difficulty" (§3.6.1); a lower z_freeze
must be justified by showing the feature has settled there. This script takes finished
evaluations of a high-jump search, copies each one's training (`evaluations/NNN/train`) to
OUT/NNN/train, resumes it with the curriculum until the bar reaches each height of `--bars` in
turn, and at each height measures the deterministic policy exactly as the search's black box
does (`agents.discovery.jump_black_box.measure`: its episodes at the bar reached, result.json,
episode.npz, peak.png in OUT/NNN/bar_H.HH/). The search's own files are not touched.

Run:  python benchmarks/feature_settling.py SEARCH_DIR EVALUATION... [--bars 0.6 0.7 0.8 0.9 1.0]
          [--out runs/settling] [--data-dir ../shared/data] [--episodes 4]
      python benchmarks/feature_settling.py SEARCH_DIR --table runs/settling   (the table only)
      python benchmarks/feature_settling.py SEARCH_DIR --filmstrips PNG --table runs/settling
          [--bars 0.7 1.0]    (each evaluation's episode in the search and at those heights,
                               one filmstrip a row, seen along the bar)

      python benchmarks/feature_settling.py SEARCH_DIR --from-training [--bars ...]
          (no training, seconds: from each successful evaluation's training log, the up angle
           its training episodes crossed with while the bar stood at each height)

Killed, the first form is run again with the same arguments: a height already measured is not
measured again, and a training goes on from its last checkpoint. Run it alone on the machine: it
is a training. The last form is a cheaper and noisier view than the measurements (stochastic
training episodes, not the deterministic policy) that needs only each evaluation's training log,
`evaluations/NNN/train/metrics.jsonl` (which docs/discovery's carried copies of searches lack).
"""

import argparse
import math
import shutil
import sys
from pathlib import Path

import numpy as np

from agents.discovery.jump_black_box import (DIFFICULTY_TOLERANCE, EVALUATIONS, RESULT, TRAIN,
                                             evaluation_dir, measure, read_episode, read_result)
from bds.acquisition import rotation_geodesic


def bar_dir(out: Path, index: int, bar: float) -> Path:
    return out / f"{index:03d}" / f"bar_{bar:.2f}"


def settle(search_dir: Path, index: int, bars, out: Path, data_dir, episodes: int):
    """Train evaluation `index` of the search on to each of `bars` and measure it there."""
    from agents.commands import train_commands
    from agents.rl import trainer as trainer_lib
    source = evaluation_dir(search_dir, index)
    first = read_result(source)
    if first is None or first["outcome"] != "success":
        raise SystemExit(f"{source}: not a successful evaluation (nothing to train on)")
    run_dir = out / f"{index:03d}" / TRAIN
    if not (run_dir / trainer_lib.CHECKPOINT).exists():
        shutil.copytree(source / TRAIN, run_dir, dirs_exist_ok=True)
    for bar in bars:
        if read_result(bar_dir(out, index, bar)) is not None:
            continue
        reached = lambda config, last: (last.get(trainer_lib.DIFFICULTY, -1)
                                        >= bar - DIFFICULTY_TOLERANCE)
        overrides = lambda config, last: [f"run.stop_difficulty={bar}", "run.iterations=1000000",
                                          "run.time_limit_minutes=0"]
        echo = lambda text="": print(f"  [{index:03d} → {bar:.2f} m] {text}")
        train_commands.train_or_resume(None, run_dir, (), data_dir, echo, reached, overrides)
        result = measure(bar_dir(out, index, bar), run_dir, episodes, data_dir,
                         index=index, x=first["x"], bar=bar)
        print(f"{index:03d} at {result['evaluated_at']:.2f} m: {result['outcome']}, up angle "
              f"{_degrees(result)}, {result['samples']:,} samples, "
              f"{result['minutes']:.0f} training minutes", flush=True)


def _degrees(result) -> str:
    if result["outcome"] != "success":
        return "—"
    return f"{math.degrees(result['feature']['up_angle']):.0f}°"


def _rotation_distance(feature, other) -> float:
    """The geodesic angle between two features' 3-D root orientations at the crossing."""
    f, g = (np.asarray(r["cross_rotvec"], np.float32) for r in (feature, other))
    return float(rotation_geodesic(f, g[None])[0])


def table(search_dir: Path | None, out: Path) -> str:
    """A markdown table: per evaluation and height, the up angle, the 3-D orientation's change
    from the height before, the training's samples and minutes."""
    lines = ["| evaluation | bar | outcome | up angle | orientation moved since the row above "
             "| peak CoM | samples | training minutes |",
             "|---:|---:|---|---:|---:|---:|---:|---:|"]
    for evaluation in sorted(p for p in out.iterdir() if p.is_dir()):
        rows = []
        if search_dir is not None:
            rows.append(("search", read_result(evaluation_dir(search_dir, int(evaluation.name)))))
        rows += [(p.name[4:], read_result(p)) for p in sorted(evaluation.glob("bar_*"))
                 if (p / RESULT).exists()]
        previous = None
        for label, result in rows:
            if result is None:
                continue
            feature = result.get("feature")
            moved = peak = "—"
            if feature:
                peak = f"{feature['peak_com']:.2f} m"
                if previous:
                    moved = f"{math.degrees(_rotation_distance(feature, previous)):.0f}°"
                previous = feature
            lines.append(f"| {evaluation.name} | {result['evaluated_at']:.2f} m ({label}) | "
                         f"{result['outcome']} | {_degrees(result)} | {moved} | {peak} | "
                         f"{result['samples']:,} | {result['minutes']:.0f} |")
    return "\n".join(lines)


def training_table(search_dir: Path, bars, window: float = 0.05) -> str:
    """A markdown table: per successful evaluation of the search, the median over training
    iterations of the mean up angle of the episodes that crossed the bar plane, while the bar
    stood within `window` below each of `bars`; then the deterministic policy's up angle as the
    search measured it. (The trainer averages an episode metric over the episodes that ended in
    the iteration, one that never crossed the bar plane logging an up angle of 0, so each
    iteration's mean is divided by its share of crossed episodes; an iteration in which none
    ended logs null, read as NaN, and is left out.)"""
    from agents.rl import trainer as trainer_lib
    lines = ["| evaluation | " + " | ".join(f"{bar:.2f} m" for bar in bars) + " | measured |",
             "|---:|" + "---:|" * (len(bars) + 1)]
    for directory in sorted((search_dir / EVALUATIONS).iterdir()):
        result = read_result(directory)
        if result is None or result["outcome"] != "success":
            continue
        if not (directory / TRAIN / trainer_lib.METRICS).exists():
            lines.append(f"| {directory.name} | no training log |" + " |" * (len(bars) - 1)
                         + f" {_degrees(result)} |")
            continue
        records = trainer_lib.read_metrics(directory / TRAIN)
        logged = lambda key: np.array([r.get(key) for r in records], dtype=float)  # null: NaN
        bar_of = logged("env/episode/difficulty")        # the bar the ended episodes jumped
        crossed, up = logged("env/episode/crossed"), logged("env/episode/up_angle")
        cells = []
        for bar in bars:
            at = (bar_of > bar - window) & (bar_of <= bar + DIFFICULTY_TOLERANCE) & (crossed > 0)
            cells.append(f"{math.degrees(np.median(up[at] / crossed[at])):.0f}°" if at.any()
                         else "—")
        lines.append(f"| {directory.name} | " + " | ".join(cells) + f" | {_degrees(result)} |")
    return "\n".join(lines)


def filmstrips(search_dir: Path, out: Path, bars, path: Path, panels: int = 10):
    """One PNG: a row per episode (each evaluation in OUT as the search measured it, then at
    each of `bars`), `panels` poses of it seen along the bar (`jaxsim.render.filmstrip`)."""
    episodes = []
    for evaluation in sorted(p for p in out.iterdir() if p.is_dir()):
        index = int(evaluation.name)
        episodes += [(f"{index:03d} in the search", evaluation_dir(search_dir, index),
                      evaluation / TRAIN)]
        episodes += [(f"{index:03d} at {bar:.2f} m", bar_dir(out, index, bar), evaluation / TRAIN)
                     for bar in bars]
    filmstrip_sheet(episodes, path, panels)


def filmstrip_sheet(episodes, path: Path, panels: int = 10):
    """One PNG of episodes [(label, directory with episode.npz, the training run that drew it)],
    a row each: `panels` poses seen along the bar (`jaxsim.render.filmstrip`)."""
    import tempfile
    from PIL import Image
    from agents.discovery import pictures
    from agents.discovery.gallery import drawing_env
    from jaxsim import render
    rows, envs = [], {}
    with tempfile.TemporaryDirectory() as scratch:
        for label, directory, run_dir in episodes:
            if run_dir not in envs:                  # (rows of one run share its world)
                envs[run_dir] = drawing_env(run_dir)
            env = envs[run_dir]
            poses, control_dt, task = read_episode(directory, env.q0.dtype)
            _, along = pictures.bar_directions(env, task)
            row = Path(scratch) / f"{len(rows)}.png"
            render.filmstrip(env.model, poses, row, world=env.world_for(task),
                             n_panels=panels, azimuth=pictures.azimuth_looking_along(along),
                             times=control_dt * (np.arange(len(poses)) + 1), title=label,
                             panel_size=1.6)
            rows.append(Image.open(row).convert("RGB"))
    sheet = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows)), "white")
    top = 0
    for row in rows:
        sheet.paste(row, (0, top))
        top += row.height
    sheet.convert("P", palette=Image.ADAPTIVE, colors=32).save(path, optimize=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("search_dir", nargs="?", type=Path)
    parser.add_argument("evaluations", nargs="*", type=int)
    parser.add_argument("--bars", nargs="+", type=float, default=[0.6, 0.7, 0.8, 0.9, 1.0])
    parser.add_argument("--out", type=Path, default=Path("runs/settling"))
    parser.add_argument("--data-dir", type=Path)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--table", type=Path, help="only print the table of this OUT directory")
    parser.add_argument("--filmstrips", type=Path, help="with --table: write the filmstrips here")
    parser.add_argument("--from-training", action="store_true",
                        help="only print the training episodes' up angle at each bar")
    args = parser.parse_args(argv)
    if args.from_training:
        if args.search_dir is None or not (args.search_dir / EVALUATIONS).is_dir():
            parser.error(f"--from-training needs a search directory with {EVALUATIONS}/; "
                         f"got {args.search_dir}")
        print(training_table(args.search_dir, args.bars))
        return
    if args.table is not None:
        if args.filmstrips is not None:
            filmstrips(args.search_dir, args.table, args.bars, args.filmstrips)
        print(table(args.search_dir, args.table))
        return
    if args.search_dir is None or not args.evaluations:
        parser.error("give the search directory and at least one evaluation index")
    if sorted(args.bars) != args.bars:
        parser.error(f"--bars must rise; got {args.bars}")
    for index in args.evaluations:
        settle(args.search_dir, index, args.bars, args.out, args.data_dir, args.episodes)
    print(table(args.search_dir, args.out))


if __name__ == "__main__":
    sys.exit(main())
