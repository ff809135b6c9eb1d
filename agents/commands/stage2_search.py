"""`takeoff stage2 SEARCH_DIR`: Stage 2 of strategy discovery over a jump search (thesis §3.5.2,
§3.7.1): novel policy seeking from every Stage-1 strategy the search found.

"In Stage 2, we perform novel policy search for five DRL iterations from each good initial state
of Stage 1. Training is warm started with the associated Stage 1 policy" (§3.7.1).

What "five DRL iterations" means. Not five PPO iterations (4,096 samples each; seconds of
training): the thesis's Stage 2 took about 60 hours for the initial states of its six Stage-1
strategies, while one Stage-1 evaluation (a training to z_freeze) took about 6 hours. Thirty
trainings of about 2 hours each fit: we read a DRL iteration as one round of novel policy search,
one training of a new policy π_{n+1} against the set Π of the policies found so far (§3.5.2),
and give it a third of a Stage-1 evaluation's budget. Hence the defaults:
    --rounds      5 rounds per Stage-1 strategy;
    --iterations  ⌈jump.samples / 3 / samples per iteration⌉ PPO iterations per round
                  (jump.samples: the search's training budget of one evaluation): 977 for
                  configs/highjump_bds.toml's 12,000,000 samples at 4,096 per iteration
                  (163 for the 2,000,000 of the first two searches in docs/discovery).
With them Stage 2 costs what the thesis's did relative to Stage 1: six strategies × 5 rounds ×
a third of an evaluation = the ten evaluations of the search.
    --sigma       none: a round's exploration noise σ goes on from where its Stage-1 policy
                  left it (`agents.discovery.stage2.warm_start`); given, every round explores
                  with this constant σ instead (its config's ppo.sigma_start = sigma_end).
                  Why: σ anneals with samples (`agents.rl.networks.sigma_at`, 0.5 → 0.1 over
                  10 M), so a policy trained to z_freeze = 1.0 m (8.4 M samples) hands Stage 2
                  a σ of 0.17 that falls to 0.10 in its round, and neither 1.0 m round of
                  docs/discovery left its source's strategy; the 0.6 m policies (2 M samples)
                  explored at σ ≈ 0.43 and four of their five rounds found a novel one.

Each Stage-1 strategy (`agents.discovery.stage2.stage1_strategies`: the search's successful
evaluations grouped as its own summary groups them) starts its rounds from its representative,
the evaluation that cleared the highest bar (or, when that one's trained policy is not in the
search directory, the one of the strategy's evaluations with a policy that did). When none of
them has its policy here (a search carried between machines keeps results, not policies), or the
one it has is a training stopped part way, the search's own black box trains it (again) before
the round starts — the search's training config, overrides, budget and z_freeze, from the
evaluation's x, resumed from its checkpoint if killed — and says so: an hour or more at z_freeze
= 1.0 m. Each round is a `takeoff train` run from that evaluation's config (its take-off state,
networks and PPO settings) with a `[novelty]` section warm-starting from its Stage-1 policy. The
features a round is novel against (`known`) are those of every policy the search has found when
the round starts: every successful Stage-1 evaluation — not only the representatives: Stage 1
groups by the 1-D up angle alone, and two evaluations of one group may cross the bar in
different 3-D orientations — and every successful Stage-2 round before it. So Π grows as in
§3.5.2, and two rounds that find the same new strategy do not both count it as novel. The rounds
therefore run one after another, round by round (the first round of every strategy, then the
second, …), so a Stage 2 stopped early has tried every strategy.

A Stage-1 policy trained again is measured into SEARCH/evaluations/NNN/retrained/
(`_stage1_policy`), and its crossing joins the known set beside the one the search logged.

Files, under OUT (default SEARCH/stage2):
    plan.json        the rounds (index, Stage-1 evaluation, its strategy, round), fixed at the
                     first start, with the rounds, iterations and σ
    NNN/stage2.toml  the round's training config (written before it trains; its known features
                     fixed then), NNN/known.json which policy each known feature is
    NNN/train/       its `takeoff train` run directory
    NNN/result.json  (and episode.npz, peak.png) its policy measured as Stage 1 measures an
                     evaluation (`agents.discovery.jump_black_box.measure`), written last
    summary.json     what the summary printed
Run again, the command skips the rounds with a result.json, resumes the one in progress from its
checkpoint, and goes on; with a larger --rounds it first adds the rounds after the plan's own
(round by round, from the same starts), so a Stage 2 can grow sitting by sitting.

The summary: a round's policy is novel when its crossing orientation is farther than d_threshold
from every feature it was trained against (where r_novelty, eq. 3.12, reaches 1); otherwise it
repeats the nearest of them, named with its Stage-1 strategy.
"""

