"""scipy's Nelder–Mead and L-BFGS-B behind ask/tell: stencil batches, gradients, convergence, cleanup."""

from __future__ import annotations

import gc
import threading
import time

import numpy as np
import pytest

from optimizers import OptimizerError
from optimizers.scipy_local import LBfgsB, NelderMead, _fd_gradient, _stencil

LOWER = np.array([700.0, -100.0, 0.8, -0.5])
UPPER = np.array([740.0, -80.0, 1.3, -0.1])
TARGET = np.array([0.3, 0.7, 0.45, 0.6])  # minimum, in normalised units
X0 = LOWER + 0.5 * (UPPER - LOWER)


def _quadratic(X: np.ndarray) -> np.ndarray:
    u = (X - LOWER) / (UPPER - LOWER)
    return np.sum(np.array([1.0, 4.0, 0.5, 2.0]) * (u - TARGET) ** 2, axis=1)


def _solve(opt, max_evals: int = 5000):
    n = 0
    while opt.stop is None and n < max_evals:
        X = opt.ask()
        opt.tell(X, _quadratic(X))
        n += len(X)
    return n


@pytest.mark.parametrize("central, size", [(False, 5), (True, 9)])
def test_lbfgsb_asks_the_whole_fd_stencil_as_one_batch(central, size):
    opt = LBfgsB(LOWER, UPPER, seed=0, x0=X0, central=central)
    X = opt.ask()
    assert X.shape == (size, 4)
    np.testing.assert_allclose(X[0], X0)  # the centre comes first


def test_fd_gradient_matches_the_analytic_gradient():
    weights = np.array([1.0, 4.0, 0.5, 2.0])
    u = np.array([0.2, 1.0, 0.5, 0.0])  # one coordinate on the upper wall, one on the lower
    grad = 2 * weights * (u - TARGET)
    for central in (False, True):
        U = _stencil(1e-6, central)(u)
        assert np.all((U >= 0) & (U <= 1))
        f = np.sum(weights * (U - TARGET) ** 2, axis=1)
        np.testing.assert_allclose(_fd_gradient(U, f), grad, atol=1e-4)


@pytest.mark.parametrize("cls, params, outcome", [
    (LBfgsB, {"central": True}, "converged"),  # central differences are exact on a quadratic
    (LBfgsB, {}, ""),  # forward differences are O(fd_step) off, so scipy may end on ABNORMAL line search
    (NelderMead, {}, "converged"),
])
def test_converges_to_an_interior_minimum_and_stops(cls, params, outcome):
    opt = cls(LOWER, UPPER, seed=0, x0=X0, **params)
    _solve(opt)
    assert opt.stop is not None and opt.stop.startswith(outcome)
    x, f = opt.best
    np.testing.assert_allclose((x - LOWER) / (UPPER - LOWER), TARGET, atol=2e-3)
    assert f < 1e-5
    with pytest.raises(OptimizerError, match="stopped"):
        opt.ask()


def test_nelder_mead_asks_one_point_and_starts_at_x0():
    opt = NelderMead(LOWER, UPPER, seed=0, x0=X0)
    X = opt.ask()
    assert X.shape == (1, 4)
    np.testing.assert_allclose(X[0], X0)


def test_lbfgsb_respects_bounds_when_the_minimum_is_outside():
    opt = LBfgsB(LOWER, UPPER, seed=0, x0=X0)
    def shift(X):
        return np.sum(((X - LOWER) / (UPPER - LOWER) - 1.7) ** 2, axis=1)
    while opt.stop is None:
        X = opt.ask()
        assert np.all((X >= LOWER) & (X <= UPPER))
        opt.tell(X, shift(X))
    np.testing.assert_allclose(opt.best[0], UPPER)


def test_nonfinite_values_do_not_break_the_line_search():
    opt = LBfgsB(LOWER, UPPER, seed=0, x0=X0)
    n = 0
    while opt.stop is None and n < 3000:
        X = opt.ask()
        f = _quadratic(X)
        f[(X[:, 0] > 730)] = np.nan  # a "diverged" region of the box
        opt.tell(X, f)
        n += len(X)
    assert np.isfinite(opt.best[1]) and opt.best[0][0] <= 730


def test_dropping_an_optimiser_mid_run_ends_its_worker_thread():
    before = threading.active_count()
    for _ in range(3):
        opt = LBfgsB(LOWER, UPPER, seed=0, x0=X0)
        X = opt.ask()
        opt.tell(X, _quadratic(X))
        opt.ask()  # abandoned with a batch outstanding, as the harness does at the budget
        del opt
        opt = NelderMead(LOWER, UPPER, seed=0, x0=X0)
        del opt
    gc.collect()
    deadline = time.monotonic() + 5
    while threading.active_count() > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert threading.active_count() == before


def test_close_is_explicit_and_idempotent():
    opt = NelderMead(LOWER, UPPER, seed=0, x0=X0)
    opt.close()
    opt.close()
    assert opt.stop == "closed"
