"""`takeoff sensitivity CONFIG`: a sensitivity study (`agents.sensitivity`) from a config's
`[sensitivity]` section, written as a table (`sensitivity.md`, `sensitivity.csv`) and a bar
chart of the elasticities (`sensitivity.png`), flagged gradients in red.

    [sensitivity]
    run = "runs/highjump"          # a trained run: its policy acts, held fixed …
    config = ""                    # … or a training config, driven open loop by `action`
    set = []                       # overrides of that config (as --set)
    action = 0.0                   # open loop: every action number (PD actions: joint targets)
    outcome = "apex_height"        # agents.sensitivity.OUTCOMES (tracking_error: imitation, runup)
    parameters = ["highjump.takeoff[3]", "physics.leg_length_scale", "physics.gravity_scale"]
    seconds = 1.0                  # rollout length
    fd_step = 1e-3                 # relative step of the central differences
    tolerance = 0.1                # relative disagreement that flags a gradient
    remat = true                   # rematerialise each control step in the backward pass
    scan_traversal = true          # tree passes as scans: the gradient compiles faster
"""

import copy
import dataclasses
import json
import resource
from dataclasses import dataclass, field
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from agents import config as config_io
from agents import sensitivity
from jaxsim.atomic import write_text_atomic


@dataclass(frozen=True)
class SensitivitySettings:
    run: str = ""
    config: str = ""
    set: tuple[str, ...] = ()
    action: float = 0.0
    outcome: str = "apex_height"
    parameters: tuple[str, ...] = ()
    seconds: float = 1.0
    fd_step: float = 1e-3
    tolerance: float = 0.1
    remat: bool = True
    scan_traversal: bool = True

    def __post_init__(self):
        if bool(self.run) == bool(self.config):
            raise ValueError("give one of run (a trained run directory) or config (a training "
                             "config, driven open loop)")
        if self.outcome not in sensitivity.OUTCOMES:
            raise ValueError(f"outcome must be one of {', '.join(sensitivity.OUTCOMES)}; got "
                             f"{self.outcome!r}")
        if not self.parameters:
            raise ValueError("parameters must name at least one parameter")
        config_io.check_positive(self, ("seconds", "fd_step", "tolerance"))


@dataclass(frozen=True)
class SensitivityConfig:
    """A sensitivity config file: its one section."""

    sensitivity: SensitivitySettings = field(default_factory=SensitivitySettings)


def run(config_path, out_dir=None, overrides=(), data_dir=None, echo=print):
    """Run the study of the config at `config_path`; returns the `sensitivity.Study`."""
    from agents.commands import train_commands
    from agents.rl import trainer as trainer_lib

    settings = config_io.load(config_path, SensitivityConfig, overrides).sensitivity
    section = ([] if not any(p.startswith("physics.") for p in settings.parameters)
               else ["physics.length_scale=1.0"])          # (kept if the config sets it)
    if settings.run:
        source = Path(settings.run) / train_commands.CONFIG
        config = train_commands.load_run_config(settings.run)
        if config.physics is not None:
            section = []
        config = train_commands.overridden(config, [*settings.set, *section], source)
    else:
        source = settings.config
        config = train_commands.load_config(settings.config, settings.set)
        if config.physics is None and section:
            config = train_commands.load_config(settings.config, [*settings.set, *section])
    trainer = train_commands.make_trainer(config, data_dir)
    if settings.run:
        state = trainer_lib.load_checkpoint(trainer.init(), settings.run, echo)
        curriculum, ppo, norm = state.curriculum, state.ppo, state.norm
        act = lambda obs: trainer.policy_apply(ppo.policy_params, norm.normalize(obs))
    else:
        curriculum = trainer.curriculum.init()
        act = lambda obs: jnp.full(trainer.env.action_size, settings.action, obs.dtype)
    env = trainer.env_for(curriculum)
    if settings.scan_traversal:                    # (the same physics; `Model.with_traversal`)
        env = copy.copy(env)
        env.model = env.model.with_traversal(False)
    params = trainer.curriculum.params(trainer.env_params, curriculum)
    try:
        parsed = {name: sensitivity.parse_name(name, config.run.task, params)
                  for name in settings.parameters}
    except ValueError as error:
        raise config_io.ConfigError(f"{config_path}: sensitivity.parameters: {error}") from None
    steps = max(1, int(round(settings.seconds / env.control_dt)))
    try:
        outcome_of = sensitivity.rollout_outcome(env, params, parsed, act, settings.outcome,
                                                 steps, settings.remat)
    except ValueError as error:
        raise config_io.ConfigError(f"{config_path}: sensitivity.outcome: {error}") from None
    substeps = getattr(env, "substeps", None)
    echo(f"{settings.outcome} of {steps} control steps"
         + (f" ({steps * substeps:,} substeps)" if substeps else "") + " "
         f"of {config.run.task} from {source}: gradient and central differences of "
         f"{len(parsed)} parameters…")
    result = sensitivity.study(outcome_of, sensitivity.start_values(params, parsed),
                               settings.fd_step, settings.tolerance)
    out = Path(out_dir or Path("runs") / Path(config_path).stem)
    out.mkdir(parents=True, exist_ok=True)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    table = report(result, settings, peak_rss)
    write_text_atomic(out / "sensitivity.md", table)
    write_text_atomic(out / "sensitivity.csv", _csv(result))
    write_text_atomic(out / "sensitivity.json", json.dumps(
        {"settings": dataclasses.asdict(settings), "outcome": result.outcome,
         "rows": [dataclasses.asdict(r) for r in result.rows], "seconds": result.seconds,
         "temp_bytes": result.temp_bytes, "peak_rss_bytes": peak_rss}, indent=1) + "\n")
    echo(table)
    chart = _chart(result, settings, out / "sensitivity.png")
    echo(f"wrote {out / 'sensitivity.md'}, sensitivity.csv, sensitivity.json"
         + (", sensitivity.png" if chart else ""))
    return result


