"""The `takeoff` command line. Subcommands arrive with the parts they drive."""

import argparse
import os
import sys
import traceback
import warnings

from jaxsim import allocator
from jaxsim.atomic import write_text_atomic


def _load_character(spec: str):
    """A built-in character name (`humanoid`, `quadruped`, `snake:N`) or a DeepMimic file."""
    from jaxsim import characters

    from jaxsim.model import ModelError

    name, colon, arg = spec.partition(":")
    if name == "snake" and colon:
        if not arg.isdigit() or int(arg) < 1:
            raise SystemExit(f"takeoff: bad character {spec!r}: snake:N needs a positive whole "
                             "number of links")
        return characters.snake(int(arg))
    if name in characters.BUILTIN and not colon:
        return characters.BUILTIN[name]()
    if os.path.isdir(spec):
        raise SystemExit(f"takeoff: {spec} is a directory; give a DeepMimic character file")
    if os.path.exists(spec):
        try:
            return characters.load_deepmimic(spec)
        except ModelError as error:
            raise SystemExit(f"takeoff: {error}")
    raise SystemExit(f"takeoff: unknown character {spec!r}: give one of "
                     f"{', '.join(characters.BUILTIN)} (snake:N for N links) or a DeepMimic "
                     "character file")


def _cmd_characters(args):
    from jaxsim import characters

    specs = args.character or ["humanoid", "quadruped", "snake:10", "snake:22", "snake:63"]
    print(f"{'character':<24}{'links':>6}{'nq':>6}{'DoF':>6}{'path DoF':>10}{'mass kg':>9}"
          f"{'height m':>10}")
    for spec in specs:
        model = _load_character(spec)
        low, high = characters.vertical_extent(model)
        print(f"{os.path.basename(spec):<24}{model.n_links:>6}{model.nq:>6}{model.nv:>6}"
              f"{model.topology.max_path_dofs:>10}{float(model.mass.sum()):>9.2f}"
              f"{high - low:>10.3f}")


def _cmd_mjcf(args):
    from jaxsim import to_mjcf

    model = _load_character(args.character)
    xml = to_mjcf(model, name=os.path.basename(args.character).split(".")[0].replace(":", "_"))
    if args.out is None:
        print(xml)
        return
    write_text_atomic(args.out, xml)
    print(f"wrote {args.out}")


def _cmd_search(args):
    from agents.commands import strategy_search
    from agents.config import ConfigError
    from jaxsim.executor import ExecutorError
    from bds.search import SearchError
    from jaxsim.atomic import OutputError
    from jaxsim.runlog import LogError

    try:
        strategy_search.run(args.config, args.out, args.set, args.workers,
                            data_dir=args.data_dir)
    except (ConfigError, SearchError, OutputError, LogError, ExecutorError) as error:
        raise SystemExit(f"takeoff search: {error}")
    except KeyboardInterrupt:
        raise SystemExit(130)


def _cmd_pvae_dataset(args):
    from agents.commands import pvae_commands
    from agents.datadir import DataDirError, data_dir_from
    from agents.pose.pose_dataset import DatasetError
    from jaxsim.atomic import OutputError
    from jaxsim.motion import MotionFileError

    try:
        pvae_commands.build_dataset(data_dir_from(args.data_dir), args.out)
    except (DataDirError, DatasetError, MotionFileError, OutputError) as error:
        raise SystemExit(f"takeoff pvae dataset: {error}")


def _cmd_pvae_train(args):
    from agents.commands import pvae_commands
    from agents.config import ConfigError
    from agents.pose.pose_dataset import DatasetError
    from jaxsim.atomic import OutputError

    try:
        pvae_commands.train(args.config, args.out, args.set)
    except (ConfigError, DatasetError, OutputError) as error:
        raise SystemExit(f"takeoff pvae train: {error}")


def run_errors():
    """The errors of a training or evaluation run that are the user's to fix: a config, data
    or run directory that cannot be used, or a run that went non-finite (a tuple for `except`;
    the benchmark scripts that drive runs catch them too)."""
    from agents.checkpoint import CheckpointError
    from agents.config import ConfigError
    from agents.datadir import DataDirError
    from agents.rl.trainer import TrainingError
    from jaxsim.atomic import OutputError
    from jaxsim.model import ModelError
    from jaxsim.motion import MotionFileError
    from jaxsim.runlog import LogError

    return (ConfigError, DataDirError, CheckpointError, TrainingError, ModelError,
            MotionFileError, OutputError, LogError)


