"""Any optimiser of nevergrad's registry, by name (``optimizer.params.name=NGOpt``)."""

from __future__ import annotations

import numpy as np

from optimizers.base import BestTracker, OptimizerError, WorstFiniteFill, check_bounds
from optimizers.registry import register


@register("nevergrad")
class Nevergrad:
    """``nevergrad.optimizers.registry[name]`` on a bounded ``ng.p.Array``; the batch is ``num_workers``.

    The parametrization starts at ``x0`` when given (else the box centre) and is seeded through
    its own ``random_state`` (never numpy's global one). ``budget`` is only a hint nevergrad uses
    to choose and tune its method (NGOpt picks its algorithm from budget, dimension and
    num_workers); set it to the run's evaluation budget. Stops only if nevergrad's optimiser
    raises its own stop (none of the common ones do).

    >>> opt = Nevergrad([0, 0], [1, 1], seed=0, name="DE", num_workers=4, budget=40)
    >>> X = opt.ask(); opt.tell(X, (X ** 2).sum(axis=1)); X.shape
    (4, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, name: str = "NGOpt", num_workers: int = 8,
                 budget: int | None = 1000) -> None:
        import nevergrad as ng

        self.lower, self.upper = check_bounds(lower, upper)
        if name not in ng.optimizers.registry:
            some = ", ".join(n for n in ("NGOpt", "CMA", "DE", "TwoPointsDE", "PSO", "OnePlusOne", "TBPSA",
                                         "RandomSearch", "ScrHammersleySearch", "NelderMead") if n in ng.optimizers.registry)
            raise OptimizerError(f"nevergrad: unknown optimizer name {name!r}; valid names include {some} "
                                 f"({len(ng.optimizers.registry)} in nevergrad.optimizers.registry)")
        if int(num_workers) < 1:
            raise OptimizerError(f"nevergrad: num_workers must be >= 1, got {num_workers}")
        init = (self.lower + self.upper) / 2 if x0 is None else np.clip(np.asarray(x0, float), self.lower, self.upper)
        # ng.p.Array(lower=, upper=) reads random_state while building and, finding none, draws a
        # seed from numpy's global generator; so: sigma first (it adds a sub-parameter), then the
        # seeded state (propagated to sub-parameters), then the bounds
        # sigma = range / 6 is what ng.p.Array(lower=, upper=) would set
        param = ng.p.Array(init=init).set_mutation(sigma=(self.upper - self.lower) / 6)
        param.random_state = np.random.RandomState(int(seed) % 2**32)
        param.set_bounds(self.lower, self.upper)
        self.num_workers = int(num_workers)
        self._opt = ng.optimizers.registry[name](parametrization=param, budget=None if budget is None else int(budget),
                                                 num_workers=self.num_workers)
        self._pending: list = []
        self._best = BestTracker(self.lower.size)
        self._fill = WorstFiniteFill()  # NaN/inf told as the worst finite value

    def ask(self) -> np.ndarray:
        if self._pending:
            raise OptimizerError("nevergrad: ask() called twice without tell()")
        self._pending = [self._opt.ask() for _ in range(self.num_workers)]
        return np.clip(np.array([c.value for c in self._pending]), self.lower, self.upper)

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        cands, self._pending = self._pending, []
        f = np.asarray(f, float).ravel()
        if not cands or f.shape != (len(cands),):
            raise OptimizerError(f"nevergrad: tell() needs the f of the last ask ({self.num_workers},), got {f.shape}")
        values = self._fill(f)
        for cand, value in zip(cands, values):
            self._opt.tell(cand, float(value))
        self._best.update(X, f)

    @property
    def stop(self) -> str | None:
        return None

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f
