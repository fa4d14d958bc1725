"""Uniform random search: the floor every method must beat."""

from __future__ import annotations

import numpy as np

from optimizers.base import BestTracker, check_bounds
from optimizers.registry import register


@register("random")
class RandomSearch:
    """Independent uniform samples in the box, ``batch_size`` at a time.

    >>> opt = RandomSearch([0, 0], [1, 1], seed=0, batch_size=4)
    >>> X = opt.ask(); opt.tell(X, X.sum(axis=1)); X.shape
    (4, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, batch_size: int = 32) -> None:
        self.lower, self.upper = check_bounds(lower, upper)
        self.rng = np.random.default_rng(seed)
        self.batch_size = int(batch_size)
        self._best = BestTracker(self.lower.size)

    def ask(self) -> np.ndarray:
        return self.rng.uniform(self.lower, self.upper, size=(self.batch_size, self.lower.size))

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        self._best.update(X, f)

    @property
    def stop(self) -> str | None:
        return None

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f
