"""How many distinct strategies do BDS, batched BDS and random search find on synthetic strategy
landscapes, and how long does one BDS decision take?

For each of N random landscapes (bds.landscapes: a 4-D box split into 8 strategies of very unequal
size by a weighted Voronoi diagram, 2 of them owning most of the box), each method runs a 20-
evaluation search with the landscape's seed; we count the distinct strategies among the first 10
and the first 20 evaluations. The methods are

    random     uniform random search
    bds        Algorithm 1 (4 random, then 3 exploration / 3 diversity picks alternating), q = 1
    bds-q4     batched BDS, 4 points per round (counted per evaluation, not per round)

Reference: how many strategies spreading the points alone finds — the expected count for uniform
random points (from the strategies' volumes) and for maximin space-filling designs (best of 300
random designs by smallest pairwise distance, 5 per landscape).

--sweep compares Algorithm 1's splits, and reports for each kind of pick after the first four how
often it found a new strategy, how often it lay on a face of the box, and the volume of the strategy
it landed in (which picks do the finding, and where).

Decision time: the wall time of planning one BDS pick (GP fit + acquisition + optimisation) with
50 observations in a 4-D box, for an exploration and a diversity pick; median of repeats after a
warm-up (compile time reported separately).

Run:  python benchmarks/bds_search.py                       (50 landscapes)
      python benchmarks/bds_search.py --landscapes 5 --budget 10
      python benchmarks/bds_search.py --sweep --budget 10         (the splits of Algorithm 1)
      python benchmarks/bds_search.py --feature-range             (BDS told the features' range)
Writes JSON (default benchmarks/results/bds.json) and prints a markdown table.
"""

import argparse
import json
import shlex
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from jaxsim import allocator
from jaxsim.atomic import write_text_atomic
from bds.landscapes import FEATURE_KINDS, LandscapeSettings, StrategyLandscape
from bds.search import SearchSettings, plan_round, search
from spd import machine_info, markdown_table

DEFAULT_JSON = Path(__file__).resolve().parent / "results" / "bds.json"
# --sweep: Algorithm 1's split between random, exploration and diversity picks, at q = 1
# ("i" initial random picks, "e" exploration and "d" diversity picks per cycle).
SWEEP = {
    "random": dict(strategy="random"),
    "i4 e3 d3": dict(strategy="bds"),
    "i2 e3 d3": dict(strategy="bds", initial=2),
    "i1 e3 d3": dict(strategy="bds", initial=1),
    "i4 e1 d3": dict(strategy="bds", explore=1),
    "i4 e0 d1": dict(strategy="bds", explore=0, diverse=1),
    "i4 e1 d0": dict(strategy="bds", explore=1, diverse=0),
    "i2 e1 d0": dict(strategy="bds", initial=2, explore=1, diverse=0),
    "i1 e1 d0": dict(strategy="bds", initial=1, explore=1, diverse=0),
    "i2 e3 d1": dict(strategy="bds", initial=2, explore=3, diverse=1),
    "i2 e1 d1": dict(strategy="bds", initial=2, explore=1, diverse=1),
}
METHODS = {
    "random": dict(strategy="random"),
    "bds": dict(strategy="bds", batch=1),
    "bds-q4": dict(strategy="bds", batch=4),
}


def describe_picks(landscape, volumes, result):
    """Per pick: its kind, whether it found a strategy not seen before, whether it lies on a face
    of the box, and the volume of the strategy it landed in."""
    labels = landscape.label(result.x).tolist()
    return [{"kind": kind, "new": label not in labels[:j],
             "on_face": bool(np.min(np.minimum(x, 1.0 - x)) < 1e-3),
             "volume": float(volumes[label])}
            for j, (x, kind, label) in enumerate(zip(result.x, result.kinds, labels))]


