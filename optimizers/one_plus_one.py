"""A (1+1) evolution strategy with the 1/5th success rule: the example of docs/guide/adding-an-optimiser.md."""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell
from optimizers.registry import register


@register("one_plus_one")
class OnePlusOne(AskTell):
    """Mutate the best point with Gaussian steps; widen the step after a success, shrink it after a failure.

    Works in units of the box width. ``sigma0``: initial step (fraction of the width);
    ``batch_size``: offspring per ask; ``min_sigma``: stop when the step falls below it.
    """

    def __init__(self, lower, upper, seed: int, x0=None, sigma0: float = 0.2,
                 batch_size: int = 4, min_sigma: float = 1e-6) -> None:
        super().__init__(lower, upper)  # bounds, ask/tell guards, NaN -> inf, best tracking
        self.sigma = self.float_param("sigma0", sigma0, 0, 1, low_open=True)
        self.batch_size = self.int_param("batch_size", batch_size, 1)
        self.min_sigma = self.float_param("min_sigma", min_sigma, 0)
        self.rng = np.random.default_rng(self.seed_param(seed))
        start = self.rng.uniform(self.lower, self.upper) if x0 is None else np.asarray(x0, float)
        self.parent, self.parent_f = start, np.inf

    def _ask(self) -> np.ndarray:
        steps = self.rng.normal(size=(self.batch_size, self.dim)) * self.sigma * self.span
        return self.parent + steps

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        i = int(np.argmin(f))
        success = f[i] < self.parent_f
        if success:
            self.parent, self.parent_f = np.array(X[i]), float(f[i])
        self.sigma *= np.exp(0.8 if success else -0.2)  # 1/5th rule: stationary at 20% success

    @property
    def stop(self) -> str | None:
        return f"step size {self.sigma:.2g} below {self.min_sigma:g}" if self.sigma < self.min_sigma else None
