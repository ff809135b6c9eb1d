"""Sensitivity studies (`takeoff sensitivity CONFIG`): how a rollout's scalar outcome changes
with named task parameters, by `jax.grad` through the whole rollout, each gradient beside a
central finite difference of the same outcome so a gradient that contact has made unreliable is
flagged rather than trusted.

`study(outcome_of, values)` is the method for any scalar function of named scalars; `rollout_
outcome` builds that function from an environment: `seconds` of control steps from the reset
(no episode ends it: the simulation runs on), the actions those of a trained policy held fixed
(its mean, the run's observation statistics) or an open-loop constant, each control step
rematerialised in the backward pass (`jax.checkpoint`), so the memory the gradient needs grows
with the control steps' states, not with every substep's intermediates.

Outcomes (`OUTCOMES`): `apex_height`, the highest the centre of mass gets (the jump tasks track
it every substep; other tasks at control steps); `clearance`, a jump's centre of mass over the
bar where it crosses the bar's plane (0 when it never does); `final_root_height`; `travel`, the
root's horizontal distance from where it started; `return`, the sum of the rewards;
`tracking_error`, the mean over the control steps of the joint angles' error to the reference
clip in degrees (the imitation and run-up tasks' `pose_error_degrees`).

Parameters are named as config keys: `physics.<factor>` (`agents.tasks.physics`), or a task
parameter `<task>.<name>` with `[i]` for one number of a vector (`highjump.takeoff[3]`, the
take-off v_z; `highjump.gravity[1]`).

Each result row: the value, the gradient, the central difference (f(v + h) − f(v − h)) / 2h with
h = `fd_step`·max(|v|, 1), the elasticity ∂log outcome / ∂log parameter = gradient · v /
outcome, and whether gradient and difference agree within `tolerance` relative to the larger of
the two (or within `FLOOR`·(1 + |outcome|)/max(|v|, 1), an elasticity too small to matter).
"""

import math
import re
import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

FLOOR = 1e-4
OUTCOMES = ("apex_height", "clearance", "final_root_height", "travel", "return",
            "tracking_error")
TRACKING_METRIC = "pose_error_degrees"
_NAME = re.compile(r"^([A-Za-z_][\w]*)\.([A-Za-z_]\w*)(?:\[(\d+)\])?$")


@dataclass(frozen=True)
class Row:
    name: str
    value: float
    gradient: float
    difference: float          # the central finite difference
    elasticity: float
    agrees: bool


@dataclass(frozen=True)
class Study:
    outcome: float
    rows: list                 # Row, sorted by |elasticity|, largest first
    seconds: dict              # compile (gradient), gradient run, finite differences
    temp_bytes: int | None     # XLA's temporary buffers of the compiled gradient


def study(outcome_of, values: dict, fd_step=1e-3, tolerance=0.1) -> Study:
    """The gradient of `outcome_of(values)` (a traceable scalar function of a dict of named
    scalars) at `values`, beside central differences, one row per name (module docstring)."""
    names = list(values)
    point = {k: jnp.asarray(v) for k, v in values.items()}
    started = time.perf_counter()
    gradient_fn = jax.jit(jax.value_and_grad(outcome_of)).lower(point).compile()
    compiled = time.perf_counter() - started
    temp_bytes = _temp_bytes(gradient_fn)
    started = time.perf_counter()
    outcome, gradient = jax.block_until_ready(gradient_fn(point))
    ran = time.perf_counter() - started
    steps = {k: fd_step * max(abs(float(v)), 1.0) for k, v in values.items()}
    shifted = [{**point, k: point[k] + sign * steps[k]} for k in names for sign in (1, -1)]
    batch = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *shifted)
    started = time.perf_counter()
    sides = np.asarray(jax.jit(jax.vmap(outcome_of))(batch), float).reshape(len(names), 2)
    differenced = time.perf_counter() - started
    outcome = float(outcome)
    rows = []
    for k, (plus, minus) in zip(names, sides):
        g, d, v = float(gradient[k]), (plus - minus) / (2 * steps[k]), float(values[k])
        floor = FLOOR * (1 + abs(outcome)) / max(abs(v), 1.0)
        agrees = bool(np.isfinite(g) and np.isfinite(d)
                      and abs(g - d) <= tolerance * max(abs(g), abs(d)) + floor)
        elasticity = g * v / outcome if outcome != 0 else math.nan
        rows.append(Row(k, v, g, d, elasticity, agrees))
    rows.sort(key=lambda r: -abs(r.elasticity) if np.isfinite(r.elasticity) else 0.0)
    return Study(outcome, rows, {"compile": compiled, "gradient": ran,
                                 "differences": differenced}, temp_bytes)


def _temp_bytes(compiled):
    try:
        return int(compiled.memory_analysis().temp_size_in_bytes)
    except Exception:            # (a backend without memory analysis)
        return None


