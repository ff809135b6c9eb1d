"""Does the take-off speed towards the bar decide a high-jump training's outcome? (`bar_time`)

For each evaluation of each given search directory (`evaluations/NNN/result.json`, written by a
strategy search or by benchmarks/thesis_rows.py): the root's take-off speed towards the bar
plane, v · n(α) (`JumpEnv.bar_speed`, with the clip of the search's training config), the time
the bar of that config (`bar_plane_distance`) takes at that speed, and the evaluation's outcome
and up angle at the bar crossing. It prints them as a markdown table sorted by the speed, then
the outcomes counted in speed bands (`--bands`, m/s), beside each band's share of the search
box `HIGHJUMP_BOUNDS` (of 200,000 uniform points).

Run:  python benchmarks/bar_speed.py docs/discovery/pd docs/discovery/box2 ... \
          [--bands 1.5 2.2] [--data-dir ../shared/data]

A few seconds: nothing is simulated.
"""

import argparse
import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np

from agents.commands import strategy_search, train_commands
from agents.datadir import data_dir_from
from agents.discovery.jump_black_box import outcome, read_result
from agents.tasks import jump
from agents.tasks.takeoff_state import HIGHJUMP_BOUNDS
from bds.search import Failure


def rows_of(search_dir: Path, data_dir) -> tuple[list[dict], jump.JumpEnv]:
    """One row per evaluation in `search_dir` with a result.json, and the environment of its
    training config."""
    config = strategy_search.load_search_config(search_dir)
    base = train_commands.load_config(config.jump.train, config.jump.set)
    if base.run.task != "highjump":
        raise SystemExit(f"{search_dir}: the bar speed is the high jump's; this search trains "
                         f"{base.run.task}")
    settings = base.task
    env = jump.JumpEnv(dataclasses.replace(settings, actions="pd"), data_dir)  # no P-VAE needed
    rows = []
    for path in sorted((search_dir / "evaluations").glob("*/result.json")):
        result = read_result(path.parent)
        speed = float(env.bar_speed(result["x"]))
        distance = float(jump.bar_plane_distance(speed, settings.bar_distance, settings.bar_time))
        feature = outcome(result)          # the search's own reading: a feature or a Failure
        rows.append({"search": search_dir.name, "index": result["index"], "x": result["x"],
                     "actions": settings.actions, "speed": speed,
                     "time": distance / speed if speed > 0 else float("inf"),
                     "distance": distance, "outcome": result["outcome"],
                     "up_angle": (None if isinstance(feature, Failure)
                                      else float(np.degrees(feature[0])))})
    return rows, env


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("searches", nargs="+", type=Path)
    parser.add_argument("--bands", nargs="*", type=float, default=[1.5, 2.2])
    parser.add_argument("--data-dir", default=None)
    args = parser.parse_args()
    data_dir = data_dir_from(args.data_dir)
    found = [rows_of(search_dir, data_dir) for search_dir in args.searches]
    rows = sorted((row for rows, _ in found for row in rows), key=lambda row: row["speed"])
    low, high = (np.asarray(bound) for bound in HIGHJUMP_BOUNDS)
    box = np.random.default_rng(0).uniform(low, high, (200_000, len(low)))
    box_speeds = np.asarray(found[0][1].bar_speed(box))
    point = lambda x: "(" + ", ".join(f"{v:.2f}" for v in x) + ")"
    print("| search | evaluation | x = (α, ω_x, ω_z, v_z) | actions | v · n(α) (m/s) | bar (m) | "
          "time to it (s) | outcome | up angle |")
    print("|---|---:|---|---|---:|---:|---:|---|---:|")
    for row in rows:
        angle = "—" if row["up_angle"] is None else f"{row['up_angle']:.0f}°"
        print(f"| {row['search']} | {row['index']:03d} | {point(row['x'])} | {row['actions']} | "
              f"{row['speed']:.2f} | {row['distance']:.2f} | {row['time']:.2f} | "
              f"{row['outcome']} | {angle} |")
    edges = [-np.inf, *sorted(args.bands), np.inf]
    counts = Counter((np.searchsorted(edges, row["speed"], side="right") - 1, row["actions"],
                      row["outcome"]) for row in rows)
    print("\n| v · n(α) (m/s) | actions | successes | failures | share of the box |\n"
          "|---|---|---:|---:|---:|")
    for band in range(len(edges) - 1):
        share = np.mean((box_speeds >= edges[band]) & (box_speeds < edges[band + 1]))
        for actions in sorted({row["actions"] for row in rows}):
            print(f"| [{edges[band]:.1f}, {edges[band + 1]:.1f}) | {actions} | "
                  f"{counts[band, actions, 'success']} | {counts[band, actions, 'failure']} | "
                  f"{share:.0%} |")


if __name__ == "__main__":
    main()
