"""Which part of a run-up's hand-over makes its jump fail? The jump policy from its own take-off
state with one part at a time swapped for the run-up's.

A jump policy is trained from the desired take-off state of x (`JumpEnv.reset`); in the full
motion it starts instead from where its run-up arrived (`agents.tasks.full_motion.handover`).
This script runs the full motion once to get that hand-over state, then the jump policy's
deterministic episode (at its run's bar, `--bar` for another) from:

    the take-off state of x, and the hand-over state, whole;
    each of them with one part taken from the other: the joint angles (q beyond the root's 7),
    the joint velocities (qd beyond the root's 6), the root's orientation, the root's velocities.

Each episode starts with fresh contacts (`simulation.init_state`), where the full motion carries
the run-up's ground contact springs over: the hand-over row against the full motion's own
summary.json says how much that matters.

Run:  python benchmarks/handover_parts.py RUNUP_DIR JUMP_DIR [--bar Z] [--data-dir ../shared/data]
(about a minute on two cores, most of it compiling).
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from agents.commands import motion_commands
from agents.datadir import data_dir_from
from agents.tasks.observations import body_observation
from jaxsim import simulation

ROOT_Q, ROOT_QD = 7, 6          # the free root's position and quaternion; its ω and v


def swapped_states(q_x, qd_x, q_h, qd_h):
    """{name: (q, qd)}: the two states whole and each with one part from the other."""
    parts = {"joint angles": ("q", slice(ROOT_Q, None)),
             "joint velocities": ("qd", slice(ROOT_QD, None)),
             "root orientation": ("q", slice(3, ROOT_Q)),
             "root velocities": ("qd", slice(0, ROOT_QD))}
    states = {"take-off state of x": (q_x, qd_x), "hand-over state": (q_h, qd_h)}
    for base, other, (q, qd), (q_other, qd_other) in (
            ("take-off state of x", "hand-over", (q_x, qd_x), (q_h, qd_h)),
            ("hand-over state", "take-off state's", (q_h, qd_h), (q_x, qd_x))):
        for name, (which, where) in parts.items():
            new_q, new_qd = q.copy(), qd.copy()
            if which == "q":
                new_q[where] = q_other[where]
            else:
                new_qd[where] = qd_other[where]
            states[f"{base}, {other} {name}"] = (new_q, new_qd)
    return states


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runup_dir")
    parser.add_argument("jump_dir")
    parser.add_argument("--bar", type=float, help="the jump's bar (default: its run's)")
    parser.add_argument("--data-dir")
    args = parser.parse_args()
    data = data_dir_from(args.data_dir)
    quiet = lambda *_, **__: None                                      # noqa: E731
    runup = motion_commands.load_run(args.runup_dir, data, echo=quiet)
    jump = motion_commands.load_run(args.jump_dir, data, echo=quiet)
    full = motion_commands.run_full_motion(runup, jump)
    env, params, policy = jump.env, dict(jump.params), jump.policy
    if args.bar is not None:
        params["difficulty"] = jnp.asarray(args.bar, params["difficulty"].dtype)
    fresh = jax.jit(env.reset)(params, jax.random.PRNGKey(0))
    q_x, qd_x = (np.asarray(a) for a in (fresh.physics.q, fresh.physics.qd))
    q_h = np.asarray(full.handover.pose_to_jump(jnp.asarray(full.takeoff_physics.q)))
    qd_h = np.asarray(full.takeoff_physics.qd)

    @jax.jit
    def episode(q, qd):
        physics = simulation.init_state(env.model, env.world, q, qd)
        start = fresh.replace(physics=physics, obs=body_observation(env.model, q, qd))

        def step(state, _):
            action = jump.trainer.policy_apply(policy.params, policy.norm.normalize(state.obs))
            state = env.step(params, state, action)
            return state, (state.metrics["episode/success"], state.task["clearance"],
                           state.terminated | state.truncated)

        return jax.lax.scan(step, start, None, length=env.episode_steps)[1]

    print(f"jump {args.jump_dir} at {float(params['difficulty']):.2f} m from the hand-over of "
          f"{args.runup_dir}")
    print(f"{'start':62s} {'outcome':8s} {'ends at step':>12s} {'clearance':>10s}")
    for name, (q, qd) in swapped_states(q_x, qd_x, q_h, qd_h).items():
        success, clearance, done = (np.asarray(a) for a in episode(
            jnp.asarray(q, q_x.dtype), jnp.asarray(qd, q_x.dtype)))
        end = int(np.argmax(done)) if done.any() else len(done) - 1
        outcome = "success" if success[end] > 0 else "failure"
        print(f"{name:62s} {outcome:8s} {end + 1:12d} {clearance[end]:10.2f} m")


if __name__ == "__main__":
    main()
