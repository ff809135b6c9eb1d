"""What a search's exploration pick had to go on: the feature GP that `bds.search.plan_round`
fits before pick INDEX of a logged search, and where its posterior σ (eq. 3.10) times the
success model's P[success] is largest.

For the evaluations logged before INDEX it fits the feature GP as `plan_round` does
(`bds.search.RoundModel`) and the success model, and prints the fitted hyperparameters, σ and P over uniform
points of the box, and the best of those points by σ · P and by σ alone. `--hyperprior` fits
the feature GP under `bds.gp`'s hyperparameter priors instead, whatever the search used.

Run:  python benchmarks/exploration_fit.py runs/highjump_bds_z1 4 [--hyperprior]
(docs/discovery, "Why the exploration picks land beside a success"; seconds.)
"""

import argparse
import dataclasses
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from agents.tasks.takeoff_state import HIGHJUMP_BOUNDS
from bds import acquisition, feasibility, gp
from bds.search import SEARCH_LOG, RoundModel, SearchSettings, logged_evaluations, success_model


def fitted(directory: Path, index: int, hyperprior: bool | None):
    """(feature posterior with the failures believed, success model or None, box bounds)."""
    stored = json.loads((directory / "config.json").read_text())["search"]
    settings = SearchSettings(**{k: tuple(v) if isinstance(v, list) else v
                                 for k, v in stored.items()})
    if hyperprior is not None:
        settings = dataclasses.replace(settings, hyperprior=hyperprior)
    lower, upper = (np.array(b) for b in HIGHJUMP_BOUNDS)
    records = logged_evaluations(directory / SEARCH_LOG)[:index]
    unit = lambda rs: gp.to_unit(np.array([r["x"] for r in rs]).reshape(-1, 4), lower, upper)
    good = [r for r in records if r["feature"] is not None]
    failed_unit = unit([r for r in records if r["feature"] is None])
    x_unit, features = unit(good), np.array([r["feature"] for r in good])
    posterior = RoundModel(settings, index, x_unit, features, failed_unit, 1).posterior
    model = success_model(settings, index, x_unit, failed_unit)
    return posterior, model, (lower, upper), records


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("search_dir", type=Path)
    parser.add_argument("index", type=int, help="the pick whose fit to show")
    parser.add_argument("--hyperprior", action="store_true", default=None)
    parser.add_argument("--points", type=int, default=4000)
    args = parser.parse_args()
    posterior, model, (lower, upper), records = fitted(args.search_dir, args.index,
                                                       args.hyperprior)
    hyper = posterior.hyper
    print("lengthscales (box widths, α ω_x ω_z v_z):",
          np.round(np.asarray(hyper.lengthscales)[0], 3),
          f" signal variance {float(hyper.signal_variance[0]):.3f}"
          f"  noise variance {float(hyper.noise_variance[0]):.3g}")
    points = np.random.default_rng(0).uniform(size=(args.points, 4))
    sigma = np.asarray(acquisition.exploration(posterior, jnp.asarray(points)))
    chance = (np.full(len(points), 1.0) if model is None else
              np.asarray(feasibility.success_probability(model, jnp.asarray(points))))
    print(f"σ over {args.points} uniform points: min {sigma.min():.3f}, median "
          f"{np.median(sigma):.3f}, max {sigma.max():.3f}")
    print(f"P[success] over them: min {chance.min():.3f}, median {np.median(chance):.3f}, "
          f"max {chance.max():.3f}")
    x_text = lambda u: "(" + ", ".join(f"{v:.2f}" for v in gp.from_unit(u, lower, upper)) + ")"
    for name, score in (("σ · P", sigma * chance), ("σ", sigma)):
        best = int(np.argmax(score))
        print(f"best by {name}: x = {x_text(points[best])}, σ {sigma[best]:.3f}, "
              f"P {chance[best]:.3f}")
    for record in records:
        u = gp.to_unit(np.array(record["x"]), lower, upper)[None]
        at = lambda f: float(np.asarray(f(jnp.asarray(u)))[0])
        p = 1.0 if model is None else at(lambda v: feasibility.success_probability(model, v))
        print(f"at evaluation {record['index']:03d} "
              f"({'success' if record['feature'] is not None else 'failure'}): "
              f"σ {at(lambda v: acquisition.exploration(posterior, v)):.3f}, P {p:.3f}")

if __name__ == "__main__":
    main()
