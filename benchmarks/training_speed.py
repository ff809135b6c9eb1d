"""The throughput of one training iteration of a config, and its split (shared by the imitation
and jump benchmarks).

`measure(config_path, data_dir, overrides)` builds the config's trainer and times, each as the
median of `repeats` calls after a first (compiling) call, with the XLA options the trainer
compiles them with: the rollout (simulation and policy; the simulator's options), the PPO update
(XLA's defaults; also timed under the simulator's options), and the whole
iteration (the trainer's two programs, and for comparison one program compiled with the
simulator's options throughout); and two floors of the update: its floating-point operations
at this machine's rate for a large matrix product, and the time of its own matrix products
alone (`network_passes`: the networks' forward and backward passes at the minibatch's shape, as
many as the update makes, with nothing else). The update, its passes and the large product are
timed alternately, so that the VM's changes of speed fall on all three alike.
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


def update_flop(update, args, steps):
    """The floating-point operations of one PPO update (`update` jitted, on `args`). XLA's cost
    analysis of the compiled update counts the body of a loop once, so it gives one minibatch
    step (plus the advantages); times `steps` minibatch steps."""
    return update.lower(*args).compile().cost_analysis()["flops"] * steps


def network_passes(trainer, batch, steps, minibatch):
    """A jitted function of (policy, value parameters) that makes `steps` forward and backward
    passes of both networks on `minibatch` observations of `batch` each, as the update does, and
    nothing else (no loss beyond a sum of squares, no optimiser, no shuffling): the time of the
    update's matrix products."""
    obs = batch.obs.reshape(-1, batch.obs.shape[-1])
    pieces = obs.shape[0] // minibatch

    def loss(policy, value, x):
        return (jnp.sum(trainer.policy_apply(policy, x) ** 2)
                + jnp.sum(trainer.value_apply(value, x) ** 2))

    def passes(policy, value):
        def one(total, i):
            x = jax.lax.dynamic_slice_in_dim(obs, (i % pieces) * minibatch, minibatch)
            grads = jax.grad(loss, argnums=(0, 1))(policy, value, x * (1.0 + 1e-9 * total))
            return total + sum(jnp.sum(g) for g in jax.tree_util.tree_leaves(grads)), None
        return jax.lax.scan(one, jnp.zeros((), obs.dtype), jnp.arange(steps))[0]
    return jax.jit(passes)


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
    _, update_compile = timed(update, p, batch, state.key, repeats=0)   # timed below
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
    steps = config.ppo.epochs * (samples // config.ppo.minibatch_size)
    flop = update_flop(update, (p, batch, state.key), steps)
    size = 2048
    square = jnp.ones((size, size), jnp.float32)
    passes = network_passes(trainer, batch, steps, config.ppo.minibatch_size)
    (update_s, passes_s, matmul_s), _ = timed_alternately(
        (lambda: update(p, batch, state.key), lambda: passes(p.policy_params, p.value_params),
         lambda: jnp.matmul(square, square)), repeats=max(repeats, 5))
    matmul_rate = 2 * size ** 3 / matmul_s
    result = {"config": str(config_path), "overrides": list(overrides), "envs": config.run.envs,
              "steps_per_iteration": config.run.steps_per_iteration,
              "samples_per_iteration": samples,
              "iteration_seconds": iteration_s, "samples_per_second": samples / iteration_s,
              "one_program_iteration_seconds": fused_s,
              "rollout_seconds": rollout_s, "update_seconds": update_s,
              "update_seconds_simulation_options": update_sim_s,
              "rollout_share": rollout_s / (rollout_s + update_s),
              "update_gflop": flop / 1e9, "matmul_gflop_per_s": matmul_rate / 1e9,
              "update_floor_seconds": flop / matmul_rate,
              "update_network_passes_seconds": passes_s, "xla_options": options,
              "compile_seconds": {"rollout": rollout_compile, "update": update_compile,
                                  "iteration": iteration_compile,
                                  "one_program_iteration": fused_compile}}
    substeps = getattr(trainer.env, "substeps", None)      # the env `trainer.rollout` steps
    if substeps:
        result["substeps"] = substeps
        result["simulation_steps_per_second"] = samples * substeps / rollout_s
    return result
