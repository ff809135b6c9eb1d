"""Config-file sweeps (`takeoff sweep CONFIG`): every member of the config's `[sweep]` table
(`agents.sweep_spec`) run, and one row per member of its values and outcomes.

Two kinds, by what the table's `evaluate` says:

- **An evaluation sweep** (`evaluate = "RUN_DIR"`, a trained run): the run's deterministic
  policy, under the run's config with each member's values, for `episodes` episodes a member at
  the run's curriculum difficulty (or `difficulty`). Every swept key must be a task parameter —
  a `[physics]` factor or a key its task declares `vmappable` (the jump tasks: `gravity`,
  `takeoff`, `vertical_velocity`) — because all the members run as one compiled rollout of
  members × episodes environments, each with its own parameters: 256 body shapes are one call,
  not 256. Any other key (a network size, the solver) cannot change under a trained policy in
  one program and is refused, naming it.
- **A training sweep** (a training config with a `[sweep]` table): each member is a training
  run in `DIR/members/NNN` from the config with the member's values. When every swept key is
  `run.seed`, a task parameter or a PPO hyperparameter (`ppo.policy_lr`, `value_lr`, `clip`,
  `sigma_start`, `sigma_end`, `sigma_horizon`), `vmap` is not false and `run.devices` is 1,
  all the members train in one compiled program (`agents.rl.members`), checkpointed together
  in `DIR/members/`; else each is its own run through the executor (`workers` local
  processes, each pinned to its cores), and the sweep says why. A killed sweep resumes:
  members with a row are not run again, and a training goes on from its last checkpoint
  (`train_commands.train_or_resume`; the group's own checkpoint).

A sweep directory holds `sweep.json` (the members; a rerun must describe the same sweep),
`base.json` (a training sweep's config without its table), `sweep.jsonl` (a row per finished
member: `member`, the swept keys, the outcomes), and what `agents.sweep_report` makes of the
rows: `sweep.csv`, `sweep.md` and the plots.
"""

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agents import config as config_io
from agents import sweep_report, sweep_spec
from jaxsim import runlog
from jaxsim.atomic import hold_directory, write_text_atomic

PLAN, BASE, ROWS, MEMBERS = "sweep.json", "base.json", "sweep.jsonl", "members"


@dataclass(frozen=True)
class Sweep:
    """A sweep as read from its config: `members` ({key: value} each), `keys` (the swept keys,
    in the table's order), and the table's settings."""

    source: str
    members: list
    keys: tuple
    evaluate: str = ""          # a trained run: an evaluation sweep
    episodes: int = 1           # per member (evaluation)
    difficulty: float | None = None   # the bar / obstacle to evaluate at (default: the run's)
    workers: int = 1            # training members at once
    vmap: bool = True           # train the members in one program when they can be
    base: dict | None = None    # a training sweep's config, its [sweep] table taken out

    def plan(self) -> dict:
        """What makes a sweep this sweep (`sweep.json`): a rerun must agree on all of it (the
        config's path aside)."""
        return {"evaluate": self.evaluate, "episodes": self.episodes,
                "difficulty": self.difficulty, "vmap": self.vmap, "base": self.base,
                "keys": list(self.keys), "members": self.members}


def load(path, overrides=()) -> Sweep:
    """The sweep of the config file at `path` (with `--set` overrides applied to it); a
    ConfigError naming the file and key for a table or a member that cannot run."""
    data = config_io.read(path, overrides)
    table = data.pop("sweep", None)
    if table is None:
        raise config_io.ConfigError(f"{path}: no [sweep] table: it says which keys to sweep "
                                    "(see `takeoff sweep --help`)")
    members = sweep_spec.expand(table, path)
    keys = tuple(dict.fromkeys(k for member in members for k in member))
    settings = dict(evaluate=table.get("evaluate", ""), episodes=table.get("episodes", 1),
                    difficulty=table.get("difficulty"), workers=table.get("workers", 1),
                    vmap=table.get("vmap", True))
    _check_settings(settings, path)
    sweep = Sweep(str(path), members, keys, base=None if settings["evaluate"] else data,
                  **settings)
    _check_members(sweep, data, path)
    return sweep


