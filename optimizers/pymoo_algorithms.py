"""pymoo's PSO and GA behind the ask/tell contract (pymoo 0.6 ``algorithm.ask()/tell(infills=...)``).

Values come back through ``StaticProblem`` and the algorithm's own ``evaluator``, so pymoo's
evaluation counter (``algorithm.evaluator.n_eval``) advances as in ``minimize``. The algorithm
is seeded with ``seed`` (pymoo 0.6.2 draws everything from ``algorithm.random_state``, a
``numpy.random.Generator``; global state is untouched, as the tests check). pymoo's own
termination is disabled: the harness owns the budget.
"""

from __future__ import annotations

import numpy as np

from optimizers.base import BestTracker, OptimizerError, check_bounds
from optimizers.registry import register


class _PymooAdapter:
    """Shared translation between a pymoo single-objective algorithm and ask/tell."""

    def __init__(self, lower, upper, seed: int, algorithm) -> None:
        from pymoo.core.evaluator import Evaluator
        from pymoo.core.problem import Problem
        from pymoo.problems.static import StaticProblem
        from pymoo.core.termination import NoTermination

        self.lower, self.upper = check_bounds(lower, upper)
        self._problem = Problem(n_var=self.lower.size, n_obj=1, xl=self.lower, xu=self.upper)
        self._static = StaticProblem
        self.algorithm = algorithm
        self.algorithm.seed = int(seed)
        self.algorithm.evaluator = Evaluator()
        self.algorithm.setup(self._problem, termination=NoTermination(), verbose=False)
        self._pending = None
        self._best = BestTracker(self.lower.size)

    def ask(self) -> np.ndarray:
        if self._pending is not None:
            raise OptimizerError(f"{self.registered_name}: ask() called twice without tell()")
        self._pending = self.algorithm.ask()
        if self._pending is None or len(self._pending) == 0:
            raise OptimizerError(f"{self.registered_name}: pymoo produced no infill (population collapsed)")
        return np.clip(self._pending.get("X"), self.lower, self.upper)

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        pop, self._pending = self._pending, None
        f = np.asarray(f, float).ravel()
        if pop is None or f.shape != (len(pop),):
            raise OptimizerError(f"{self.registered_name}: tell() needs f of the last ask, got {f.shape}")
        f = np.where(np.isnan(f), np.inf, f)  # NaN ranks as worst
        self.algorithm.evaluator.eval(self._static(self._problem, F=f[:, None]), pop)
        self.algorithm.tell(infills=pop)
        self._best.update(X, f)

    @property
    def stop(self) -> str | None:
        return None  # pymoo's own termination is off; these run until the budget ends

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f


@register("pso")
class PymooPSO(_PymooAdapter):
    """pymoo's PSO (``pymoo.algorithms.soo.nonconvex.pso.PSO``); the batch is the swarm.

    pop_size: particles; w, c1, c2: inertia and acceleration; adaptive: pymoo's adaptive
    w/c1/c2 schedule; max_velocity_rate: speed limit as a fraction of each bound's span.

    >>> opt = PymooPSO([0, 0], [1, 1], seed=0, pop_size=5)
    >>> X = opt.ask(); opt.tell(X, (X ** 2).sum(axis=1)); X.shape
    (5, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, pop_size: int = 25, w: float = 0.9,
                 c1: float = 2.0, c2: float = 2.0, adaptive: bool = True,
                 max_velocity_rate: float = 0.2) -> None:
        from pymoo.algorithms.soo.nonconvex.pso import PSO

        super().__init__(lower, upper, seed, PSO(pop_size=int(pop_size), w=w, c1=c1, c2=c2,
                                                 adaptive=bool(adaptive), max_velocity_rate=max_velocity_rate))


@register("ga")
class PymooGA(_PymooAdapter):
    """pymoo's real-coded GA (tournament selection, SBX crossover, polynomial mutation,
    fitness survival); the batch is one generation of ``n_offsprings`` children
    (default ``pop_size``; after duplicate elimination it can be a few smaller).

    >>> opt = PymooGA([0, 0], [1, 1], seed=0, pop_size=6)
    >>> X = opt.ask(); opt.tell(X, (X ** 2).sum(axis=1)); X.shape
    (6, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, pop_size: int = 50, n_offsprings: int | None = None,
                 sbx_prob: float = 0.9, sbx_eta: float = 15.0, pm_eta: float = 20.0,
                 eliminate_duplicates: bool = True) -> None:
        from pymoo.algorithms.soo.nonconvex.ga import GA
        from pymoo.operators.crossover.sbx import SBX
        from pymoo.operators.mutation.pm import PM

        super().__init__(lower, upper, seed, GA(
            pop_size=int(pop_size), n_offsprings=None if n_offsprings is None else int(n_offsprings),
            crossover=SBX(prob=sbx_prob, eta=sbx_eta), mutation=PM(eta=pm_eta),
            eliminate_duplicates=bool(eliminate_duplicates)))