def report(result, settings, peak_rss) -> str:
    lines = [f"# Sensitivity of {settings.outcome} = {result.outcome:.6g}", "",
             f"{settings.seconds:g} s rollout; central differences with step "
             f"{settings.fd_step:g}·max(|v|, 1); flagged (✗) where gradient and difference "
             f"differ by more than {settings.tolerance:g} of the larger.", "",
             "| parameter | value | gradient | finite difference | elasticity | agrees |",
             "|---|---:|---:|---:|---:|:---:|"]
    lines += [f"| {r.name} | {r.value:.6g} | {r.gradient:.6g} | {r.difference:.6g} | "
              f"{r.elasticity:.4g} | {'✓' if r.agrees else '✗'} |" for r in result.rows]
    s = result.seconds
    memory = (f"; XLA temporaries {result.temp_bytes / 2**20:,.0f} MiB"
              if result.temp_bytes is not None else "")
    lines += ["", f"Gradient: compile {s['compile']:.1f} s, run {s['gradient']:.2f} s; "
                  f"finite differences (compile included) {s['differences']:.1f} s; peak "
                  f"resident memory {peak_rss / 2**30:.2f} GiB{memory}."]
    return "\n".join(lines) + "\n"


def _csv(result) -> str:
    rows = ["parameter,value,gradient,finite_difference,elasticity,agrees"]
    rows += [f"{r.name},{r.value!r},{r.gradient!r},{r.difference!r},{r.elasticity!r},"
             f"{int(r.agrees)}" for r in result.rows]
    return "\n".join(rows) + "\n"


def _chart(result, settings, path):
    try:
        from jaxsim import render
        plt = render.pyplot()
    except ImportError:
        return None
    rows = result.rows[::-1]
    fig, ax = plt.subplots(figsize=(6.5, 0.45 * len(rows) + 1.4))
    values = [r.elasticity if np.isfinite(r.elasticity) else 0.0 for r in rows]
    ax.barh([r.name for r in rows], values,
            color=["tab:blue" if r.agrees else "tab:red" for r in rows])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel(f"elasticity: ∂ log {settings.outcome} / ∂ log parameter")
    ax.grid(axis="x", alpha=0.3)
    flagged = sum(not r.agrees for r in rows)
    render.save_figure(fig, path, dpi=110, title=f"sensitivity of {settings.outcome}"
                       + (f" ({flagged} in red: gradient ≠ finite difference)" if flagged
                          else " (every gradient agrees with its finite difference)"))
    return path