def parse_name(name: str, task: str, params: dict):
    """(section, parameter, index or None) of a parameter's name; a ValueError naming it when
    it is not one of `params` (the environment's task parameters)."""
    match = _NAME.match(name)
    if not match:
        raise ValueError(f"parameter {name!r} is not of the form physics.<factor>, "
                         f"{task}.<parameter> or {task}.<parameter>[i]")
    section, key, index = match.group(1), match.group(2), match.group(3)
    index = None if index is None else int(index)
    if section == "physics":
        if "physics" not in params or key not in params["physics"] or index is not None:
            known = ", ".join(f"physics.{k}" for k in params.get("physics", {}))
            raise ValueError(f"parameter {name!r}: no such factor" +
                             (f"; the factors are {known}" if known else
                              f" (the task {task!r} takes no [physics] section)"))
        return section, key, None
    names = [k for k in params if k != "physics"]
    if section != task or key not in names:
        raise ValueError(f"parameter {name!r}: the task {task!r} has the parameters "
                         f"{', '.join(f'{task}.{k}' for k in names)} (and physics.*)")
    size = int(np.size(params[key]))
    if (index is None) != (np.ndim(params[key]) == 0) or (index is not None and index >= size):
        raise ValueError(f"parameter {name!r}: {task}.{key} has shape "
                         f"{tuple(np.shape(params[key]))}; name one number"
                         + (f", {task}.{key}[0] to [{size - 1}]" if np.ndim(params[key]) else ""))
    return section, key, index


def with_values(params: dict, parsed: dict, values: dict) -> dict:
    """`params` with each named value (`parsed[name]` from `parse_name`) in place."""
    params = {**params, **({"physics": dict(params["physics"])} if "physics" in params else {})}
    for name, value in values.items():
        section, key, index = parsed[name]
        table = params["physics"] if section == "physics" else params
        current = table[key]
        value = jnp.asarray(value, current.dtype)
        table[key] = value if index is None else current.at[index].set(value)
    return params


def start_values(params: dict, parsed: dict) -> dict:
    """The parameters' values in `params`, as floats."""
    values = {}
    for name, (section, key, index) in parsed.items():
        current = np.asarray((params["physics"] if section == "physics" else params)[key])
        values[name] = float(current if index is None else current[index])
    return values


def rollout_outcome(env, params: dict, parsed: dict, act, outcome: str, steps: int,
                    remat=True, key=None):
    """f(values) -> the `outcome` of `steps` control steps of `env` from its reset under
    `params` with `values` in place (`with_values`), the action at each step `act(obs)`."""
    from jaxsim import kinematics

    if outcome not in OUTCOMES:
        raise ValueError(f"outcome must be one of {', '.join(OUTCOMES)}; got {outcome!r}")
    key = jax.random.PRNGKey(0) if key is None else key
    if outcome == "tracking_error":
        metrics = jax.eval_shape(env.reset, params, key).metrics     # traced, not run
        if TRACKING_METRIC not in metrics:
            raise ValueError(f"outcome 'tracking_error' needs a task that follows a reference "
                             f"clip (imitation, runup); this one reports "
                             f"{', '.join(sorted(metrics)) or 'no metrics'}")

    def com_height(model, q):
        return kinematics.center_of_mass(model, q)[1]

    def outcome_of(values):
        run_params = with_values(params, parsed, values)
        start = env.reset(run_params, key)
        tracks_peak = isinstance(start.task, dict) and "peak_com" in start.task
        model = env.physical(run_params, env.world)[0] if hasattr(env, "physical") else env.model

        def control_step(carry, _):
            state, total, apex, error = carry
            state = env.step(run_params, state, act(state.obs))
            apex = jnp.maximum(apex, com_height(model, state.physics.q))
            error = error + state.metrics.get(TRACKING_METRIC, jnp.zeros_like(error))
            return (state, total + state.reward, apex, error), None

        # (inside a scan no common subexpression can merge the rematerialised forward pass
        # with the original, so the barriers against it are left out: 9 % less compile)
        body = jax.checkpoint(control_step, prevent_cse=False) if remat else control_step
        zero = jnp.zeros((), start.reward.dtype)
        (end, total, apex, error), _ = jax.lax.scan(
            body, (start, zero, com_height(model, start.physics.q), zero), None, length=steps)
        q0, q1 = start.physics.q, end.physics.q
        return {"tracking_error": error / steps,
                "apex_height": end.task["peak_com"] if tracks_peak else apex,
                "clearance": (end.task["clearance"] if isinstance(end.task, dict)
                              and "clearance" in end.task else jnp.nan * zero),
                "final_root_height": q1[1],
                "travel": jnp.sqrt((q1[0] - q0[0]) ** 2 + (q1[2] - q0[2]) ** 2),
                "return": total}[outcome]

    return outcome_of