def _check_settings(settings, path):
    if not isinstance(settings["evaluate"], str):
        raise config_io.ConfigError(f"{path}: sweep.evaluate must be a run directory (a "
                                    f"string); got {settings['evaluate']!r}")
    for name, most in (("episodes", config_io.MAX_INT), ("workers", config_io.MAX_INT)):
        value = settings[name]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
            raise config_io.ConfigError(f"{path}: sweep.{name} must be a whole number from 1 "
                                        f"to {most:,}; got {value!r}")
    if not isinstance(settings["vmap"], bool):
        raise config_io.ConfigError(f"{path}: sweep.vmap must be true or false; got "
                                    f"{settings['vmap']!r}")
    difficulty = settings["difficulty"]
    if difficulty is not None and (isinstance(difficulty, bool)
                                   or not isinstance(difficulty, (int, float))):
        raise config_io.ConfigError(f"{path}: sweep.difficulty must be a number; got "
                                    f"{difficulty!r}")


def _check_members(sweep: Sweep, data, path):
    """Every member's config built (so its types and ranges are checked); for an evaluation
    sweep, every key a task parameter."""
    from agents.commands import train_commands

    if not sweep.evaluate:
        for member in sweep.members:
            train_commands.build_config(_overridden(data, member, path), path)
        return
    if data:
        raise config_io.ConfigError(
            f"{path}: an evaluation sweep (sweep.evaluate = {sweep.evaluate!r}) runs that run's "
            f"config; this file may hold only [sweep], but it also has "
            f"[{', '.join(sorted(data))}]")
    config = train_commands.load_run_config(sweep.evaluate)
    allowed = vmappable_keys(config)
    for key in sweep.keys:
        if key not in allowed:
            raise config_io.ConfigError(
                f"{path}: sweep.{key} cannot be vmapped: an evaluation sweep runs every member "
                f"in one compiled call, so it sweeps task parameters only; for the task "
                f"{config.run.task!r} these are {', '.join(allowed)}")
    source = Path(sweep.evaluate) / train_commands.CONFIG
    for member in sweep.members:
        train_commands.overridden(config, sweep_spec.overrides(member), source)


def _overridden(data, member, path) -> dict:
    data = json.loads(json.dumps(data))
    for override in sweep_spec.overrides(member):
        config_io.apply_override(data, override, path)
    return data


def vmappable_keys(config) -> tuple[str, ...]:
    """The config keys of a training config that are task parameters of its environment."""
    from agents.tasks import physics
    entry = config.entry
    body_and_world = physics.names() if entry.takes_physics else ()
    return (*(f"physics.{name}" for name in body_and_world),
            *(f"{config.run.task}.{name}" for name in entry.vmappable))


def run(path, out_dir=None, overrides=(), data_dir=None, echo=print) -> Path:
    """Run the sweep of the config at `path` into `out_dir` (default runs/<config name>),
    going on where a killed run of the same sweep stopped; returns the directory."""
    sweep = load(path, overrides)
    out = Path(out_dir or Path("runs") / Path(path).stem)
    with hold_directory(out, "the sweep"):
        _claim(out, sweep)
        done = {row["member"] for row in rows_of(out, echo)}
        todo = [i for i in range(len(sweep.members)) if i not in done]
        kind = "evaluation" if sweep.evaluate else "training"
        echo(f"sweep of {len(sweep.members)} members ({kind}; {', '.join(sweep.keys)}) → {out}"
             + (f"; {len(done)} done before" if done else ""))
        if todo and sweep.evaluate:
            _evaluate(sweep, out, data_dir, echo)
        elif todo:
            _train(sweep, out, todo, data_dir, echo)
        rows = rows_of(out, echo)
        for name in sweep_report.write(out, sweep.keys, rows):
            echo(f"wrote {out / name}")
    return out


def _claim(out: Path, sweep: Sweep):
    """Write the sweep's plan in `out`, or check that the plan already there is this sweep's."""
    plan = json.loads(json.dumps(sweep.plan()))
    path = out / PLAN
    if path.exists():
        stored = config_io.read_stored(path)
        if stored != plan:
            raise config_io.ConfigError(
                f"{out} holds another sweep ({path} differs from what {sweep.source} makes); "
                "give another --out, or delete the directory to start it again")
        return
    out.mkdir(parents=True, exist_ok=True)
    if sweep.base is not None:
        write_text_atomic(out / BASE, json.dumps(sweep.base, indent=2) + "\n")
    write_text_atomic(path, json.dumps(plan, indent=1) + "\n")


