"""Would the success model have kept the high-jump search off its failures? A replay.

For each model-based pick of the committed high-jump search (docs/discovery/evaluations.jsonl,
feasibility off), given the outcomes logged before it: the chance of success that BDS's success
model (`bds.feasibility`, fitted exactly as `bds.search.plan_round` fits it for that pick) gives
the point the search picked, and the point BDS with the success model picks instead, with its
chance. Nothing is evaluated: the replay says where the search would have gone, not what it
would have found.

Run:  python benchmarks/feasibility_replay.py [SEARCH_DIR]   (a markdown table; about a minute)

SEARCH_DIR (default docs/discovery) is any high-jump search's directory: on a search made with
the success model on, the two pick columns agree, which checks that the replay fits the model
as the search did; for picks planned before 2026-12-06, when the success model was fitted by
its marginal likelihood alone (not under priors, as now), they need not.
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np

from agents.commands.strategy_search import load_search_config
from bds import feasibility, gp
from bds.search import SEARCH_LOG, logged_evaluations, plan_round, success_model

DISCOVERY = Path(__file__).resolve().parent.parent / "docs" / "discovery"


def replay(directory=DISCOVERY):
    """Rows (index, kind, the pick made, its P, the pick with the model, its P)."""
    config = load_search_config(directory)
    settings = dataclasses.replace(config.search, feasibility=True)
    lower, upper = config.bounds()                   # the search's own box
    records = logged_evaluations(directory / SEARCH_LOG)
    rows = []
    for index in range(settings.initial, len(records) + 1):
        done = records[:index]
        unit = lambda rs: gp.to_unit(np.array([r["x"] for r in rs]).reshape(-1, 4), lower, upper)
        good = [r for r in done if r["feature"] is not None]
        failed = [r for r in done if r["feature"] is None]
        x_unit, failed_unit = unit(good), unit(failed)
        features = np.array([r["feature"] for r in good])
        points, kinds, _ = plan_round(settings, index, 1, x_unit, features, 4, failed_unit)
        model = success_model(settings, index, x_unit, failed_unit)
        chance = lambda u: float(feasibility.success_probability(model, np.asarray(u)[None])[0])
        made = records[index]["x"] if index < len(records) else None
        rows.append((index, kinds[0], made,
                     None if made is None else chance(gp.to_unit(np.array(made), lower, upper)),
                     gp.from_unit(np.asarray(points[0]), lower, upper), chance(points[0])))
    return rows


def main():
    point = lambda x: "(" + ", ".join(f"{v:.2f}" for v in x) + ")"
    print("| pick | kind | the search's pick x = (α, ω_x, ω_z, v_z) | P[success] "
          "| with the success model | P[success] |")
    print("|---:|---|---|---:|---|---:|")
    directory = Path(sys.argv[1]) if len(sys.argv) > 1 else DISCOVERY
    for index, kind, made, made_p, pick, pick_p in replay(directory):
        made_text = "(next) | —" if made is None else f"{point(made)} | {made_p:.2f}"
        print(f"| {index:03d} | {kind} | {made_text} | {point(pick)} | {pick_p:.2f} |")


if __name__ == "__main__":
    main()