import json
import math
from pathlib import Path

from agents import config as config_io
from agents.commands import train_commands
from agents.config import ConfigError
from agents.discovery import jump_black_box, stage2
from agents.discovery.stage2 import KNOWN, PLAN, RETRAINED, RUN_CONFIG   # (shared)
from agents.rl import parallel
from agents.rl import trainer as trainer_lib
from bds.search import SearchError
from jaxsim.atomic import check_writable, hold_directory, write_text_atomic

SUMMARY = "summary.json"
ROUNDS = 5                  # "five DRL iterations" (§3.7.1), as rounds
ROUND_SHARE = 3             # a round's samples: a third of one Stage-1 evaluation's budget


def run(search_dir, iterations=None, rounds=None, out=None, data_dir=None, echo=print,
        sigma=None) -> list:
    """Run (or resume) Stage 2 over the search in `search_dir`; print and return the summary
    (a dict per round). `sigma`: the rounds' constant exploration noise (None: Stage 1's)."""
    search_dir = Path(search_dir)
    out = search_dir / stage2.STAGE2 if out is None else Path(out)
    search_config, records = stage2.read_search(search_dir)
    _start_devices(search_dir, records)
    with hold_directory(out, "Stage 2"):
        plan = _plan(search_dir, out, search_config, iterations, rounds, sigma, echo)
        for entry in plan["runs"]:
            _run_round(search_dir, out, entry, plan, search_config, data_dir, echo)
        return summarise(search_dir, out, echo)


def _start_devices(search_dir, records):
    """The devices the Stage-1 trainings used, asked for before JAX's backend starts."""
    for record in records:
        path = (jump_black_box.evaluation_dir(search_dir, record["index"])
                / jump_black_box.TRAIN / train_commands.CONFIG)
        if path.is_file():
            parallel.start(config_io.read_stored(path).get("run", {}).get("devices", 1))
            return


def _plan(search_dir, out, search_config, iterations, rounds, sigma, echo) -> dict:
    """The stored plan of a Stage 2 in `out`, or a new one written there."""
    path = out / PLAN
    if path.exists():
        plan = config_io.read_stored(path)
        for flag, given, stored in (("--iterations", iterations, plan["iterations"]),
                                    ("--sigma", sigma, plan.get("sigma"))):
            if given is not None and given != stored:
                raise ConfigError(f"{out} holds a Stage 2 of {plan['rounds']} rounds × "
                                  f"{plan['iterations']} iterations{_with_sigma(plan)}, and "
                                  f"{flag} {given} asks for another: give the same (or none) to "
                                  "resume it, or another --out")
        if rounds is not None and rounds < plan["rounds"]:
            raise ConfigError(f"{out} holds a Stage 2 of {plan['rounds']} rounds, and --rounds "
                              f"{rounds} asks for fewer: give {plan['rounds']} or more (more "
                              "rounds are added after its own), or none, or another --out")
        if rounds is not None and rounds > plan["rounds"]:
            echo(f"adding rounds {plan['rounds'] + 1}–{rounds} to the Stage 2 in {out}")
            plan = _with_rounds(plan, rounds)
            _write_json(path, plan)
        else:
            echo(f"resuming Stage 2 in {out}")
        return plan
    found = stage2.stage1_strategies(search_dir)
    if not found:
        raise SearchError(f"{search_dir}: no evaluation of the search succeeded, so there is no "
                          "Stage-1 strategy to start Stage 2 from")
    rounds = ROUNDS if rounds is None else rounds
    if iterations is None:
        per_iteration = _samples_per_iteration(search_dir, search_config,
                                               found[0].representative)
        iterations = math.ceil(search_config["jump"]["samples"] / ROUND_SHARE / per_iteration)
    starts = [{"evaluation": _start_evaluation(search_dir, strategy, echo),
               "strategy": strategy.label} for strategy in found]
    plan = _with_rounds({"search": str(search_dir), "rounds": 0, "iterations": iterations,
                         "sigma": sigma, "runs": []}, rounds, starts)
    check_writable(out, what="Stage 2's runs")
    _write_json(path, plan)
    echo(f"Stage 2 of {search_dir}: {len(found)} Stage-1 strateg{'y' if len(found) == 1 else 'ies'}"
         f" × {rounds} round{'s' if rounds > 1 else ''} of {iterations} iteration"
         f"{'s' if iterations > 1 else ''}{_with_sigma(plan)} → {out}")
    return plan