def _cmd_train(args):
    if (args.config is None) == (args.resume is None):
        raise SystemExit("takeoff train: give a CONFIG to start a run or --resume DIR, not both")
    cluster = _cluster(args)
    if args.processes > 1:
        from agents.commands import launch          # (the launcher imports no JAX)
        raise SystemExit(launch.launch(_train_args(args), args.processes))
    from agents.commands import train_commands
    from agents.rl import parallel

    try:
        train_commands.train(args.config, args.out, args.set, args.resume, args.data_dir,
                             cluster=cluster)
    except run_errors() as error:
        _leave(cluster, f"takeoff train{parallel.process_label()}: {error}")
    except KeyboardInterrupt:
        raise SystemExit(130)
    except Exception:
        if cluster is None:
            raise
        traceback.print_exc()
        _leave(cluster, f"takeoff train{parallel.process_label()}: failed (above)")


def _leave(cluster, message):
    """A SystemExit with `message`; a process of a multi-process run says it and leaves at
    once, rather than wait at JAX's shutdown barrier for processes that will not come there
    (its launcher, or the cluster's runtime, ends them)."""
    if cluster is None:
        raise SystemExit(message)
    print(message, file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(1)


def _train_args(args) -> list:
    """The arguments of `takeoff train` that say what to train (for each launched process)."""
    words = [args.config] if args.config is not None else ["--resume", args.resume]
    for flag, value in (("--out", args.out), ("--data-dir", args.data_dir)):
        if value is not None:
            words += [flag, value]
    for override in args.set:
        words += ["--set", override]
    return words


def _cluster(args):
    """The multi-process run this process joins (None: none) from --coordinator,
    --num-processes and --process-id; a SystemExit for flags that do not go together."""
    given = [flag for flag, value in (("--num-processes", args.num_processes),
                                      ("--process-id", args.process_id)) if value is not None]
    if args.coordinator is None:
        if given:
            raise SystemExit(f"takeoff train: {given[0]} goes with --coordinator HOST:PORT")
        return None
    if args.processes > 1:
        raise SystemExit("takeoff train: --processes starts a run's processes on this host, "
                         "--coordinator joins a run as one of them; give one or the other")
    from agents.rl.parallel import Cluster

    if args.coordinator == "auto":
        if given:
            raise SystemExit(f"takeoff train: with --coordinator auto the cluster's environment "
                             f"gives the processes and their indices; drop {' and '.join(given)}")
        return Cluster()
    host, colon, port = args.coordinator.rpartition(":")
    if not (colon and host and port.isdigit()):
        raise SystemExit(f"takeoff train: --coordinator must be HOST:PORT or auto; got "
                         f"{args.coordinator!r}")
    if len(given) < 2:
        raise SystemExit("takeoff train: --coordinator HOST:PORT needs --num-processes N and "
                         "--process-id I")
    if not 0 <= args.process_id < args.num_processes:
        raise SystemExit(f"takeoff train: --process-id must be 0 … {args.num_processes - 1} "
                         f"with --num-processes {args.num_processes}; got {args.process_id}")
    return Cluster(args.coordinator, args.num_processes, args.process_id)


def _cmd_eval(args):
    from agents.commands import train_commands

    try:
        train_commands.evaluate(args.run_dir, args.episodes, args.render, args.data_dir)
    except run_errors() as error:
        raise SystemExit(f"takeoff eval: {error}")


def _cmd_sweep(args):
    from agents import sweep
    from jaxsim.executor import ExecutorError

    try:
        sweep.run(args.config, args.out, args.set, args.data_dir)
    except (*run_errors(), ExecutorError) as error:
        raise SystemExit(f"takeoff sweep: {error}")
    except KeyboardInterrupt:
        raise SystemExit(130)


def _cmd_sensitivity(args):
    from agents.commands import sensitivity_command

    try:
        sensitivity_command.run(args.config, args.out, args.set, args.data_dir)
    except run_errors() as error:
        raise SystemExit(f"takeoff sensitivity: {error}")


def _cmd_plot(args):
    from agents.commands import train_commands

    try:
        path = train_commands.plot(args.run_dir)
    except run_errors() as error:
        raise SystemExit(f"takeoff plot: {error}")
    if path is None:
        raise SystemExit(f"takeoff plot: {args.run_dir} has no metrics yet")
    print(f"wrote {path}")


def _cmd_motion(args):
    from agents.commands import motion_commands

    try:
        motion_commands.full_motion(args.runup_dir, args.jump_dir, args.out, args.data_dir,
                                    args.fps, args.seed, bar=args.bar)
    except run_errors() as error:
        raise SystemExit(f"takeoff motion: {error}")


def _cmd_gallery(args):
    from agents.discovery import gallery

    try:
        path = gallery.write_gallery(args.search_dir, args.out, args.data_dir,
                                     redraw=args.redraw, stage2_dirs=args.stage2)
    except gallery.errors() as error:
        raise SystemExit(f"takeoff gallery: {error}")
    print(f"wrote {path}")


def _cmd_stage2(args):
    from agents.commands import stage2_search
    from bds.search import SearchError

    try:
        stage2_search.run(args.search_dir, args.iterations, args.rounds, args.out, args.data_dir,
                          sigma=args.sigma)
    except (*run_errors(), SearchError) as error:
        raise SystemExit(f"takeoff stage2: {error}")
    except KeyboardInterrupt:
        raise SystemExit(130)


def _positive_int(text):
    """An argparse type: a whole number ≥ 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number ≥ 1; got {text!r}")
    return value


def _positive_float(text):
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0; got {text!r}")
    return value


def _gif_path(text):
    """An argparse type: a path ending in .gif, the only animation format `render` writes."""
    if not text.lower().endswith(".gif"):
        raise argparse.ArgumentTypeError(f"the animation is written as a GIF; got {text!r}, "
                                         "use a name ending in .gif")
    return text


DATA_DIR_HELP = ("reference data directory (default: $TAKEOFF_DATA, else ../shared/data beside "
                 "the checkout)")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="takeoff", description="Batched, differentiable character simulation in JAX.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("characters", help="list characters with their links, DoF and mass")
    p.add_argument("character", nargs="*",
                   help="humanoid, quadruped, snake:N or a DeepMimic character file")
    p.set_defaults(run=_cmd_characters)
    p = sub.add_parser("mjcf", help="export a character as MuJoCo MJCF XML")
    p.add_argument("character", help="humanoid, quadruped, snake:N or a DeepMimic character file")
    p.add_argument("--out", help="output file (default: print to standard output)")
    p.set_defaults(run=_cmd_mjcf)
    p = sub.add_parser("search", help="Bayesian Diversity Search (or random search) for diverse "
                                      "strategies of a black box named in a config")
    p.add_argument("config", help="TOML config, e.g. configs/search_landscape.toml")
    p.add_argument("--out", help="run directory (default runs/<config name>); an existing one "
                                 "is resumed")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a config value (repeatable)")
    p.add_argument("--workers", type=_positive_int,
                   help="evaluate a round's points in this many worker processes at once (or "
                        "Ray tasks, with [executor] backend = \"ray\"); overrides the config's "
                        "executor.workers")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_search)
    p = sub.add_parser("stage2", help="Stage 2 of strategy discovery: novel policy seeking from "
                                      "every Stage-1 strategy of a jump search (rerun: resumes)")
    p.add_argument("search_dir", help="the directory of a `takeoff search` of a jump task")
    p.add_argument("--iterations", type=_positive_int, help="PPO iterations per round (default: "
                   "a third of one Stage-1 evaluation's samples)")
    p.add_argument("--rounds", type=_positive_int, help="rounds of novel policy search per "
                   "strategy (default 5, the thesis's five; more than a resumed Stage 2's adds "
                   "rounds after its own)")
    p.add_argument("--sigma", type=_positive_float, help="explore every round with this "
                   "constant σ (default: go on with the Stage-1 policy's annealed σ)")
    p.add_argument("--out", help="where the rounds go (default SEARCH_DIR/stage2)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_stage2)
    p = sub.add_parser("pvae", help="the pose VAE: build its dataset from motion capture, train it")
    pvae_sub = p.add_subparsers(dest="pvae_command", metavar="STEP", required=True)
    q = pvae_sub.add_parser("dataset", help="retarget CMU 01-03 and DeepMimic clips to the "
                                            "humanoid and save 30 Hz pose features")
    q.add_argument("--data-dir", help=DATA_DIR_HELP)
    q.add_argument("--out", default="poses.npz", help="dataset file (default poses.npz)")
    q.set_defaults(run=_cmd_pvae_dataset)
    q = pvae_sub.add_parser("train", help="train a P-VAE from a config, e.g. configs/pvae.toml")
    q.add_argument("config", help="TOML config")
    q.add_argument("--out", help="run directory (default runs/<config name>)")
    q.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a config value (repeatable)")
    q.set_defaults(run=_cmd_pvae_train)
    p = sub.add_parser("train", help="train a policy with PPO from a config, or resume a run")
    p.add_argument("config", nargs="?", help="TOML config, e.g. configs/imitate_walk.toml")
    p.add_argument("--out", help="run directory (default runs/<config name>)")
    p.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a config value (repeatable)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.add_argument("--processes", type=_positive_int, default=1, metavar="N",
                   help="train as N processes of one run on this host (jax.distributed), the "
                        "environments split over them")
    p.add_argument("--coordinator", metavar="HOST:PORT",
                   help="join a multi-process run as one of its processes (one per machine): "
                        "where process 0 listens; auto: as the cluster's environment says "
                        "(SLURM, Open MPI, …)")
    p.add_argument("--num-processes", type=_positive_int, metavar="N",
                   help="with --coordinator HOST:PORT: the run's number of processes")
    p.add_argument("--process-id", type=int, metavar="I",
                   help="with --coordinator HOST:PORT: this process's index, 0 … N−1 (process 0 "
                        "writes the run directory)")
    p.set_defaults(run=_cmd_train)
    p = sub.add_parser("eval", help="run a trained policy deterministically and report")
    p.add_argument("run_dir", help="a run directory from takeoff train")
    p.add_argument("--episodes", type=_positive_int, default=8,
                   help="how many episodes to run (default 8)")
    p.add_argument("--render", metavar="OUT.gif", type=_gif_path,
                   help="also write an animation of episode 0")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_eval)
    p = sub.add_parser("sweep", help="run every member of a config's [sweep] table: a trained "
                                     "policy evaluated over task parameters in one call, or "
                                     "one training per member (rerun: resumes)")
    p.add_argument("config", help="a config with a [sweep] table, e.g. "
                                  "configs/sweep_highjump_body.toml")
    p.add_argument("--out", help="sweep directory (default runs/<config name>); an existing one "
                                 "of the same sweep is resumed")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a config value (repeatable)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_sweep)
    p = sub.add_parser("sensitivity", help="the gradient of a rollout's outcome with respect "
                                           "to named parameters, beside finite differences")
    p.add_argument("config", help="a config with a [sensitivity] section, e.g. "
                                  "configs/sensitivity_highjump.toml")
    p.add_argument("--out", help="where to write the table and chart (default "
                                 "runs/<config name>)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a config value (repeatable)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_sensitivity)
    p = sub.add_parser("motion", help="a run-up policy and a jump policy as one full motion: "
                                      "GIF, filmstrip, BVH and summary.json")
    p.add_argument("runup_dir", help="a run directory of the runup task")
    p.add_argument("jump_dir", help="a highjump or obstacle run directory of the same take-off x")
    p.add_argument("--out", required=True, metavar="DIR", help="where to write the motion")
    p.add_argument("--fps", type=float, help="frames per second of the GIF and BVH (default: "
                                             "the run-up's control rate)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the rollout (default 0)")
    p.add_argument("--bar", type=float, metavar="Z", help="the jump's bar height (obstacle: "
                                                          "width) in m (default: its run's)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_motion)
    p = sub.add_parser("gallery", help="one HTML page (and a PNG contact sheet) of a strategy "
                                       "search's evaluations and strategies")
    p.add_argument("search_dir", help="the run directory of a `takeoff search`")
    p.add_argument("--out", metavar="DIR", help="where to write gallery.html and gallery/ "
                                                "(default: the search directory)")
    p.add_argument("--redraw", action="store_true",
                   help="draw every picture again (by default one newer than its episode is kept)")
    p.add_argument("--stage2", metavar="DIR", action="append", default=[],
                   help="also show the rounds of this `takeoff stage2 --out DIR` directory, in a "
                        "section of their own (repeatable; SEARCH/stage2 is always shown)")
    p.add_argument("--data-dir", help=DATA_DIR_HELP)
    p.set_defaults(run=_cmd_gallery)
    p = sub.add_parser("plot", help="draw a run's learning curve (learning_curve.png)")
    p.add_argument("run_dir")
    p.set_defaults(run=_cmd_plot)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A log set right (`jaxsim.runlog.LogWarning`) as one line for the user, without a source
    location; any other warning as Python shows it."""
    from jaxsim.runlog import LogWarning

    if issubclass(category, LogWarning):
        print(f"takeoff: warning: {message}", file=file or sys.stderr)
    else:
        _PYTHON_SHOWWARNING(message, category, filename, lineno, file, line)


_PYTHON_SHOWWARNING = warnings.showwarning


def main(argv=None):
    warnings.showwarning = _show_warning
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    args.run(args)
    return 0


def command_line():
    """The `takeoff` executable: restart with the malloc tunables (jaxsim.allocator), then run,
    its output written line by line (an hour-long search or Stage 2 run with `nohup … > log`
    shows its progress in the log as it goes, not a block at a time)."""
    allocator.restart_with_tunables()
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(line_buffering=True)
    return main()


if __name__ == "__main__":
    sys.exit(command_line())
