"""Which evaluations of a strategy search are the same strategy: the one rule the search's summary,
the gallery and Stage 2 count distinct strategies by. (The search benchmark on the ballistic box,
`benchmarks/bds_search.py --ballistic`, counts fixed bins of the up angle instead: with bins, the
count uniform random search should reach and the most any search could reach follow from the
bins' shares of the box, which grouping in order of arrival does not give.)

The thesis names its strategies by eye (§3.7.1). We group by feature instead: evaluations are
taken in the order they were made, and each joins the first strategy whose representative (its
first evaluation) lies within `threshold` of its feature, by the search's feature distance
(`bds.acquisition.distance_function`); otherwise it starts a new strategy. A failure (no
feature) belongs to no strategy. The rule depends on the order, as a person going through the
evaluations one by one would; it never merges two evaluations farther apart than 2 × threshold.

The threshold for Stage 1's feature, the angle between the root's facing direction and the up
axis at the bar crossing (`UP_ANGLE_THRESHOLD` = π/6, 30°): the high-jump strategies differ in
how the athlete faces while crossing — up (the Fosbury flop, near 0), sideways (the western roll
and side jumps, near π/2), down (the straddle and the dives, near π) — and π/6 splits [0, π]
into six such bands: two crossings 30° apart look alike in a filmstrip, 60° apart they do not.
For Stage 2's 3-D root orientation it is the thesis's d_threshold = π/2 (§3.6.2), the distance
at which the novelty reward (eq. 3.12) stops rewarding more difference.
"""

import math

import jax.numpy as jnp
import numpy as np

from bds.acquisition import distance_function

UP_ANGLE_THRESHOLD = math.pi / 6
ROTATION_THRESHOLD = math.pi / 2


def group(features, threshold: float, distance: str = "euclidean") -> np.ndarray:
    """The strategy of each evaluation (n,): 0, 1, … in order of first appearance, −1 for a
    failure. `features` is a sequence of features (each a list of m numbers) or None for a
    failure (a row of NaN counts as a failure too)."""
    if not threshold > 0:
        raise ValueError(f"the same-strategy threshold must be positive; got {threshold}")
    measure = distance_function(distance)
    labels, representatives = [], []
    for feature in features:
        if feature is None or not np.all(np.isfinite(np.asarray(feature, float))):
            labels.append(-1)
            continue
        f = np.atleast_1d(np.asarray(feature, float))
        if representatives:
            gaps = np.asarray(measure(jnp.asarray(f), jnp.asarray(np.stack(representatives))))
            nearest = int(np.argmin(gaps))
            if gaps[nearest] <= threshold:
                labels.append(nearest)
                continue
        representatives.append(f)
        labels.append(len(representatives) - 1)
    return np.array(labels, int)


def count(features, threshold: float, distance: str = "euclidean") -> int:
    """How many distinct strategies the features hold (failures are none)."""
    labels = group(features, threshold, distance)
    return int(labels.max() + 1) if labels.size else 0
