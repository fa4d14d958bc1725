"""A (1+1) evolution strategy with the 1/5th success rule: the README's "add an optimiser" example."""

from __future__ import annotations

import numpy as np

from optimizers.base import BestTracker, check_bounds
from optimizers.registry import register


@register("one_plus_one")
class OnePlusOne:
    """Mutate the best point with Gaussian steps; widen the step after a success, shrink it after a failure.

    Works in units of the box width. ``sigma0``: initial step (fraction of the width);
    ``batch_size``: offspring per ask; ``min_sigma``: stop when the step falls below it.
    """

    def __init__(self, lower, upper, seed: int, x0=None, sigma0: float = 0.2,
                 batch_size: int = 4, min_sigma: float = 1e-6) -> None:
        self.lower, self.upper = check_bounds(lower, upper)
        self.rng = np.random.default_rng(seed)
        self.sigma, self.batch_size, self.min_sigma = float(sigma0), int(batch_size), float(min_sigma)
        start = self.rng.uniform(self.lower, self.upper) if x0 is None else np.asarray(x0, float)
        self.parent, self.parent_f = start, np.inf
        self._best = BestTracker(self.lower.size)

    def ask(self) -> np.ndarray:
        width = self.upper - self.lower
        steps = self.rng.normal(size=(self.batch_size, self.lower.size)) * self.sigma * width
        return np.clip(self.parent + steps, self.lower, self.upper)

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        self._best.update(X, f)
        i = int(np.argmin(f))
        success = f[i] < self.parent_f
        if success:
            self.parent, self.parent_f = np.array(X[i]), float(f[i])
        self.sigma *= np.exp(0.8 if success else -0.2)  # 1/5th rule: stationary at 20% success

    @property
    def stop(self) -> str | None:
        return f"step size {self.sigma:.2g} below {self.min_sigma:g}" if self.sigma < self.min_sigma else None

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f