def rows_of(out: Path, echo=print) -> list[dict]:
    """The rows of the members done (a torn last line, from a kill, set aside and said)."""
    log = runlog.read(out / ROWS)
    note = runlog.repair(log) if not log.intact else ""
    if note:
        echo(f"warning: {note}")
    return log.records


def _row(index, member, outcomes) -> dict:
    clean = {k: (None if v is None or not np.isfinite(v) else float(v))
             for k, v in outcomes.items()}
    return {"member": index, **member, **clean}


def member_params(sweep: Sweep, keys_to_values, params):
    """`params` (task parameters, one set per environment) with each swept key's column
    (members × episodes rows) in place: a `physics.` key's factor or the task key of the same
    name."""
    import jax.numpy as jnp
    params = dict(params)
    for key, column in keys_to_values.items():
        section, name = key.split(".", 1)
        if section == "physics":
            params["physics"] = {**params["physics"],
                                 name: jnp.asarray(column, params["physics"][name].dtype)}
        else:
            current = params[name]
            column = jnp.asarray(column, current.dtype)
            if column.shape != current.shape:
                raise config_io.ConfigError(
                    f"{sweep.source}: sweep.{key}: each value must have the shape "
                    f"{tuple(current.shape[1:])} of the task parameter; got "
                    f"{tuple(column.shape[1:])}")
            params[name] = column
    return params


def _evaluate(sweep: Sweep, out: Path, data_dir, echo):
    """Every member in one rollout of members × episodes environments."""
    from agents.commands import train_commands

    count, episodes = len(sweep.members), sweep.episodes
    columns = {key: np.repeat(np.asarray([member[key] for member in sweep.members], float),
                              episodes, axis=0) for key in sweep.keys}
    config = train_commands.load_run_config(sweep.evaluate)
    section = ([] if config.physics is not None or not any(k.startswith("physics.")
                                                            for k in sweep.keys)
               else ["physics.length_scale=1.0"])     # the section, all its factors at 1
    started = time.perf_counter()
    measured = train_commands.run_episodes(
        sweep.evaluate, count * episodes, data_dir, difficulty=sweep.difficulty,
        echo=lambda *_: None, overrides=section,
        vary=lambda params: member_params(sweep, columns, params))
    echo(f"evaluated {count} members × {episodes} episodes in one call: "
         f"{time.perf_counter() - started:.1f} s (compile included)")
    per_member = {name.removeprefix("episode/"): np.asarray(values, float).reshape(
        count, episodes) for name, values in measured.outcomes.items()}
    with np.errstate(invalid="ignore"):
        means = {name: np.nanmean(values, axis=1) if np.isfinite(values).any() else
                 np.full(count, np.nan) for name, values in per_member.items()}
    for index, member in enumerate(sweep.members):
        runlog.append(out / ROWS, _row(index, member,
                                       {k: v[index] for k, v in means.items()}))


def why_not_one_program(sweep: Sweep) -> str | None:
    """Why the training sweep's members cannot train in one program, or None when they can:
    `vmap` not false, on one device, every swept key the seed, a task parameter or a PPO
    hyperparameter."""
    from agents.commands import train_commands
    config = train_commands.build_config(_with_physics(sweep), sweep.source)
    allowed = {"run.seed", *vmappable_keys(config), *_hyperparameter_keys()}
    others = [k for k in sweep.keys if k not in allowed]
    if not sweep.vmap:
        return "the sweep says vmap = false"
    if config.run.devices != 1:
        return (f"run.devices is {config.run.devices}, and members share one program on one "
                f"device only (--set run.devices=1 for that)")
    if others:
        return (f"{', '.join(others)} cannot differ between the members of one program (the "
                f"seed, task parameters and {', '.join(_hyperparameter_keys())} can)")
    return None