def _with_rounds(plan, rounds, starts=None) -> dict:
    """`plan` with rounds up to `rounds` per strategy: the new ones after its own, round by
    round, from each strategy's start (`starts`: [{evaluation, strategy}]; default: those of
    its first round)."""
    if starts is None:
        starts = [{"evaluation": run["evaluation"], "strategy": run["strategy"]}
                  for run in plan["runs"] if run["round"] == 0]
    added = [{**start, "round": r} for r in range(plan["rounds"], rounds) for start in starts]
    runs = plan["runs"] + [{"index": len(plan["runs"]) + i, **entry}
                           for i, entry in enumerate(added)]
    return {**plan, "rounds": rounds, "runs": runs}


def _with_sigma(plan) -> str:
    sigma = plan.get("sigma")          # (a plan written before --sigma existed has none)
    return "" if sigma is None else f" at σ {sigma:g}"


def _start_evaluation(search_dir, strategy, echo) -> int:
    """The evaluation a Stage-1 strategy's rounds warm-start from: its representative (the
    highest bar, the first of equals), unless that one's trained policy is not in `search_dir`
    — a search carried from machine to machine keeps its results, not its policies — and another
    of the strategy's evaluations has one: then the one of those that cleared the highest bar.
    With no policy anywhere it stays the representative, whose policy `_stage1_policy` trains
    again."""
    def has_policy(index):
        return trainer_lib.has_checkpoint(jump_black_box.evaluation_dir(search_dir, index)
                                          / jump_black_box.TRAIN)
    with_policy = [i for i in strategy.evaluations if has_policy(i)]
    if has_policy(strategy.representative) or not with_policy:
        return strategy.representative
    start, bar = stage2.highest_bar(search_dir, with_policy)
    echo(f"Stage-1 strategy {strategy.label}: evaluation {strategy.representative}'s policy is "
         f"not in {search_dir}, so its rounds start from evaluation {start}'s (bar {bar:.2f} m)")
    return start


def _samples_per_iteration(search_dir, search_config, evaluation) -> int:
    """Samples per PPO iteration of the Stage-1 training of `evaluation`, from its stored
    config; from the search's training config when its run is not here."""
    run_dir = jump_black_box.evaluation_dir(search_dir, evaluation) / jump_black_box.TRAIN
    if (run_dir / train_commands.CONFIG).is_file():
        return train_commands.load_run_config(run_dir).run.samples_per_iteration
    jump = search_config["jump"]
    return train_commands.load_config(jump["train"], jump["set"]).run.samples_per_iteration


def stage2_sections(stage1_run, known, iterations, sigma=None) -> dict:
    """The config (nested dicts) of a Stage-2 round from the Stage-1 run in `stage1_run`: its
    settings (task, take-off state, networks, PPO; with a constant exploration σ = `sigma`
    unless that is None), `iterations` iterations with no stop difficulty or time limit, and a
    [novelty] section warm-starting from it, novel against the rotation vectors `known`. The
    warm start is written as `stage1_run` is given (a relative path stays relative to the
    working directory, as the config's P-VAE path is), not resolved to this machine's absolute
    path."""
    sections = config_io.read_stored(Path(stage1_run) / train_commands.CONFIG)
    sections["run"].update(iterations=iterations, stop_difficulty=0.0, time_limit_minutes=0.0)
    if sigma is not None:
        sections["ppo"].update(sigma_start=sigma, sigma_end=sigma)
    sections["novelty"] = {"warm_start": str(Path(stage1_run)),
                           "known": [[float(v) for v in f] for f in known],
                           "threshold": stage2.NoveltySettings.threshold,
                           "distance": stage2.NoveltySettings.distance}
    return sections


