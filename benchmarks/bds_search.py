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

--ballistic runs the same three methods on a real feature map instead: the ballistic black box
(`agents.tasks.ballistic`: the high jump's take-off state for x in `HIGHJUMP_BOUNDS` flies 2 s
holding its take-off pose; the feature is Stage 1's up angle when the centre of mass crosses the
bar plane, or a failure when it never does). Strategies are the up angle's bins of equal width
(`--bin-width`, degrees, 30 by default; 15, 45 and 60 are counted too); failures are no
strategy. The searches call the black box one point at a time, as they would the real one. The
mode also measures the up angle's distribution over `--uniform` uniform points (which gives the
expected count of random search and what a perfect search could reach) and draws the up angle
over three 2-D slices of the box (`--plot`).

Run:  python benchmarks/bds_search.py                       (50 landscapes)
      python benchmarks/bds_search.py --landscapes 5 --budget 10
      python benchmarks/bds_search.py --sweep --budget 10         (the splits of Algorithm 1)
      python benchmarks/bds_search.py --feature-range             (BDS told the features' range)
      python benchmarks/bds_search.py --ballistic                 (50 seeds on the ballistic box)
      python benchmarks/bds_search.py --ballistic --feasibility   (and BDS with bds.feasibility)
      python benchmarks/bds_search.py --ballistic --feasibility --hyperprior \
          --methods random bds-feasible bds-feasible-hyperprior   (the GP's hyperparameter priors)
Writes JSON (default benchmarks/results/bds.json; bds_ballistic.json with --ballistic) and
prints a markdown table.
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
DEFAULT_PLOT = Path(__file__).resolve().parents[1] / "docs" / "ballistic_up_angle.png"
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
# --ballistic --feasibility adds BDS (q = 1) whose picks are weighted by the chance of success
# (`bds.feasibility`).
FEASIBLE_METHODS = {"bds-feasible": dict(strategy="bds", batch=1, feasibility=True)}
# --ballistic --hyperprior adds BDS whose feature GP is fitted under weak hyperparameter priors
# (`bds.gp`, `hyperprior`), with the success model too when --feasibility is given.
HYPERPRIOR_METHODS = {"bds-hyperprior": dict(strategy="bds", batch=1, hyperprior=True)}
FEASIBLE_HYPERPRIOR_METHODS = {"bds-feasible-hyperprior": dict(strategy="bds", batch=1,
                                                               feasibility=True, hyperprior=True)}
# Each added method's ratio in the summary is to the method it adds one setting to.
BASELINE = {"bds-feasible": "bds", "bds-hyperprior": "bds",
            "bds-feasible-hyperprior": "bds-feasible"}


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


# ---------------------------------------------------------------------------------------------
# --ballistic: the ballistic black box (agents.tasks.ballistic)

BIN_WIDTHS = (15.0, 30.0, 45.0, 60.0)      # degrees; the one given by --bin-width is the headline


def strategy_bins(up_angle, width_deg):
    """The strategy of each up angle (rad, in [0, π]): its bin of `width_deg` degrees from 0,
    the last bin closed at π; NaN (a failure) is -1, no strategy."""
    up_angle = np.asarray(up_angle, float)
    count = int(np.ceil(180.0 / width_deg - 1e-9))
    bins = np.minimum(np.floor(np.degrees(np.nan_to_num(up_angle, nan=0.0)) / width_deg),
                      count - 1).astype(int)
    return np.where(np.isnan(up_angle), -1, bins)


def distinct_strategies(up_angle, width_deg, first):
    """How many strategies (bins; failures excluded) the first `first` evaluations found."""
    bins = strategy_bins(up_angle[:first], width_deg)
    return len(set(bins[bins >= 0].tolist()))


def feature_distribution(box, lower, upper, count, widths, checkpoints):
    """The up angle over `count` uniform points of the box (seeded): the failure fraction, a
    5° histogram and, per bin width, each strategy's probability, the expected distinct
    strategies of uniform random search after each checkpoint, and the most any search could
    find (the strategies that occur at all)."""
    xs = np.random.default_rng(20_211).uniform(lower, upper, size=(count, len(lower)))
    start = time.perf_counter()
    up_angle, crossed = box.features(xs)
    seconds = time.perf_counter() - start
    angles = np.where(crossed, up_angle, np.nan)
    out = {"points": count, "seconds": seconds, "failure_fraction": float(1 - crossed.mean()),
           "histogram_5deg": np.histogram(up_angle[crossed], bins=36, range=(0, np.pi))[0]
           .tolist(), "by_width": {}}
    for width in widths:
        bins = strategy_bins(angles, width)
        p = np.bincount(bins[bins >= 0], minlength=int(np.ceil(180 / width - 1e-9))) / count
        out["by_width"][str(width)] = {
            "probabilities": p.tolist(),
            "expected_random": {str(c): float(np.sum(1 - (1 - p) ** c)) for c in checkpoints},
            "ceiling": {str(c): int(min(c, np.count_nonzero(p))) for c in checkpoints}}
    return out


def run_ballistic_searches(box, lower, upper, args, feature_range, methods=METHODS):
    """Each method's search for each seed, the black box called per point; per search the
    distinct strategies after each checkpoint for every bin width, the failures, the
    searches' and the black box's seconds."""
    rows = []
    for seed in range(args.seeds):
        for method, options in methods.items():
            settings = SearchSettings(budget=args.budget, seed=seed, **options, **feature_range)
            spent = []
            start = time.perf_counter()
            result = search(box, lower, upper, settings,
                            progress=lambda record: spent.append(record["seconds"]))
            seconds = time.perf_counter() - start
            angles = result.features[:, 0]
            found = {str(w): {str(c): distinct_strategies(angles, w, c) for c in args.checkpoints}
                     for w in args.widths}
            rows.append({"seed": seed, "method": method, "seconds": seconds,
                         "black_box_seconds": float(np.sum(spent)),
                         "failures": int(np.isnan(angles).sum()), "found": found,
                         "kinds": result.kinds, "up_angle": [None if np.isnan(a) else float(a)
                                                             for a in angles],
                         "x": result.x.tolist()})
            print(f"seed {seed:3d} {method:8s} " + "  ".join(
                f"@{c}: {found[str(args.bin_width)][str(c)]}" for c in args.checkpoints)
                + f"  failures {rows[-1]['failures']}  {seconds:.1f} s", file=sys.stderr,
                flush=True)
    return rows


def ballistic_summary(rows, widths, checkpoints, methods=METHODS):
    """{width: {method: {checkpoint: (mean, standard error)}}} of the distinct strategies."""
    table = {}
    for width in widths:
        table[str(width)] = {}
        for method in methods:
            counts = {c: [r["found"][str(width)][str(c)] for r in rows if r["method"] == method]
                      for c in checkpoints}
            table[str(width)][method] = {
                str(c): (float(np.mean(v)), float(np.std(v) / np.sqrt(len(v))))
                for c, v in counts.items()}
    return table


def width_table(table, distribution, widths, checkpoints):
    """Markdown: per bin width, the strategies that occur, each method's mean distinct
    strategies, the ratios BDS ÷ random (first checkpoint) and q = 4 ÷ q = 1, the expected
    count of uniform random search and the ceiling over it (first checkpoint)."""
    methods = ("random", "bds", "bds-q4")
    first = str(checkpoints[0])
    lines = []
    for w in widths:
        mean = {m: {c: v[0] for c, v in table[str(w)][m].items()} for m in methods}
        shares = distribution["by_width"][str(w)]
        expected = shares["expected_random"][first]
        lines.append([f"{w:g}°", str(np.count_nonzero(shares["probabilities"])),
                      *(f"{mean[m][str(c)]:.2f}" for c in checkpoints for m in methods),
                      f"{mean['bds'][first] / mean['random'][first]:.2f}",
                      *(f"{mean['bds-q4'][str(c)] / mean['bds'][str(c)]:.2f}"
                        for c in checkpoints),
                      f"{expected:.2f}", f"{shares['ceiling'][first] / expected:.2f}"])
    return markdown_table(
        ["bin width", "strategies (bins) that occur",
         *(f"{m} @{c}" for c in checkpoints for m in methods), f"bds ÷ random @{first}",
         *(f"q4 ÷ q1 @{c}" for c in checkpoints), f"expected uniform random @{first}",
         f"ceiling ÷ expected random @{first}"], lines)


SLICES = ((0, 1), (1, 2), (0, 3))            # (α, ω_x), (ω_x, ω_z), (α, v_z)


def plot_slices(box, lower, upper, path, resolution):
    """The up angle over 2-D slices of the box through its centre (`SLICES`), the other two
    coordinates at the centre's values; failures grey, the 30° bin edges as contours."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centre = (lower + upper) / 2
    names = ("α (rad)", "ω_x (rad/s)", "ω_z (rad/s)", "v_z (m/s)")
    fig, axes = plt.subplots(1, len(SLICES), figsize=(5 * len(SLICES), 4.4),
                             layout="constrained")
    for ax, (i, j) in zip(axes, SLICES):
        a = np.linspace(lower[i], upper[i], resolution)
        b = np.linspace(lower[j], upper[j], resolution)
        grid = np.tile(centre, (resolution * resolution, 1))
        grid[:, i] = np.repeat(a, resolution)
        grid[:, j] = np.tile(b, resolution)
        up_angle, crossed = box.features(grid)
        image = np.degrees(np.where(crossed, up_angle, np.nan)).reshape(resolution, resolution)
        ax.set_facecolor("0.75")
        mesh = ax.pcolormesh(a, b, image.T, cmap="viridis", vmin=0, vmax=180, shading="nearest")
        ax.contour(a, b, image.T, levels=np.arange(30, 180, 30), colors="white",
                   linewidths=0.6)
        fixed = [k for k in range(4) if k not in (i, j)]
        ax.set_xlabel(names[i]), ax.set_ylabel(names[j])
        ax.set_title(f"{names[fixed[0]].split()[0]} = {centre[fixed[0]]:.2f}, "
                     f"{names[fixed[1]].split()[0]} = {centre[fixed[1]]:.2f}", fontsize=10)
    fig.colorbar(mesh, ax=axes, shrink=0.9, label="up angle at the crossing (°)")
    fig.suptitle("Ballistic black box: the up angle when the centre of mass crosses the bar "
                 "plane (white: 30° bin edges; grey: never crosses within 2 s)", fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}", file=sys.stderr)


def ballistic(args):
    """The --ballistic mode (see the module docstring)."""
    from agents import datadir
    from agents.tasks.ballistic import BallisticBlackBox
    from agents.tasks.takeoff_state import HIGHJUMP_BOUNDS

    args.widths = sorted({*BIN_WIDTHS, args.bin_width})
    lower, upper = (np.array(b) for b in HIGHJUMP_BOUNDS)
    box = BallisticBlackBox("highjump", datadir.data_dir_from(args.data_dir))
    # The up angle's range is [0, π] by definition; the thesis sets the GP's prior mean to the
    # middle of a feature's range (§3.6.1, "GP Priors and Kernels").
    feature_range = {} if args.unknown_range else dict(feature_low=(0.0,), feature_high=(np.pi,))
    start = time.perf_counter()
    box(lower)                                                     # compile one flight
    compile_one = time.perf_counter() - start
    distribution = feature_distribution(box, lower, upper, args.uniform, args.widths,
                                        args.checkpoints)
    print(f"{args.uniform} uniform points: {distribution['seconds']:.1f} s, failures "
          f"{distribution['failure_fraction']:.3f}", file=sys.stderr, flush=True)
    if args.plot_resolution:
        plot_slices(box, lower, upper, args.plot, args.plot_resolution)
    methods = {**METHODS, **(FEASIBLE_METHODS if args.feasibility else {}),
               **(HYPERPRIOR_METHODS if args.hyperprior else {}),
               **(FEASIBLE_HYPERPRIOR_METHODS if args.feasibility and args.hyperprior else {})}
    if args.methods:
        unknown = sorted(set(args.methods) - set(methods))
        if unknown:
            raise SystemExit(f"--methods: {', '.join(unknown)} not among {', '.join(methods)}")
        methods = {m: methods[m] for m in args.methods}
    start = time.perf_counter()
    rows = run_ballistic_searches(box, lower, upper, args, feature_range, methods)
    search_seconds = time.perf_counter() - start
    table = ballistic_summary(rows, args.widths, args.checkpoints, methods)
    headline = table[str(args.bin_width)]
    lines = [f"bin width {args.bin_width:g}°, {args.seeds} seeds:", "", markdown_table(
        ["method", *(f"distinct @{c} (mean ± s.e.)" for c in args.checkpoints)],
        [[method, *(f"{m:.2f} ± {e:.2f}" for m, e in by_c.values())]
         for method, by_c in headline.items()]), ""]
    if all(m in methods for m in METHODS):        # its ratios need all three
        lines.append(width_table(table, distribution, args.widths, args.checkpoints))
    added = [m for m in methods if BASELINE.get(m) in methods]
    if added:
        lines += ["", "the added settings, per bin width (distinct strategies, ratio to the "
                  "same method without the setting):"]
        for w in args.widths:
            mean = lambda method, c: table[str(w)][method][str(c)][0]
            lines.append(f"  {w:g}°: " + "; ".join(
                f"{m} @{c} {mean(m, c):.2f} ({mean(m, c) / mean(BASELINE[m], c):.2f}×)"
                for m in added for c in args.checkpoints))
    failures = {m: float(np.mean([r["failures"] for r in rows if r["method"] == m]))
                for m in methods}
    timing = {m: {"search_s": float(np.mean([r["seconds"] for r in rows if r["method"] == m])),
                  "black_box_s": float(np.mean([r["black_box_seconds"] for r in rows
                                                if r["method"] == m]))} for m in methods}
    lines.append("")
    lines.append("failures per search: " + ", ".join(f"{m} {v:.2f}" for m, v in failures.items()))
    lines.append("seconds per search (of which the black box): " + ", ".join(
        f"{m} {t['search_s']:.2f} ({t['black_box_s']:.2f})" for m, t in timing.items()))
    lines.append(f"searches {search_seconds / 60:.1f} min; one flight compiles in "
                 f"{compile_one:.1f} s; {args.uniform} batched flights in "
                 f"{distribution['seconds']:.1f} s")
    print("\n".join(lines))
    record = {"command": shlex.join([sys.executable, *sys.argv]), "machine": machine_info(),
              "black_box": "agents.tasks.ballistic.BallisticBlackBox('highjump')",
              "bounds": [lower.tolist(), upper.tolist()], "seeds": args.seeds,
              "budget": args.budget, "bin_width_deg": args.bin_width,
              "feature_range": feature_range, "summary": table, "distribution": distribution,
              "failures_per_search": failures, "timing": timing,
              "search_minutes": search_seconds / 60, "compile_one_flight_s": compile_one,
              "rows": rows}
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
    parser.add_argument("--ballistic", action="store_true",
                        help="search the ballistic black box (agents.tasks.ballistic) instead "
                             "of synthetic landscapes; JSON to results/bds_ballistic.json "
                             "unless --json is given")
    parser.add_argument("--seeds", type=int, default=50, help="--ballistic: searches per method")
    parser.add_argument("--bin-width", type=float, default=30.0,
                        help="--ballistic: the up angle's bin width that makes a strategy, "
                             "degrees (15, 45 and 60 are reported too)")
    parser.add_argument("--uniform", type=int, default=4096,
                        help="--ballistic: uniform points for the up angle's distribution")
    parser.add_argument("--feasibility", action="store_true",
                        help="--ballistic: also run BDS with its picks weighted by the chance "
                             "of success (bds.feasibility)")
    parser.add_argument("--hyperprior", action="store_true",
                        help="--ballistic: also run BDS with its feature GP fitted under weak "
                             "hyperparameter priors (bds.gp), with and without the success "
                             "model as --feasibility says")
    parser.add_argument("--methods", nargs="+",
                        help="--ballistic: run only these methods (e.g. random bds-feasible)")
    parser.add_argument("--unknown-range", action="store_true",
                        help="--ballistic: do not tell the searches the up angle's range [0, π]")
    parser.add_argument("--plot", type=Path, default=DEFAULT_PLOT,
                        help="--ballistic: the PNG of the up angle over three slices of the box")
    parser.add_argument("--plot-resolution", type=int, default=56,
                        help="--ballistic: grid points per axis of each slice (0: no plot)")
    parser.add_argument("--data-dir", help="--ballistic: the reference data (default: "
                                           "TAKEOFF_DATA, else ../shared/data)")
    args = parser.parse_args(argv)
    args.checkpoints = sorted({c for c in (10, 20) if c <= args.budget} | {args.budget})
    if args.ballistic:
        if args.json == DEFAULT_JSON:
            args.json = DEFAULT_JSON.with_name("bds_ballistic.json")
        return ballistic(args)
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
