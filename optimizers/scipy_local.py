"""Local baselines from the reference point: scipy's Nelder–Mead and L-BFGS-B, as ask/tell.

Design: ``scipy.optimize.minimize`` is a blocking call that pulls values through its objective.
Re-implementing its iterations would fork scipy's code, and its reverse-communication pieces
are private, so the plugin runs ``minimize`` unchanged in a worker thread whose objective hands
each batch to ``ask`` and waits for ``tell`` (two one-slot queues; strictly alternating, so the
sequence of asked points is deterministic). Dropping or ``close()``-ing the optimiser sends an
abort that unwinds the worker. Both methods work in normalised coordinates
``u = (x - lower) / (upper - lower)`` in [0, 1]^d so steps and tolerances mean the same for
pixels, degrees and metres.
"""

from __future__ import annotations

import queue
import threading

import numpy as np

from optimizers.base import AskTell, OptimizerError, check_bounds
from optimizers.registry import register


class _Abort(Exception):
    """Sent into the worker's objective to unwind ``minimize`` when the optimiser is dropped."""


class _ThreadedMinimize(AskTell):
    """Runs ``minimize(objective, u0, ...)`` in a thread; the objective's batches become asks."""

    nonfinite = "worst"  # scipy needs finite numbers: a NaN/inf is told as the worst finite value

    def __init__(self, lower, upper, x0, method: str, options: dict, jac: bool, stencil) -> None:
        from scipy.optimize import minimize

        super().__init__(lower, upper)
        x0 = (self.lower + self.upper) / 2 if x0 is None else np.asarray(x0, float)
        u0 = self.to_unit(x0)
        self._stop: str | None = None
        self._next: np.ndarray | None = None  # the batch the worker's objective is waiting on
        asks, tells = queue.Queue(maxsize=1), queue.Queue(maxsize=1)
        self._asks, self._tells = asks, tells
        bounds = [(0.0, 1.0)] * self.lower.size

        # the worker holds only the queues (not self), so dropping the optimiser triggers __del__
        def objective(u):
            U = stencil(np.clip(u, 0.0, 1.0))
            asks.put(("batch", U))
            f = tells.get()
            if f is None:
                raise _Abort
            return f[0] if not jac else (f[0], _fd_gradient(U, f))

        def work():
            try:
                res = minimize(objective, u0, method=method, jac=jac or None, bounds=bounds, options=options)
                outcome = "converged" if res.success else "stopped"
                asks.put(("done", f"{outcome}: scipy {method}: {res.message} (nit={res.nit}, nfev={res.nfev})"))
            except _Abort:
                pass
            except Exception as err:
                asks.put(("error", f"scipy {method} failed: {type(err).__name__}: {err}"))

        threading.Thread(target=work, daemon=True, name=f"scipy-{method}").start()
        self._receive()

    def _receive(self) -> None:
        kind, payload = self._asks.get()
        if kind == "batch":
            self._next = payload
        elif kind == "done":
            self._stop = payload
        else:
            raise OptimizerError(payload)

    def _ask(self) -> np.ndarray:
        if self._stop is not None:
            raise OptimizerError(f"{self.registered_name}: ask() after the optimiser stopped ({self._stop})")
        U, self._next = self._next, None
        return self.from_unit(U)

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        self._tells.put(f)
        self._receive()

    def close(self) -> None:
        """Unwind the worker thread (also done when the optimiser is garbage-collected)."""
        if getattr(self, "_stop", "") is None:  # the worker is waiting in its objective for a tell
            self._stop = "closed"
            self._tells.put(None)

    def __del__(self) -> None:
        self.close()

    @property
    def stop(self) -> str | None:
        return self._stop


