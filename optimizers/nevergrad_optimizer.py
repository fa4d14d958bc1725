"""Any optimiser of nevergrad's registry, by name (``optimizer.params.name=NGOpt``)."""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell, OptimizerError
from optimizers.registry import register


@register("nevergrad")
class Nevergrad(AskTell):
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

    nonfinite = "worst"  # nevergrad models values: a NaN/inf is told as the worst finite value

    def __init__(self, lower, upper, seed: int, x0=None, name: str = "NGOpt", num_workers: int = 8,
                 budget: int | None = 1000) -> None:
        # importing nevergrad draws from numpy's global generator (150 of MT19937's 624 words,
        # nevergrad 1.0.12): its state is put back, so the first plugin built leaves it untouched too
        state = np.random.get_state()
        import nevergrad as ng

        np.random.set_state(state)
        super().__init__(lower, upper)
        if name not in ng.optimizers.registry:
            known = ("NGOpt", "CMA", "DE", "TwoPointsDE", "PSO", "OnePlusOne", "TBPSA", "RandomSearch",
                     "ScrHammersleySearch", "NelderMead")
            some = ", ".join(n for n in known if n in ng.optimizers.registry)
            raise OptimizerError(f"nevergrad: unknown optimizer name {name!r}; valid names include {some} "
                                 f"({len(ng.optimizers.registry)} in nevergrad.optimizers.registry)")
        self.num_workers = self.int_param("num_workers", num_workers, 1)
        budget = None if budget is None else self.int_param("budget", budget, 1)
        seed = self.seed_param(seed)
        init = (self.lower + self.upper) / 2 if x0 is None else np.clip(np.asarray(x0, float), self.lower, self.upper)
        # ng.p.Array(lower=, upper=) reads random_state while building and, finding none, draws a
        # seed from numpy's global generator; so: sigma first (it adds a sub-parameter), then the
        # seeded state (propagated to sub-parameters), then the bounds
        # sigma = range / 6 is what ng.p.Array(lower=, upper=) would set
        param = ng.p.Array(init=init).set_mutation(sigma=self.span / 6)
        param.random_state = np.random.RandomState(seed % 2**32)
        param.set_bounds(self.lower, self.upper)
        self._opt = ng.optimizers.registry[name](parametrization=param, budget=budget,
                                                 num_workers=self.num_workers)
        self._candidates: list = []

    def _ask(self) -> np.ndarray:
        self._candidates = [self._opt.ask() for _ in range(self.num_workers)]
        return np.array([c.value for c in self._candidates])

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        for cand, value in zip(self._candidates, f):
            self._opt.tell(cand, float(value))
