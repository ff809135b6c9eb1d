"""Optimisers over a box for the acquisition functions of BDS (thesis §3.5.1).

`maximize_lbfgs`: multi-start L-BFGS (Optax's, with its zoom line search) for the smooth exploration
acquisition. The box is handled by a change of variables x = (1 + sin z) / 2 per coordinate, so z is
unconstrained, every point of the closed box (its faces and corners included, where the posterior
standard deviation is often largest) is reachable, and the gradient exists everywhere. Starts are
the best of many uniform candidates; all starts run at once under `vmap`.

`direct`: Jones, Perttunen & Stuckman's DIviding RECTangles (J. Optim. Theory Appl. 79, 1993), a
derivative-free global minimiser, for the Monte-Carlo diversity acquisition whose surface has kinks
(from the min over observed features). Written in NumPy around a batched objective: every point an
iteration needs is evaluated in one call.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax


def _to_box(z):
    return 0.5 * (1.0 + jnp.sin(z))


def _from_box(x):
    return jnp.arcsin(jnp.clip(2.0 * x - 1.0, -1.0, 1.0))


def maximize_lbfgs(fun, dim, key, starts=8, candidates=1024, steps=30):
    """Maximise fun(x (n, d) in the unit box) → (n,) from the `starts` best of `candidates` uniform
    points, with `steps` L-BFGS iterations each. Traceable (call it inside `jax.jit`); returns the
    best point (d,) and its value."""
    points = jax.random.uniform(key, (candidates, dim))
    values = fun(points)
    values = jnp.where(jnp.isfinite(values), values, -jnp.inf)
    _, best = jax.lax.top_k(values, starts)

    def negative(z):
        return -fun(_to_box(z)[None])[0]

    solver = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(negative)

    def run(z):
        def iteration(carry, _):
            z, state = carry
            value, grad = value_and_grad(z, state=state)
            updates, state = solver.update(grad, state, z, value=value, grad=grad,
                                           value_fn=negative)
            return (optax.apply_updates(z, updates), state), None
        (z, _), _ = jax.lax.scan(iteration, (z, solver.init(z)), None, length=steps)
        return z

    refined = _to_box(jax.vmap(run)(_from_box(points[best])))
    refined_values = fun(refined)
    all_points = jnp.concatenate([points[best], refined])
    all_values = jnp.concatenate([values[best], jnp.where(jnp.isfinite(refined_values),
                                                          refined_values, -jnp.inf)])
    winner = jnp.argmax(all_values)
    return all_points[winner], all_values[winner]


class DirectResult(NamedTuple):
    x: np.ndarray           # the best point found, in [lower, upper]
    value: float
    evaluations: int
    iterations: int


def _potentially_optimal(sizes, values, epsilon):
    """Indices of the potentially optimal rectangles (Jones et al. 1993, Definition 1).

    Rectangle j qualifies if some K > 0 makes f_j − K d_j the smallest of all f_i − K d_i and at
    least ε|f_min| below f_min. Only the lowest value of each size can qualify, and of those only the
    lower-right convex hull of (d, f) from the overall minimum to the largest size.
    """
    f_min = values.min()
    unique_sizes = np.unique(sizes)
    best_per_size = np.array([np.flatnonzero(sizes == s)[np.argmin(values[sizes == s])]
                              for s in unique_sizes])
    d, f = sizes[best_per_size], values[best_per_size]
    start = np.flatnonzero(f == f.min())[-1]         # the largest rectangle holding f_min
    hull = [start]
    for k in range(start + 1, len(d)):                # monotone-chain lower hull, left to right
        while len(hull) >= 2:
            i, j = hull[-2], hull[-1]
            # drop j if it lies on or above the segment from i to k
            if (f[j] - f[i]) * (d[k] - d[i]) >= (f[k] - f[i]) * (d[j] - d[i]):
                hull.pop()
            else:
                break
        hull.append(k)
    chosen = []
    for position, j in enumerate(hull):
        if position + 1 < len(hull):                  # the largest admissible slope K
            k = hull[position + 1]
            slope = (f[k] - f[j]) / (d[k] - d[j])
            if slope <= 0 or f[j] - slope * d[j] > f_min - epsilon * abs(f_min):
                continue
        chosen.append(best_per_size[j])
    return np.array(chosen, int)


def direct(fun, lower, upper, max_evaluations=500, max_iterations=10_000, epsilon=1e-4):
    """Minimise fun over the box [lower, upper] with DIRECT.

    fun maps points (n, d) to values (n,) (NumPy or JAX; non-finite values count as +inf-like: the
    largest finite value seen). Stops after the iteration in which the evaluation count reaches
    `max_evaluations` (so it may exceed it by one iteration's worth) or after `max_iterations`.
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    if lower.shape != upper.shape or lower.ndim != 1 or not np.all(upper > lower):
        raise ValueError(f"direct needs 1-D bounds with upper > lower; got lower={lower}, "
                         f"upper={upper}")
    dim = lower.size

    centres = [np.full(dim, 0.5)]
    levels = [np.zeros(dim, int)]                   # side of coordinate i is 3^(−levels[i])
    f_values = []

    def evaluate(unit_points):
        values = np.asarray(fun(lower + unit_points * (upper - lower)), float).reshape(-1)
        finite = np.isfinite(values)
        if not finite.all():
            known = np.concatenate([values[finite], f_values])
            values[~finite] = known.max() + 1.0 if known.size else 1.0
        return values

    f_values.extend(evaluate(centres[0][None]))
    iterations = 0
    while len(f_values) < max_evaluations and iterations < max_iterations:
        iterations += 1
        level_array = np.array(levels)
        sizes = np.round(0.5 * np.sqrt(np.sum(9.0 ** -level_array, axis=1)), 12)
        chosen = _potentially_optimal(sizes, np.array(f_values), epsilon)
        # Sample every chosen rectangle at c ± δ e_i along its longest sides, all in one call.
        plans, new_points = [], []
        for r in chosen:
            long_dims = np.flatnonzero(levels[r] == levels[r].min())
            delta = 3.0 ** -(levels[r].min() + 1)
            steps = delta * np.eye(dim)[long_dims]
            new_points.append(np.stack([centres[r] + steps, centres[r] - steps], axis=1))
            plans.append((r, long_dims))
        new_points = np.concatenate(new_points)                      # (samples, 2, d)
        new_values = evaluate(new_points.reshape(-1, dim)).reshape(-1, 2)
        cursor = 0
        for r, long_dims in plans:
            points = new_points[cursor:cursor + len(long_dims)]
            values = new_values[cursor:cursor + len(long_dims)]
            cursor += len(long_dims)
            # Divide along the dimension with the best sample first, so the best samples end up
            # in the largest new rectangles.
            for k in np.argsort(values.min(axis=1), kind="stable"):
                levels[r][long_dims[k]] += 1
                for side in range(2):
                    centres.append(points[k, side])
                    levels.append(levels[r].copy())
                    f_values.append(values[k, side])
    best = int(np.argmin(f_values))
    return DirectResult(lower + centres[best] * (upper - lower), float(f_values[best]),
                        len(f_values), iterations)