def _fd_gradient(U: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Gradient from a stencil whose row 0 is the centre and rows 1.. are ±h e_i steps (see ``_stencil``)."""
    d = U.shape[1]
    steps = U[1:] - U[0]
    if len(U) == d + 1:  # forward (or backward at the upper wall) differences
        return (f[1:] - f[0]) / np.diag(steps)
    return (f[1 : d + 1] - f[d + 1 :]) / (np.diag(steps[:d]) - np.diag(steps[d:]))  # central


def _stencil(step: float, central: bool):
    """Batch maker: centre u, then u + h e_i (u - h e_i where u + h leaves the box); central adds u - h e_i."""

    def make(u: np.ndarray) -> np.ndarray:
        h = np.where(u + step <= 1.0, step, -step)
        plus = u + np.diag(h)
        if not central:
            return np.vstack([u, plus])
        minus = np.clip(u - np.diag(h), 0.0, 1.0)  # at a wall the central step is one-sided
        return np.vstack([u, plus, minus])

    return make


@register("lbfgsb")
class LBfgsB(_ThreadedMinimize):
    """L-BFGS-B from ``x0`` with a finite-difference gradient evaluated as ONE batch.

    The batch is the stencil: the centre and one step per variable (d + 1 points, forward
    differences) or a step each way (2d + 1, ``central=True``). ``fd_step`` is the step in
    units of the box width (1e-3: large enough to see through a noisy simulation objective,
    small against the box). ``ftol``/``gtol``/``maxiter`` are scipy's options.

    >>> opt = LBfgsB([0, 0], [1, 1], seed=0, x0=[0.3, 0.6])
    >>> X = opt.ask(); X.shape
    (3, 2)
    >>> opt.tell(X, ((X - 0.5) ** 2).sum(axis=1))
    """

    def __init__(self, lower, upper, seed: int, x0=None, fd_step: float = 1e-3, central: bool = False,
                 ftol: float = 1e-9, gtol: float = 1e-6, maxiter: int = 1000) -> None:
        self.seed_param(seed)  # unused (deterministic from x0) but still a valid seed
        fd_step = self.float_param("fd_step", fd_step, 0, 0.5, low_open=True, high_open=True)
        options = {"ftol": self.float_param("ftol", ftol, 0), "gtol": self.float_param("gtol", gtol, 0),
                   "maxiter": self.int_param("maxiter", maxiter, 1)}
        super().__init__(lower, upper, x0, "L-BFGS-B", options, jac=True,
                         stencil=_stencil(fd_step, self.bool_param("central", central)))


@register("nelder_mead")
class NelderMead(_ThreadedMinimize):
    """Nelder–Mead (scipy, bounded) from ``x0``; the batch is one point (the method is sequential).

    The initial simplex is ``x0`` plus ``initial_step`` (box widths) along each axis, stepping
    inwards at a wall. ``xatol``/``fatol`` (normalised x, f units) and ``maxfev`` are scipy's options.

    >>> opt = NelderMead([0, 0], [1, 1], seed=0, x0=[0.3, 0.6])
    >>> X = opt.ask(); X.shape
    (1, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, initial_step: float = 0.1, xatol: float = 1e-4,
                 fatol: float = 1e-6, maxfev: int = 100_000) -> None:
        self.seed_param(seed)  # unused (deterministic from x0) but still a valid seed
        initial_step = self.float_param("initial_step", initial_step, 0, 0.5, low_open=True)
        xatol, fatol = self.float_param("xatol", xatol, 0), self.float_param("fatol", fatol, 0)
        maxfev = self.int_param("maxfev", maxfev, 1)
        lo, hi = check_bounds(lower, upper)
        u0 = np.clip((np.asarray((lo + hi) / 2 if x0 is None else x0, float) - lo) / (hi - lo), 0.0, 1.0)
        h = np.where(u0 + initial_step <= 1.0, initial_step, -initial_step)
        simplex = np.vstack([u0, u0 + np.diag(h)])
        super().__init__(lower, upper, x0, "Nelder-Mead",
                         {"initial_simplex": simplex, "xatol": xatol, "fatol": fatol, "maxfev": maxfev},
                         jac=False, stencil=lambda u: u[None, :])
