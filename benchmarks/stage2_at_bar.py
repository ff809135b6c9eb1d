"""Is Stage 2 novel when it warm-starts from a policy trained to a lower bar than 1.0 m?

At 1.0 m no Stage-2 round of the third high-jump search was novel (docs/discovery), while from
0.6 m policies four rounds in five were. A z_freeze below 1.0 m is allowed where the Stage-1
feature has settled (§3.6.1; docs/discovery, "Had the feature settled at 0.57 m?": from 0.7 m on
it had), so this asks whether Stage 2 works from policies at such a bar. It takes a training run
measured at a bar by `benchmarks/feature_settling.py` (OUT/NNN/bar_H.HH/result.json), copies its
checkpoint as it stood then (the settling run trains on past it), and runs one Stage-2 round
from it as `takeoff stage2` builds one (`stage2_search.stage2_sections`: the Stage-1 run's
settings, its exploration σ going on or a constant `--sigma`, r_novelty of eq. 3.12 against
`known`), then measures it as the search measures an evaluation. `known` is every
`bar_H.HH/result.json` of the same height in the settling directories given: the Stage-1
policies at that bar, the start's own crossing among them.

Run (alone on the machine; it is a training):
    python benchmarks/stage2_at_bar.py runs/settling/003/bar_0.70 --known runs/settling \
        docs/discovery/settling --iterations 400 --out runs/stage2_at_0.70/003 \
        --data-dir ../shared/data [--filmstrip runs/stage2_at_0.70/003/filmstrip.png]
Killed, it is run again with the same arguments: the round resumes from its checkpoint. Run
again with more --iterations (or a higher --stop-bar), the finished round trains on and is
measured again. With the novelty reward saturated the curriculum raises the bar as in Stage 1,
so `--stop-bar 1.0 --iterations 3000` trains a round on until it clears 1.0 m.
"""

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from agents.commands import stage2_search, train_commands
from agents.discovery import jump_black_box, stage2
from agents.rl import trainer as trainer_lib
from bds.acquisition import rotation_geodesic
from jaxsim.atomic import write_text_atomic

SNAPSHOT = "start"          # OUT/start: the settling run's checkpoint at the bar


def known_at(bar_name: str, roots) -> list[tuple[str, list[float]]]:
    """(name, crossing rotation vector) of every successful result at the bar `bar_name`
    (e.g. "bar_0.70") under the settling directories `roots`."""
    found = []
    for root in roots:
        for path in sorted(Path(root).glob(f"*/{bar_name}/{jump_black_box.RESULT}")):
            result = jump_black_box.read_result(path.parent)
            if result and result["outcome"] == "success":
                found.append((f"{path.parent.parent.name} at {bar_name[4:]} m ({root})",
                              [float(v) for v in result["feature"]["cross_rotvec"]]))
    return found


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("start", type=Path, help="a settling run's OUT/NNN/bar_H.HH directory")
    parser.add_argument("--known", type=Path, nargs="+", required=True,
                        help="settling directories whose results at the same bar are known")
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--sigma", type=float, default=None)
    parser.add_argument("--stop-bar", type=float, default=0.0,
                        help="stop the round when its curriculum's bar reaches this (m; 0: none)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--filmstrip", type=Path, default=None,
                        help="also draw the start's and the round's episodes into this PNG")
    args = parser.parse_args(argv)

    start_result = jump_black_box.read_result(args.start)
    if start_result is None or start_result["outcome"] != "success":
        raise SystemExit(f"{args.start}: no successful measurement to start from")
    snapshot = args.out / SNAPSHOT
    if not trainer_lib.has_checkpoint(snapshot):
        # The settling run's checkpoint when it was measured at this bar: copied right after
        # the measurement, before the settling run trains on (see the docstring).
        source = args.start.parent / jump_black_box.TRAIN
        shutil.copytree(source, snapshot, dirs_exist_ok=True)
    reached = trainer_lib.read_metrics(snapshot)[-1].get(trainer_lib.DIFFICULTY)
    if abs(reached - start_result["evaluated_at"]) > 2 * jump_black_box.DIFFICULTY_TOLERANCE:
        raise SystemExit(f"{snapshot}: its checkpoint is at bar {reached:.2f} m, not the "
                         f"{start_result['evaluated_at']:.2f} m measured in {args.start}: the "
                         "settling run has trained on; copy it at that bar")
    config_path, run_dir = args.out / stage2.RUN_CONFIG, args.out / jump_black_box.TRAIN
    if not config_path.exists():
        # The known set is decided once, as `takeoff stage2` decides a round's, and kept in
        # known.json beside the config: a rerun is judged against what the round trained against.
        known = known_at(args.start.name, args.known)
        write_text_atomic(args.out / stage2.KNOWN, json.dumps(
            [{"policy": name, "cross_rotvec": feature} for name, feature in known]))
        sections = stage2_search.stage2_sections(snapshot, [f for _, f in known],
                                                 args.iterations, args.sigma)
        write_text_atomic(config_path, "# Stage 2 from a policy at a lower bar "
                          "(benchmarks/stage2_at_bar.py)\n" + stage2_search.to_toml(sections))
    say = lambda text="": print(f"  [stage2 at {args.start.name[4:]} m] {text}", flush=True)
    # The round's own length and stop, from the command line: given more on a rerun, a
    # finished round trains on; given the same, it is only measured again.
    length = [f"run.iterations={args.iterations}", f"run.stop_difficulty={args.stop_bar}"]
    finished = lambda config, last: (last.get("iteration", 0) >= args.iterations
                                     or trainer_lib.reached(last, args.stop_bar))
    train_commands.train_or_resume(config_path, run_dir, length, args.data_dir, say, finished,
                                   lambda config, last: length)
    result = jump_black_box.measure(args.out, run_dir, args.episodes, args.data_dir,
                                    x=start_result["x"], stage=2, start=str(args.start))
    if result["outcome"] != "success":
        print(f"the round FAILED: {result['reason']}")
        return
    verdict = stage2.round_verdict(args.out, result)         # eq. 3.12, as `takeoff stage2`
    print(f"the round clears {result['highest_cleared']:.2f} m, up angle "
          f"{result['feature']['up_angle']:.3f} rad; {'NOVEL' if verdict['novel'] else 'a repeat'}"
          f": nearest {verdict['nearest']}, {verdict['distance']:.2f} rad (π/2 = "
          f"{verdict['threshold']:.2f})")
    known = json.loads((args.out / stage2.KNOWN).read_text())
    gaps = rotation_geodesic(np.asarray(result["feature"]["cross_rotvec"], np.float32),
                             np.asarray([k["cross_rotvec"] for k in known], np.float32))
    for policy, gap in zip(known, np.asarray(gaps)):
        print(f"  {gap:.2f} rad from {policy['policy']}")
    if args.filmstrip:
        from feature_settling import filmstrip_sheet        # (benchmarks/, the script's folder)
        bar = args.start.name[4:]
        filmstrip_sheet([(f"the start, at {bar} m", args.start, snapshot),
                         (f"Stage 2 from it, {result['iterations']} iterations", args.out,
                          run_dir)], args.filmstrip)


if __name__ == "__main__":
    main()
