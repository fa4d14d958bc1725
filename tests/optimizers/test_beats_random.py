"""The population methods beat uniform random search on the 10-D analytic problems (paper bounds)."""

from __future__ import annotations

import numpy as np
import pytest
from _loop import run_loop

from bench import problems
from optimizers import registry

SEEDS = range(10)
BUDGET = 1000
# TPE costs ~0.7 s per run at 200 evaluations but ~9 s at 1,000 (its model is refitted on every
# trial), too slow for 30 runs here. Its best-so-far can only fall with more evaluations, and a
# run's first 200 asks do not depend on the budget, so "TPE at 200 beats random at 1,000" is a
# stronger check that implies the 1,000-evaluation claim.
BUDGETS = {"psoga": BUDGET, "pso": BUDGET, "ga": BUDGET, "cmaes": BUDGET, "tpe": 200}


def _median_best(name: str, problem, budget: int) -> float:
    space = problem.space
    runs = [run_loop(registry.get(name)(space.lower, space.upper, seed=s, x0=space.reference), problem, budget)[0]
            for s in SEEDS]
    return float(np.median(runs))


@pytest.mark.slow
@pytest.mark.parametrize("problem_name", ["sphere", "rastrigin", "rosenbrock"])
def test_each_method_beats_random_search_in_median_best_f(problem_name):
    problem = problems.get(problem_name)()
    floor = _median_best("random", problem, BUDGET)
    medians = {name: _median_best(name, problem, budget) for name, budget in BUDGETS.items()}
    losers = {name: m for name, m in medians.items() if not m < floor}
    assert not losers, f"{problem_name}: random median {floor:.4g}; not beaten by {losers} (all: {medians})"


def test_run_loop_trims_the_last_batch_to_the_budget_and_does_not_tell_it():
    problem = problems.get("sphere")()
    told = []

    class Recorder:
        stop = None

        def ask(self):
            return np.tile(problem.space.reference, (7, 1))

        def tell(self, X, f):
            told.append(len(X))

    best, n_evals, asked = run_loop(Recorder(), problem, 30)
    assert n_evals == 30 and len(asked) == 5 and told == [7, 7, 7, 7]
