"""The throughput of one training iteration of a config, and its split (shared by the imitation
and jump benchmarks).

`measure(config_path, data_dir, overrides)` builds the config's trainer and times, each as the
median of `repeats` calls after a first (compiling) call, with the XLA options the trainer
compiles them with: the rollout (simulation and policy; the simulator's options), the PPO update
(XLA's defaults; also timed under the simulator's options), and the whole
iteration (the trainer's two programs, and for comparison one program compiled with the
simulator's options throughout); and the update's floor, its floating-point operations at this
machine's matmul rate.
"""

import statistics
import time

import jax
import jax.numpy as jnp

from agents.commands import train_commands
from jaxsim import xla_options


def timed(fn, *args, repeats):
    """Median seconds of `repeats` calls after a first (compiling) call (None when `repeats` is
    0); and that first call."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return (statistics.median(times) if times else None), first


def timed_alternately(fns, *args, repeats):
    """For functions `fns` of the same arguments: the median seconds of each over `repeats`
    rounds in which each is called once in turn, after a first (compiling) call of each; and
    those first calls."""
    firsts = [timed(fn, *args, repeats=0)[1] for fn in fns]
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, spent in zip(fns, times):
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            spent.append(time.perf_counter() - start)
    return [statistics.median(spent) for spent in times], firsts


def update_floor(update, args, steps, size=2048):
    """The floating-point operations of one PPO update (`update` jitted, on `args`) and this
    machine's float32 matmul rate (a size × size product, median of 10): the update cannot run
    faster than their ratio, however fast the simulation. XLA's cost analysis of the compiled
    update counts the body of a loop once, so it gives one minibatch step (plus the advantages);
    times `steps` minibatch steps."""
    flop = update.lower(*args).compile().cost_analysis()["flops"] * steps
    a = jnp.ones((size, size), jnp.float32)
    matmul_s, _ = timed(jax.jit(jnp.matmul), a, a, repeats=10)
    return flop, 2 * size ** 3 / matmul_s


def measure(config_path, data_dir, overrides=(), repeats=5) -> dict:
    """The figures of one config (see the module docstring), as a JSON-ready dict; with the
    simulation steps per second inside the rollout where the environment has substeps."""
    config = train_commands.load_config(config_path, list(overrides))
    trainer = train_commands.make_trainer(config, data_dir)
    state = trainer.init()
    p = state.ppo
    sigma = trainer.sigma(p.samples)
    options = xla_options.simulation_options()
    env_params = trainer.env_params_for(state.curriculum)
    rollout = jax.jit(trainer.rollout, compiler_options=options)
    rollout_args = (env_params, state.runner, p.policy_params, p.value_params, state.norm, sigma,
                    state.key)
    rollout_s, rollout_compile = timed(rollout, *rollout_args, repeats=repeats)
    batch = rollout(*rollout_args)[1]
    update = jax.jit(trainer.ppo.update)                 # as the trainer compiles it
    update_s, update_compile = timed(update, p, batch, state.key, repeats=repeats)
    update_sim_s, _ = timed(jax.jit(trainer.ppo.update, compiler_options=options), p, batch,
                            state.key, repeats=repeats)
    # The iteration against the alternative the trainer does not take, the iteration as one
    # program compiled with the simulator's options throughout; their calls alternate, so a
    # change in the machine's speed during the measurement falls on both alike.
    fused = jax.jit(lambda s: trainer._learn(s, trainer._collect(trainer.rollout, s))[1],
                    compiler_options=options)
    (iteration_s, fused_s), (iteration_compile, fused_compile) = timed_alternately(
        (lambda s: trainer.iteration(s)[1], fused), state, repeats=repeats)
    samples = config.run.samples_per_iteration
    update_flop, matmul_rate = update_floor(
        update, (p, batch, state.key), config.ppo.epochs * (samples // config.ppo.minibatch_size))
    result = {"config": str(config_path), "overrides": list(overrides), "envs": config.run.envs,
              "steps_per_iteration": config.run.steps_per_iteration,
              "samples_per_iteration": samples,
              "iteration_seconds": iteration_s, "samples_per_second": samples / iteration_s,
              "one_program_iteration_seconds": fused_s,
              "rollout_seconds": rollout_s, "update_seconds": update_s,
              "update_seconds_simulation_options": update_sim_s,
              "rollout_share": rollout_s / (rollout_s + update_s),
              "update_gflop": update_flop / 1e9, "matmul_gflop_per_s": matmul_rate / 1e9,
              "update_floor_seconds": update_flop / matmul_rate, "xla_options": options,
              "compile_seconds": {"rollout": rollout_compile, "update": update_compile,
                                  "iteration": iteration_compile,
                                  "one_program_iteration": fused_compile}}
    substeps = getattr(trainer.env, "substeps", None)      # the env `trainer.rollout` steps
    if substeps:
        result["substeps"] = substeps
        result["simulation_steps_per_second"] = samples * substeps / rollout_s
    return result