def pick_report(rows, methods, first_pick):
    """Markdown table: for each method and kind of pick, over picks `first_pick` + 1 onwards, how
    often a pick found a new strategy, how often it lay on a face of the box, and the median volume
    of the strategy it landed in."""
    lines = []
    for method in methods:
        picks = [p for r in rows if r["method"] == method for p in r["picks"][first_pick:]]
        for kind in sorted({p["kind"] for p in picks}):
            mine = [p for p in picks if p["kind"] == kind]
            lines.append([method, kind, str(len(mine)),
                          f"{np.mean([p['new'] for p in mine]):.2f}",
                          f"{np.mean([p['on_face'] for p in mine]):.2f}",
                          f"{np.median([p['volume'] for p in mine]):.3f}"])
    return markdown_table(["setting", f"picks {first_pick + 1}–", "count", "new strategy",
                           "on a face", "median volume landed in"], lines)


def run_diversity(args, methods=METHODS):
    # The landscapes' features lie in [0, 1] (one component); --feature-range tells the searches.
    feature_range = dict(feature_low=(0.0,), feature_high=(1.0,)) if args.feature_range else {}
    rows = []
    for seed in range(args.landscapes):
        landscape = StrategyLandscape(LandscapeSettings(seed=seed, features=args.features))
        volumes = landscape.volumes(50_000)
        for method, options in methods.items():
            settings = SearchSettings(budget=args.budget, seed=seed, **options, **feature_range)
            start = time.perf_counter()
            result = search(landscape, np.zeros(4), np.ones(4), settings)
            seconds = time.perf_counter() - start
            picks = describe_picks(landscape, volumes, result)
            counts = {c: sum(p["new"] for p in picks[:c]) for c in args.checkpoints}
            rows.append({"landscape": seed, "method": method, "seconds": seconds,
                         **{f"found@{c}": counts[c] for c in args.checkpoints}, "picks": picks})
            print(f"landscape {seed:3d} {method:12s} " + "  ".join(
                f"@{c}: {counts[c]}" for c in args.checkpoints), file=sys.stderr, flush=True)
    return rows


def maximin_design(count, dim, rng, tries):
    """The best of `tries` uniform random designs by their smallest pairwise distance."""
    best, best_gap = None, -1.0
    for _ in range(tries):
        points = rng.uniform(size=(count, dim))
        gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + 9.0 * np.eye(count)
        if gaps.min() > best_gap:
            best, best_gap = points, gaps.min()
    return best


def space_filling_reference(landscapes, count, designs=5, tries=300):
    """What spreading points alone achieves: for each landscape, the expected distinct
    strategies of `count` uniform random points (from the strategies' volumes) and the mean over
    `designs` maximin designs of `count` points. Returns the two means over the landscapes."""
    rng = np.random.default_rng(0)
    expected_random, maximin = [], []
    for seed in range(landscapes):
        landscape = StrategyLandscape(LandscapeSettings(seed=seed))
        volumes = landscape.volumes(50_000)
        expected_random.append(float(np.sum(1.0 - (1.0 - volumes) ** count)))
        dim = landscape.settings.dim
        maximin.append(np.mean([len(set(landscape.label(maximin_design(count, dim, rng, tries))
                                         .tolist())) for _ in range(designs)]))
    return float(np.mean(expected_random)), float(np.mean(maximin))


def time_decisions(repeats):
    """Seconds to plan one exploration and one diversity pick with 50 observations."""
    landscape = StrategyLandscape(LandscapeSettings(seed=0))
    x = np.random.default_rng(0).uniform(size=(50, 4))
    features = np.array([landscape(p) for p in x])
    out = {}
    for kind, index in (("explore", 4), ("diverse", 7)):
        settings = SearchSettings(initial=4, explore=3, diverse=3)
        assert settings.kind(index) == kind
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            plan_round(settings, index, 1, x, features, 4)
            times.append(time.perf_counter() - start)
        out[kind] = {"first_call_s": times[0], "median_s": statistics.median(times[1:]),
                     "repeats": repeats}
    return out