def _hyperparameter_keys():
    from agents.rl.ppo import HYPERPARAMETERS
    return tuple(f"ppo.{name}" for name in HYPERPARAMETERS)


def _with_physics(sweep: Sweep) -> dict:
    """The training sweep's base config, with a `[physics]` section (its factors at 1) when a
    physics key is swept and it has none."""
    data = json.loads(json.dumps(sweep.base))
    if any(k.startswith("physics.") for k in sweep.keys):
        data.setdefault("physics", {})
    return data


def _train_together(sweep: Sweep, out: Path, todo, data_dir, echo):
    """Every member in one program (`agents.rl.members`); rows for those of `todo`."""
    import jax
    import jax.numpy as jnp

    from agents.commands import train_commands
    from agents.rl import members as members_lib

    data = _with_physics(sweep)
    config = train_commands.build_config(data, sweep.source)
    trainer = train_commands.make_trainer(config, data_dir)
    count = len(sweep.members)
    seeds = [member.get("run.seed", config.run.seed) for member in sweep.members]
    hyper_keys = _hyperparameter_keys()
    columns = {k: np.asarray([m[k] for m in sweep.members], float)
               for k in sweep.keys if k != "run.seed" and k not in hyper_keys}
    hyper = None
    if any(k in hyper_keys for k in sweep.keys):
        hyper = {k.removeprefix("ppo."): jnp.asarray(
            [m.get(k, getattr(config.ppo, k.removeprefix("ppo."))) for m in sweep.members],
            jnp.float32) for k in hyper_keys}
    env_params = None
    if columns:
        stacked = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (count, *jnp.shape(x))),
                                         trainer.env_params)
        env_params = member_params(sweep, columns, stacked)
    configs = [train_commands.build_config(_overridden(data, member, sweep.source),
                                           sweep.source).sections() for member in sweep.members]
    directories = [out / MEMBERS / f"{i:03d}" for i in range(count)]
    echo(f"training {count} members in one program: {config.run.envs} environments × "
         f"{config.run.steps_per_iteration} steps each, {config.run.iterations} iterations")
    members_lib.train(members_lib.MemberTraining(trainer, seeds, env_params, hyper),
                      json.loads(json.dumps(configs)), directories, out / MEMBERS, echo)
    for index in todo:
        runlog.append(out / ROWS, _row(index, sweep.members[index],
                                       last_metrics(directories[index])), sync=True)


def _train(sweep: Sweep, out: Path, todo, data_dir, echo):
    """The members not done: in one program when they can be, else each a training run,
    `workers` at once through the executor."""
    from jaxsim import executor as executor_lib

    why_not = why_not_one_program(sweep)
    if why_not is None:
        return _train_together(sweep, out, todo, data_dir, echo)
    echo(f"training each member as its own run: {why_not}")

    jobs = [(str(out / BASE), sweep_spec.overrides(sweep.members[i]),
             str(out / MEMBERS / f"{i:03d}"), None if data_dir is None else str(data_dir))
            for i in todo]
    pool = (executor_lib.InProcess() if sweep.workers == 1
            else executor_lib.LocalProcesses(sweep.workers))
    with pool:
        for job, outcomes in pool.map_unordered(train_member, jobs):
            index = todo[job]
            runlog.append(out / ROWS, _row(index, sweep.members[index], outcomes), sync=True)
            echo(f"member {index:03d} done: " + ", ".join(
                f"{k} {v:.4g}" for k, v in outcomes.items() if k in SHOWN and v is not None))


SHOWN = ("return", "episode_length", "curriculum/difficulty")


def train_member(config_path, overrides, run_dir, data_dir) -> dict:
    """Train (or resume) one member; its outcomes are its last iteration's metrics (numbers)."""
    from agents.commands import train_commands

    train_commands.train_or_resume(config_path, run_dir, overrides, data_dir,
                                   echo=lambda *_: None)
    return last_metrics(run_dir)


def last_metrics(run_dir) -> dict:
    """The numbers of a run's last metrics record."""
    from agents.rl import trainer as trainer_lib
    last = trainer_lib.last_record(run_dir)
    return {k: v for k, v in last.items() if isinstance(v, (int, float))
            and not isinstance(v, bool)}

