"""The paper's PSO–GA: stop rules fire exactly when their condition holds; the GA keeps the best."""

from __future__ import annotations

import numpy as np
import pytest

from optimizers import OptimizerError
from optimizers.psoga import PsoGa

LOWER = np.array([700.0, -100.0, 0.8, -0.5, 170.0])
UPPER = np.array([740.0, -80.0, 1.3, -0.1, 200.0])


def _normalised(x: np.ndarray) -> np.ndarray:
    return (x - LOWER) / (UPPER - LOWER)


def _iterate(opt: PsoGa, values) -> None:
    """One PSO–GA iteration (PSO batch, GA batch), f from ``values(X)``."""
    for _ in range(2):
        X = opt.ask()
        opt.tell(X, values(X))


def test_paper_rule_fires_exactly_when_best_moves_less_than_epsilon():
    opt = PsoGa(LOWER, UPPER, seed=3, pop_size=10, stop_rule="paper", epsilon=1e-3)
    counter = iter(range(10**6))
    # every new point beats all before it, so the best jumps to a fresh point each iteration ...
    def improving(X):
        return -np.array([next(counter) for _ in range(len(X))], float)
    X = opt.ask()
    opt.tell(X, improving(X))
    moves = []
    for _ in range(4):
        before = _normalised(opt.best[0])
        _iterate(opt, improving)
        du = _normalised(opt.best[0]) - before
        moves.append(float(du @ du))
        assert (opt.stop is not None) == (du @ du <= 1e-3)
    assert opt.stop is None and min(moves) > 1e-3  # the rule was really tested on moving bests
    # ... then nothing beats the best: Δu = 0 and the rule must fire at this very iteration
    _iterate(opt, lambda X: np.full(len(X), 1e9))
    assert opt.stop is not None and "epsilon" in opt.stop
    assert opt.iterations == 5


def test_paper_rule_measures_the_move_in_normalised_units():
    # rescaling one variable's unit (metres -> millimetres) must not change when the rule fires
    def stop_iteration(lower, upper):
        opt = PsoGa(lower, upper, seed=1, pop_size=6, stop_rule="paper", epsilon=1e-3)
        def f(X):
            return np.linalg.norm((X - lower) / (upper - lower) - 0.4, axis=1)
        X = opt.ask()
        opt.tell(X, f(X))
        while opt.stop is None and opt.iterations < 200:
            _iterate(opt, f)
        return opt.iterations, opt.best[1]

    scale = np.ones(LOWER.size)
    scale[2] = 1000.0
    baseline = stop_iteration(LOWER, UPPER)
    assert 1 <= baseline[0] < 200
    rescaled = stop_iteration(LOWER * scale, UPPER * scale)
    assert rescaled[0] == baseline[0] and rescaled[1] == pytest.approx(baseline[1])


@pytest.mark.parametrize("patience", [1, 3, 5])
def test_patience_rule_fires_after_exactly_patience_stale_iterations(patience):
    opt = PsoGa(LOWER, UPPER, seed=0, pop_size=8, stop_rule="patience", patience=patience, tol=1e-6)
    X = opt.ask()
    opt.tell(X, np.full(8, 5.0))
    for k in range(1, patience + 1):
        _iterate(opt, lambda X: np.full(len(X), 5.0))  # nothing ever improves
        assert (opt.stop is not None) == (k == patience)
    assert "patience" in opt.stop or str(patience) in opt.stop


def test_patience_rule_does_not_fire_while_improving():
    opt = PsoGa(LOWER, UPPER, seed=0, pop_size=8, stop_rule="patience", patience=2)
    level = iter(np.geomspace(100, 1, 50))
    X = opt.ask()
    opt.tell(X, np.full(8, 200.0))
    for _ in range(10):
        _iterate(opt, lambda X: np.full(len(X), next(level)))
        assert opt.stop is None


def test_ga_step_keeps_the_best_population():
    opt = PsoGa(LOWER, UPPER, seed=11, pop_size=12, stop_rule="none")
    rng = np.random.default_rng(0)
    X = opt.ask()
    opt.tell(X, rng.random(12))
    X = opt.ask()  # PSO step
    opt.tell(X, rng.random(12))
    swarm_x, swarm_f = X.copy(), opt.f.copy()
    children = opt.ask()  # GA step
    f_children = rng.random(12)
    opt.tell(children, f_children)
    union_f = np.concatenate([swarm_f, f_children])
    np.testing.assert_allclose(np.sort(opt.f), np.sort(union_f)[:12])
    union_x = np.vstack([swarm_x, children])
    kept_x = opt.lower + opt.u * (opt.upper - opt.lower)
    for x, f in zip(kept_x, opt.f):  # every survivor is a told point with its own value
        i = np.flatnonzero(np.all(np.isclose(union_x, x), axis=1))
        assert i.size and np.isclose(union_f[i[0]], f)


def test_batches_alternate_pso_and_ga_and_have_pop_size_rows():
    opt = PsoGa(LOWER, UPPER, seed=2, pop_size=14)
    for phase in ("init", "pso", "ga", "pso", "ga"):
        assert opt._phase == phase
        X = opt.ask()
        assert X.shape == (14, LOWER.size)
        opt.tell(X, np.sum(_normalised(X) ** 2, axis=1))


@pytest.mark.parametrize("bad", [{"pop_size": 7}, {"pop_size": 0}, {"stop_rule": "never"}, {"v_max": 0},
                                 {"patience": 0}])
def test_bad_hyperparameters_are_rejected(bad):
    with pytest.raises(OptimizerError):
        PsoGa(LOWER, UPPER, seed=0, **bad)
