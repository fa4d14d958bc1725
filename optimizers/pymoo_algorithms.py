"""pymoo's PSO and GA behind the ask/tell contract (pymoo 0.6 ``algorithm.ask()/tell(infills=...)``).

Values come back through ``StaticProblem`` and the algorithm's own ``evaluator``, so pymoo's
evaluation counter (``algorithm.evaluator.n_eval``) advances as in ``minimize``. The algorithm
is seeded with ``seed`` (pymoo 0.6.2 draws everything from ``algorithm.random_state``, a
``numpy.random.Generator``; global state is untouched, as the tests check). pymoo's own
termination is disabled: the harness owns the budget.
"""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell, OptimizerError
from optimizers.registry import register


class _PymooAdapter(AskTell):
    """Shared translation between a pymoo single-objective algorithm and ask/tell."""

    def __init__(self, lower, upper, seed: int, make_algorithm) -> None:
        from pymoo.core.evaluator import Evaluator
        from pymoo.core.problem import Problem
        from pymoo.core.termination import NoTermination
        from pymoo.problems.static import StaticProblem

        super().__init__(lower, upper)
        seed = self.seed_param(seed)
        self._problem = Problem(n_var=self.dim, n_obj=1, xl=self.lower, xu=self.upper)
        self._static = StaticProblem
        self.algorithm = make_algorithm()
        self.algorithm.seed = seed
        self.algorithm.evaluator = Evaluator()
        self.algorithm.setup(self._problem, termination=NoTermination(), verbose=False)
        self._pop = None

    def _ask(self) -> np.ndarray:
        self._pop = self.algorithm.ask()
        if self._pop is None or len(self._pop) == 0:
            raise OptimizerError(f"{self.registered_name}: pymoo produced no infill (population collapsed)")
        return self._pop.get("X")

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        self.algorithm.evaluator.eval(self._static(self._problem, F=f[:, None]), self._pop)  # NaN arrives as +inf
        self.algorithm.tell(infills=self._pop)

    @property
    def stop(self) -> str | None:
        return None  # pymoo's own termination is off; these run until the budget ends


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

        pop_size = self.int_param("pop_size", pop_size, 2)
        w, c1, c2 = (self.float_param(k, v, 0) for k, v in (("w", w), ("c1", c1), ("c2", c2)))
        adaptive = self.bool_param("adaptive", adaptive)
        rate = self.float_param("max_velocity_rate", max_velocity_rate, 0, 1, low_open=True)
        super().__init__(lower, upper, seed, lambda: PSO(pop_size=pop_size, w=w, c1=c1, c2=c2, adaptive=adaptive,
                                                         max_velocity_rate=rate))


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

        pop_size = self.int_param("pop_size", pop_size, 2)
        n_offsprings = None if n_offsprings is None else self.int_param("n_offsprings", n_offsprings, 1)
        sbx_prob = self.float_param("sbx_prob", sbx_prob, 0, 1)
        sbx_eta = self.float_param("sbx_eta", sbx_eta, 0, low_open=True)
        pm_eta = self.float_param("pm_eta", pm_eta, 0, low_open=True)
        eliminate_duplicates = self.bool_param("eliminate_duplicates", eliminate_duplicates)
        super().__init__(lower, upper, seed, lambda: GA(
            pop_size=pop_size, n_offsprings=n_offsprings, crossover=SBX(prob=sbx_prob, eta=sbx_eta),
            mutation=PM(eta=pm_eta), eliminate_duplicates=eliminate_duplicates))