def to_toml(sections) -> str:
    """Nested dicts of plain values as TOML (a JSON string, number, boolean or array is the
    same TOML value; TOML has no null, so a None setting is left out: its default)."""
    lines = []
    for name, table in sections.items():
        lines += [f"[{name}]", *(f"{key} = {json.dumps(value, ensure_ascii=False)}"
                                 for key, value in table.items() if value is not None), ""]
    return "\n".join(lines)


def _stage1_policy(search_dir, search_config, index, data_dir, echo):
    """Make sure Stage-1 evaluation `index` has a finished policy before a round warm-starts
    from it. One whose training ended on its own (`JumpBlackBox.trained`) is used as it is,
    however it ended. One that is missing, or killed part way, is trained (again), or resumed,
    by the search's own black box (see the module docstring), then measured as the search
    measures an evaluation, into evaluations/NNN/retrained/ (result.json, episode, peak pose): a
    new training from the same x may jump another way. Its result.json — what the search
    measured and logged — is kept as it was, and the new measurement joins the policies the
    rounds are novel against (`stage2.found_policies`); the command says how far the new
    policy's crossing is from the logged one, and stops when the new policy does not clear the
    bar."""
    from agents.commands import strategy_search
    directory = jump_black_box.evaluation_dir(search_dir, index)
    run_dir, again = directory / jump_black_box.TRAIN, directory / RETRAINED
    config = config_io.build(strategy_search.SearchConfig, search_config,
                             str(Path(search_dir) / "config.json"))
    box = strategy_search.black_box(config, search_dir, data_dir)
    if box.trained(run_dir) and not again.exists():
        return                                       # the policy the search measured
    result = jump_black_box.read_result(directory)   # a success's (stage1_strategies)
    measured = jump_black_box.read_result(again)
    if measured is None:
        if not trainer_lib.has_checkpoint(run_dir):
            echo(f"Stage-1 evaluation {index}'s policy is not in {search_dir}: training it again "
                 f"from its x with the search's settings (its first training: "
                 f"{int(result.get('samples', 0)):,} samples, {result.get('minutes', 0.0):.0f} "
                 "min)")
        again.mkdir(parents=True, exist_ok=True)     # marks the run as one to measure when done
        why = box.train(run_dir, result["x"])
        if why:
            raise SearchError(
                f"{run_dir}: Stage-1 evaluation {index} trained again went nowhere ({why}), "
                f"unlike its first training, so Stage 2 has no policy to start from; delete "
                f"{run_dir} and {again} to try again")
        measured = jump_black_box.measure(again, run_dir, config.jump.episodes, data_dir,
                                          index=index, x=result["x"], retrained=True)
    if measured["outcome"] != "success":
        raise SearchError(f"{again}: Stage-1 evaluation {index} trained again does not clear the "
                          f"bar ({measured['reason']}), so Stage 2 has no policy to start from; "
                          f"delete {run_dir} and {again} to train it again")
    threshold = stage2.NoveltySettings.threshold
    _, _, moved = stage2.is_novel(measured["feature"]["cross_rotvec"],
                                  [result["feature"]["cross_rotvec"]], threshold)
    echo(f"Stage-1 evaluation {index} trained again clears {measured['highest_cleared']:.2f} m "
         f"(first training: {result['highest_cleared']:.2f} m), its crossing {moved:.2f} rad "
         f"from the one the search logged (π/2 = {threshold:.2f}); its rounds are novel "
         f"against both ({again / jump_black_box.RESULT})")


