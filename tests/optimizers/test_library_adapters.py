"""Library-specific behaviour of the thin adapters (pymoo, cmaes, optuna, nevergrad)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from optimizers import OptimizerError
from optimizers.cma_es import CmaEs
from optimizers.nevergrad_optimizer import Nevergrad
from optimizers.pymoo_algorithms import PymooGA, PymooPSO
from optimizers.tpe import Tpe

LOWER = np.array([0.0, -5.0, 100.0])
UPPER = np.array([1.0, 5.0, 300.0])


def _f(X):
    return np.sum(((X - LOWER) / (UPPER - LOWER) - 0.25) ** 2, axis=1)


@pytest.mark.parametrize("cls", [PymooPSO, PymooGA])
def test_pymoo_evaluation_counter_advances_with_every_tell(cls):
    opt = cls(LOWER, UPPER, seed=0, pop_size=10)
    told = 0
    for _ in range(4):
        X = opt.ask()
        opt.tell(X, _f(X))
        told += len(X)
        assert opt.algorithm.evaluator.n_eval == told
    assert opt.algorithm.n_iter == 5  # pymoo's iteration counter moved on as in minimize()


def test_pymoo_pso_batch_is_the_swarm():
    opt = PymooPSO(LOWER, UPPER, seed=0, pop_size=13)
    for _ in range(3):
        X = opt.ask()
        assert X.shape == (13, 3)
        opt.tell(X, _f(X))


def test_cmaes_starts_at_x0_in_the_box_and_stops_on_a_flat_function():
    x0 = np.array([0.9, 4.0, 120.0])
    opt = CmaEs(LOWER, UPPER, seed=0, x0=x0, sigma0=0.05)
    X = opt.ask()
    assert X.shape == (7, 3)  # 4 + 3 ln 3 -> 7
    assert np.all(np.abs(X.mean(axis=0) - x0) < 0.15 * (UPPER - LOWER))
    opt.tell(X, np.ones(len(X)))
    for _ in range(500):
        if opt.stop:
            break
        X = opt.ask()
        opt.tell(X, np.ones(len(X)))
    assert opt.stop is not None and opt.stop.startswith("converged")


def test_cmaes_seed_zero_is_reproducible_not_clock_seeded():
    a, b = CmaEs(LOWER, UPPER, seed=0), CmaEs(LOWER, UPPER, seed=0)
    np.testing.assert_array_equal(a.ask(), b.ask())


def test_tpe_asks_batch_size_trials_and_silences_optuna():
    opt = Tpe(LOWER, UPPER, seed=0, batch_size=5, n_startup_trials=5)
    for _ in range(3):
        X = opt.ask()
        assert X.shape == (5, 3)
        opt.tell(X, _f(X))
    assert logging.getLogger("optuna").getEffectiveLevel() >= logging.WARNING
    assert len(opt._study.trials) == 15
    assert all(t.state.name == "COMPLETE" for t in opt._study.trials)


def test_tpe_keeps_nan_trials_in_the_model_as_worst():
    opt = Tpe(LOWER, UPPER, seed=0, batch_size=4)
    X = opt.ask()
    opt.tell(X, np.array([np.nan, 1.0, np.inf, 2.0]))
    values = [t.value for t in opt._study.trials]
    assert values == [2.0, 1.0, 2.0, 2.0]


def test_nevergrad_unknown_name_lists_valid_names():
    with pytest.raises(OptimizerError, match="NGOpt"):
        Nevergrad(LOWER, UPPER, seed=0, name="NoSuchOptimizer")


@pytest.mark.parametrize("name", ["DE", "OnePlusOne", "CMA"])
def test_nevergrad_runs_any_registry_name_with_num_workers_as_batch(name):
    opt = Nevergrad(LOWER, UPPER, seed=1, name=name, num_workers=6, budget=60)
    for _ in range(3):
        X = opt.ask()
        assert X.shape == (6, 3) and np.all((X >= LOWER) & (X <= UPPER))
        opt.tell(X, _f(X))
    assert opt.best[1] == pytest.approx(min(_f(opt.best[0][None])))


def test_the_first_nevergrad_plugin_built_in_a_process_leaves_the_global_rng_untouched():
    # in a fresh interpreter, so that nevergrad's import (which draws from numpy's global
    # generator) happens inside the plugin's constructor, whatever ran before in this process
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from optimizers.nevergrad_optimizer import Nevergrad\n"
            "np.random.seed(12345); before = np.random.get_state()\n"
            "Nevergrad(np.zeros(3), np.ones(3), seed=1)\n"
            "after = np.random.get_state()\n"
            "print(before[2] == after[2] and bool((before[1] == after[1]).all()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
