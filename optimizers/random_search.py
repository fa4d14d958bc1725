"""Uniform random search: the floor every method must beat."""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell
from optimizers.registry import register


@register("random")
class RandomSearch(AskTell):
    """Independent uniform samples in the box, ``batch_size`` at a time.

    >>> opt = RandomSearch([0, 0], [1, 1], seed=0, batch_size=4)
    >>> X = opt.ask(); opt.tell(X, X.sum(axis=1)); X.shape
    (4, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, batch_size: int = 32) -> None:
        super().__init__(lower, upper)
        self.batch_size = self.int_param("batch_size", batch_size, 1)
        self.rng = np.random.default_rng(self.seed_param(seed))

    def _ask(self) -> np.ndarray:
        return self.rng.uniform(self.lower, self.upper, size=(self.batch_size, self.dim))

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        pass  # nothing to learn: the base keeps the best
