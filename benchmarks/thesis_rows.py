"""What does our jump training learn from the thesis's own take-off states? (Table 3.3 / 3.4)

Evaluates each row of `HIGHJUMP_ROWS` (or `OBSTACLE_ROWS`) with the jump black box of a strategy
search's config, exactly as that search would evaluate the point: the same training, give-up
points, z_freeze and measurement. OUT is laid out as a search directory: `config.json` (a
rerun may change only what a resumed search may, `strategy_search.check_resumable`), and each
row an evaluation directory `OUT/evaluations/NNN/` (NNN its place in the order given), so a
killed run resumes its row's training from its last checkpoint, and a row whose result.json
exists is read, not trained again (a row in another place is refused: the black box checks x).
It then prints a markdown table of the rows' outcomes, with the shares of the first 10 training
iterations' episodes that crossed the bar's plane and that hit the bar (what the probe give-up
point reads), and groups the successes by the search's strategy rule (`bds.strategies`; π/6 of
the up angle unless the config's same_strategy says otherwise), in the order given.

If the rows give as many strategies as the thesis names, our training can produce them, and
what a search finds depends on where it looks; if they give fewer, the training is the likelier
limit (other points of the box may still give what the rows do not).

Run:  python benchmarks/thesis_rows.py SEARCH_CONFIG --out runs/thesis_rows \
          [--rows western_roll side_jump ...] [--set jump.probe_samples=40960 ...] \
          [--data-dir ../shared/data]

SEARCH_CONFIG is a search's TOML (configs/highjump_bds.toml) or a search directory holding its
config.json (docs/discovery/pd); `--set` overrides the TOML's keys. A row takes what a search's
evaluation takes: about a minute given up at the probe, 25 minutes at the 2 M-sample give-up
point, 65–85 minutes to a bar of 1.0 m on 2 cores.
"""

import argparse
import json
from pathlib import Path

import numpy as np

from agents import config as config_io
from agents.commands import strategy_search, train_commands
from agents.datadir import data_dir_from
from agents.discovery.jump_black_box import (TRAIN, JumpBlackBox, early_share, evaluation_dir,
                                             outcome, read_result)
from agents.rl import parallel
from agents.rl import trainer as trainer_lib
from agents.tasks.takeoff_state import (HIGHJUMP_FEATURES, HIGHJUMP_ROWS, OBSTACLE_FEATURES,
                                        OBSTACLE_ROWS)
from bds import strategies
from bds.search import Failure, SearchError
from jaxsim.atomic import write_text_atomic

ROWS = {"highjump": HIGHJUMP_ROWS, "obstacle": OBSTACLE_ROWS}
EARLY = 10      # iterations (40,960 samples at 4,096 each): the table shows their episodes' shares
EARLY_SHARES = {f"first {EARLY} iterations {what}": key   # the table's column: the metric
                for what, key in (("crossed", "env/episode/crossed"),
                                  ("hit the bar", "env/episode/hit_bar"))}
FEATURES = {"highjump": HIGHJUMP_FEATURES, "obstacle": OBSTACLE_FEATURES}


def load_config(source: Path, overrides) -> strategy_search.SearchConfig:
    """The search config of a TOML file (with `overrides`) or of a search directory."""
    if source.is_dir():
        if overrides:
            raise SystemExit(f"--set applies to a TOML config; {source} is a search directory")
        return strategy_search.load_search_config(source)
    return config_io.load(source, strategy_search.SearchConfig, overrides)


def evaluate_rows(config, names, out: Path, data_dir) -> list[dict]:
    """Each named row's result.json, evaluated (or read back) in `out`."""
    if config.black_box != "jump":
        raise SystemExit(f"the config's black box is {config.black_box!r}; this needs 'jump'")
    rows = ROWS[config.task()]
    unknown = [name for name in names if name not in rows]
    if unknown:
        raise SystemExit(f"no such {config.task()} row: {', '.join(unknown)}; the rows are "
                         f"{', '.join(rows)}")
    out.mkdir(parents=True, exist_ok=True)
    text = strategy_search.config_text(config)
    if strategy_search.started(out):          # rows evaluated before: as a search resumes
        strategy_search.check_resumable(out, json.loads(text))
    write_text_atomic(out / "config.json", text)
    box = JumpBlackBox(config.jump, out, data_dir)
    results = []
    for index, name in enumerate(names):
        box.evaluate(index, rows[name])
        records = trainer_lib.read_metrics(evaluation_dir(out, index) / TRAIN)
        early = {column: early_share(records, key, EARLY)   # None without the training's log
                 for column, key in EARLY_SHARES.items()}
        results.append({"row": name, **read_result(evaluation_dir(out, index)), **early})
    return results


def table(results, config) -> str:
    """The rows' outcomes as a markdown table, with each success's strategy by the search's
    same-strategy rule (`bds.strategies`, as the search's summary groups them)."""
    threshold, task = config.strategy_threshold(), config.task()
    features = [None if isinstance(g, Failure) else g for g in map(outcome, results)]
    labels = strategies.group(features, threshold, config.search.distance)
    shares = list(EARLY_SHARES)
    lines = [f"| row | x = ({', '.join(FEATURES[task])}) | {' | '.join(shares)} | outcome | bar "
             "| up angle | strategy | samples | minutes |",
             "|---|---|" + "---:|" * len(shares) + "---|---:|---:|---:|---:|---:|"]
    for result, label in zip(results, labels):
        x = ", ".join(f"{v:.2f}" for v in result["x"])
        if result["feature"]:
            up = result["feature"]["up_angle"]
            cells = [f"{result['highest_cleared']:.2f} m", f"{np.degrees(up):.0f}°", str(label)]
        else:
            cells = ["—", "—", "—"]
        early = " | ".join("—" if result[name] is None else f"{result[name]:.1%}"
                           for name in shares)
        lines.append(f"| {result['row']} | ({x}) | {early} | {result['outcome']} | "
                     + " | ".join(cells)
                     + f" | {result['samples']:,} | {result['minutes']:.0f} |")
    found = len({label for label in labels if label >= 0})
    lines.append(f"\n{found} {'strategy' if found == 1 else 'strategies'} (features within "
                 f"{np.degrees(threshold):.0f}° are one) from {len(results)} rows.")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("config", type=Path, help="a search TOML or a search directory")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--rows", nargs="+", help="row names, in order (default: all)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE")
    parser.add_argument("--data-dir")
    args = parser.parse_args()
    try:
        config = load_config(args.config, args.overrides)
        parallel.start(train_commands.load_config(config.jump.train, config.jump.set).run.devices)
        names = args.rows or list(ROWS[config.task()])
        results = evaluate_rows(config, names, args.out, data_dir_from(args.data_dir))
    except (config_io.ConfigError, SearchError) as error:
        raise SystemExit(f"error: {error}") from None
    print(table(results, config))


if __name__ == "__main__":
    main()
