"""Synthetic strategy landscapes: cheap stand-ins for "train a jump policy from take-off state x and
report its strategy feature", for testing and benchmarking searches.

The box [0, 1]^d is partitioned into regions of very unequal size by an additively weighted Voronoi
(power) diagram: x belongs to the strategy k that minimises ‖x − c_k‖² − w_k. A few strategies get
large weights and own most of the box (the flat, common strategies); the rest are small pockets, as
rare strategies are in the thesis's high-jump search. Each strategy has its own feature value,
and an evaluation returns that value plus Gaussian noise. The features are either drawn well apart from
each other with no relation to where the strategies lie ("spread", the default), or follow position
("positional": a projection of each region's centre, so neighbouring strategies have nearby
features); for a seed, both kinds have the same regions. The strategy label of a point is known,
so a benchmark can count how many distinct strategies a search found.
"""

from dataclasses import dataclass

import numpy as np


FEATURE_KINDS = ("spread", "positional")


@dataclass(frozen=True)
class LandscapeSettings:
    """A family of random landscapes: one per seed."""
    dim: int = 4
    strategies: int = 8
    feature_dim: int = 1
    noise: float = 0.01             # standard deviation of the feature noise
    large: int = 2                  # strategies that own most of the box
    features: str = "spread"        # "spread" or "positional" (see StrategyLandscape)
    seed: int = 0

    def __post_init__(self):
        if self.dim < 1 or self.feature_dim < 1:
            raise ValueError("dim and feature_dim must be at least 1")
        if not 2 <= self.strategies <= 64:
            raise ValueError(f"strategies must be between 2 and 64; got {self.strategies}")
        if not 0 <= self.large < self.strategies:
            raise ValueError(f"large must be between 0 and strategies − 1; got {self.large}")
        if self.noise < 0:
            raise ValueError(f"noise must be non-negative; got {self.noise}")
        if self.seed < 0:
            raise ValueError(f"seed must be non-negative; got {self.seed}")
        if self.features not in FEATURE_KINDS:
            raise ValueError(f"features must be one of {', '.join(FEATURE_KINDS)}; got "
                             f"{self.features!r}")


class StrategyLandscape:
    """One random landscape; call it on a point x (d,) in the unit box to get its feature."""

    def __init__(self, settings: LandscapeSettings):
        self.settings = settings
        rng = np.random.default_rng(settings.seed)
        self.centres = rng.uniform(size=(settings.strategies, settings.dim))
        weights = rng.uniform(0.0, 0.01, settings.strategies)
        weights[:settings.large] = rng.uniform(0.2, 0.5, settings.large)
        self.weights = weights
        if settings.features == "spread":
            self.features = self._spread_features(rng, settings.strategies, settings.feature_dim)
        else:
            self.features = self._positional_features(rng, self.centres, settings.feature_dim)

    @staticmethod
    def _spread_features(rng, count, dim):
        """`count` feature values in [0, 1]^dim, as far apart as a greedy pick from many draws
        allows (so strategies are distinguishable through the noise)."""
        pool = rng.uniform(size=(64 * count, dim))
        chosen = [pool[0]]
        for _ in range(count - 1):
            gaps = np.min(np.linalg.norm(pool[:, None] - np.array(chosen)[None], axis=-1), axis=1)
            chosen.append(pool[np.argmax(gaps)])
        return np.array(chosen)

    @staticmethod
    def _positional_features(rng, centres, dim):
        """Features that follow where a strategy lies: each feature is the projection of the
        strategies' centres on a random direction, rescaled to [0, 1] over the strategies."""
        directions = rng.standard_normal((dim, centres.shape[1]))
        projected = centres @ directions.T
        low, high = projected.min(0), projected.max(0)
        return (projected - low) / (high - low)

    def label(self, x):
        """Strategy index of each point of x (..., d)."""
        x = np.asarray(x, float)
        power = np.sum((x[..., None, :] - self.centres) ** 2, axis=-1) - self.weights
        return np.argmin(power, axis=-1)

    def __call__(self, x):
        """Feature of the strategy at x (d,), plus noise that is a fixed function of x and the
        seed (so the landscape is a deterministic black box)."""
        x = np.asarray(x, float)
        noise = np.random.default_rng([self.settings.seed, *np.frombuffer(x.tobytes(), np.uint32)])
        feature = self.features[self.label(x)]
        return feature + self.settings.noise * noise.standard_normal(feature.shape)

    def volumes(self, samples=200_000, seed=0):
        """Monte-Carlo fraction of the box owned by each strategy."""
        points = np.random.default_rng(seed).uniform(size=(samples, self.settings.dim))
        return np.bincount(self.label(points), minlength=self.settings.strategies) / samples