def _run_round(search_dir, out, entry, plan, search_config, data_dir, echo):
    """One round: trained (or resumed), then measured; nothing when it has its result."""
    index = entry["index"]
    directory = out / f"{index:03d}"
    if jump_black_box.read_result(directory) is not None:
        return
    run_dir = directory / jump_black_box.TRAIN
    echo(f"[stage2 {index:03d}] round {entry['round'] + 1}/{plan['rounds']} from evaluation "
         f"{entry['evaluation']} (Stage-1 strategy {entry['strategy']})")
    say = jump_black_box.prefixed_echo(f"  [stage2 {index:03d}] ")
    config_path = directory / RUN_CONFIG
    if not config_path.exists():
        _stage1_policy(search_dir, search_config, entry["evaluation"], data_dir, echo)
        known = stage2.found_policies(search_dir, out)
        stage1_run = (jump_black_box.evaluation_dir(search_dir, entry["evaluation"])
                      / jump_black_box.TRAIN)
        _write_json(directory / KNOWN, [{"policy": p.name, "cross_rotvec": p.cross_rotvec}
                                        for p in known])
        sections = stage2_sections(stage1_run, [p.cross_rotvec for p in known],
                                   plan["iterations"], plan.get("sigma"))
        write_text_atomic(config_path, f"# Stage 2 (takeoff stage2), round "
                          f"{entry['round'] + 1} from {stage1_run}\n" + to_toml(sections))
    train_commands.train_or_resume(config_path, run_dir, data_dir=data_dir, echo=say)
    config = train_commands.load_run_config(run_dir)
    result = jump_black_box.measure(
        directory, run_dir, search_config["jump"]["episodes"], data_dir, index=index,
        x=list(config.sections()[config.run.task]["takeoff"]), stage=2,
        evaluation=entry["evaluation"], strategy=entry["strategy"], round=entry["round"])
    echo(f"[stage2 {index:03d}] {_outcome(result)}")


def _outcome(result) -> str:
    if result["outcome"] != "success":
        return f"FAILED: {result['reason']}"
    feature = result["feature"]
    return (f"crossing orientation ({', '.join(f'{v:.2f}' for v in feature['cross_rotvec'])}), "
            f"up angle {feature['up_angle']:.2f}, bar {result['highest_cleared']:.2f} m")


def summarise(search_dir, out, echo=print) -> list:
    """Which rounds found a novel policy and which repeat one (see the module docstring),
    printed and written to summary.json."""
    plan = config_io.read_stored(Path(out) / PLAN)
    strategy_of = {i: s.label for s in stage2.stage1_strategies(search_dir)
                   for i in s.evaluations}
    rows = []
    for entry in plan["runs"]:
        directory = Path(out) / f"{entry['index']:03d}"
        result = jump_black_box.read_result(directory)
        row = {**entry, "outcome": "not run" if result is None else result["outcome"]}
        if result is not None and result["outcome"] == "success":
            verdict = stage2.round_verdict(directory, result)
            name = verdict["nearest"]
            if name.startswith("evaluation "):
                name += f" (Stage-1 strategy {strategy_of.get(int(name.split()[1]), '?')})"
            row.update(verdict, nearest=name, feature=result["feature"],
                       highest_cleared=result["highest_cleared"])
        elif result is not None:
            row.update(reason=result["reason"])
        rows.append(row)
    _write_json(Path(out) / SUMMARY, rows)
    novel = sum(bool(r.get("novel")) for r in rows)
    repeats = sum(r.get("novel") is False for r in rows)
    failed = sum(r["outcome"] == "failure" for r in rows)
    echo(f"\nStage 2 of {search_dir}: {len(rows)} round{'s' if len(rows) != 1 else ''}, "
         f"{novel} novel, {repeats} "
         f"repeat{'s' if repeats != 1 else ''}, {failed} failed"
         + (f", {len(rows) - novel - repeats - failed} not run" if
            len(rows) > novel + repeats + failed else ""))
    for r in rows:
        start = (f"{r['index']:03d}  round {r['round'] + 1}  from evaluation {r['evaluation']} "
                 f"(strategy {r['strategy']})  ")
        if "novel" in r:
            what = (f"NOVEL: {r['distance']:.2f} rad from the nearest, {r['nearest']}"
                    if r["novel"] else f"repeats {r['nearest']} ({r['distance']:.2f} rad)")
            echo(start + f"{what}; up angle {r['feature']['up_angle']:.2f}, bar "
                         f"{r['highest_cleared']:.2f} m")
        else:
            echo(start + (f"failed: {r['reason']}" if r["outcome"] == "failure" else "not run"))
    return rows


def _write_json(path, value):
    write_text_atomic(Path(path), json.dumps(value, indent=2) + "\n")