def summary(rows, checkpoints, methods=METHODS):
    table = {}
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        table[method] = {c: (float(np.mean([r[f"found@{c}"] for r in mine])),
                             float(np.std([r[f"found@{c}"] for r in mine]) / np.sqrt(len(mine))))
                         for c in checkpoints}
    return table


def sweep(args):
    """Distinct strategies at the first checkpoint for each SWEEP setting, with its ratio to
    random search."""
    rows = run_diversity(args, SWEEP)
    table = summary(rows, args.checkpoints, SWEEP)
    first = args.checkpoints[0]
    random_mean = table["random"][first][0]
    print(markdown_table(
        ["setting", f"distinct @{first} (mean ± s.e.)", "÷ random"],
        [[name, f"{t[first][0]:.2f} ± {t[first][1]:.2f}", f"{t[first][0] / random_mean:.2f}"]
         for name, t in table.items()]))
    print()
    print(pick_report(rows, SWEEP, first_pick=4))
    write_record(args, table, rows, settings=SWEEP)


def write_record(args, table, rows, **extra):
    """The run's JSON: command, machine, the summary table, `extra` entries and every row."""
    record = {"command": shlex.join([sys.executable, *sys.argv]), "machine": machine_info(),
              "landscapes": args.landscapes,
              "summary": {m: {str(c): v for c, v in t.items()} for m, t in table.items()},
              **extra, "rows": rows}
    write_text_atomic(args.json, json.dumps(record, indent=2) + "\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--landscapes", type=int, default=50)
    parser.add_argument("--budget", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=5, help="timed decisions per kind")
    parser.add_argument("--features", choices=FEATURE_KINDS, default="spread",
                        help="how strategies' features are drawn (bds.landscapes); the regions "
                             "are the same either way")
    parser.add_argument("--feature-range", action="store_true",
                        help="give the searches the features' range, [0, 1] "
                             "(SearchSettings.feature_low/feature_high): the GP's prior mean is "
                             "its middle instead of the middle of the features seen")
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON)
    parser.add_argument("--sweep", action="store_true",
                        help="compare Algorithm 1's splits (SWEEP) instead; JSON to "
                             "results/bds_sweep.json unless --json is given")
    args = parser.parse_args(argv)
    args.checkpoints = sorted({c for c in (10, 20) if c <= args.budget} | {args.budget})
    if args.sweep:
        if args.json == DEFAULT_JSON:
            args.json = DEFAULT_JSON.with_name("bds_sweep.json")
        return sweep(args)
    reference = space_filling_reference(args.landscapes, args.checkpoints[0])
    decisions = time_decisions(args.repeats)
    rows = run_diversity(args)
    table = summary(rows, args.checkpoints)
    lines = [markdown_table(
        ["method", *(f"distinct @{c} (mean ± s.e.)" for c in args.checkpoints)],
        [[method, *(f"{mean:.2f} ± {err:.2f}" for mean, err in by_checkpoint.values())]
         for method, by_checkpoint in table.items()])]
    random_10 = table["random"][args.checkpoints[0]][0]
    lines.append("")
    lines.append(f"bds / random at {args.checkpoints[0]}: "
                 f"{table['bds'][args.checkpoints[0]][0] / random_10:.2f}; bds-q4 / bds: "
                 f"{table['bds-q4'][args.checkpoints[0]][0] / table['bds'][args.checkpoints[0]][0]:.2f}")
    lines.append(f"spreading points alone, {args.checkpoints[0]} points: uniform random "
                 f"(expected, from the volumes) {reference[0]:.2f}, maximin designs "
                 f"{reference[1]:.2f} distinct strategies ({reference[1] / reference[0]:.2f}×)")
    for kind, t in decisions.items():
        lines.append(f"one {kind} decision with 50 observations: median {t['median_s']:.3f} s "
                     f"(first call, with compilation: {t['first_call_s']:.2f} s)")
    print("\n".join(lines))
    write_record(args, table, rows, decisions=decisions,
                 space_filling={"expected_random": reference[0], "maximin": reference[1]})


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
