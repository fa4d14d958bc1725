"""A small ask/tell loop for the optimiser tests (the harness's run loop comes later)."""

from __future__ import annotations

import numpy as np


def run_loop(opt, problem, max_evals: int) -> tuple[float, int, list[np.ndarray]]:
    """Drive ``opt`` on ``problem`` for at most ``max_evals`` evaluations.

    The last batch is trimmed to the budget and, like the harness, never told.
    Returns (best f, evaluations used, the list of asked batches).
    """
    n_evals, asked, best = 0, [], np.inf
    while n_evals < max_evals and opt.stop is None:
        X = opt.ask()
        asked.append(X.copy())
        trimmed = X[: max_evals - n_evals]
        f, _ = problem.evaluate(trimmed)
        n_evals += len(trimmed)
        best = min(best, float(np.min(f)))
        if len(trimmed) == len(X):
            opt.tell(X, f)
    return best, n_evals, asked
