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

from optimizers.base import BestTracker, OptimizerError, check_bounds
from optimizers.registry import register


class _Abort(Exception):
    """Sent into the worker's objective to unwind ``minimize`` when the optimiser is dropped."""


class _ThreadedMinimize:
    """Runs ``minimize(objective, u0, ...)`` in a thread; the objective's batches become asks."""

    def __init__(self, lower, upper, x0, method: str, options: dict, jac: bool, stencil) -> None:
        from scipy.optimize import minimize

        self.lower, self.upper = check_bounds(lower, upper)
        self._span = self.upper - self.lower
        x0 = (self.lower + self.upper) / 2 if x0 is None else np.asarray(x0, float)
        u0 = np.clip((x0 - self.lower) / self._span, 0.0, 1.0)
        self._best = BestTracker(self.lower.size)
        self._stop: str | None = None
        self._pending: np.ndarray | None = None
        self._asked: np.ndarray | None = None
        self._worst = -np.inf
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
            except Exception as err:  # noqa: BLE001 - re-raised in the caller's thread with context
                asks.put(("error", f"scipy {method} failed: {type(err).__name__}: {err}"))

        threading.Thread(target=work, daemon=True, name=f"scipy-{method}").start()
        self._receive()

    def _receive(self) -> None:
        kind, payload = self._asks.get()
        if kind == "batch":
            self._pending = payload
        elif kind == "done":
            self._stop = payload
        else:
            raise OptimizerError(payload)

    def ask(self) -> np.ndarray:
        if self._stop is not None:
            raise OptimizerError(f"{self.registered_name}: ask() after the optimiser stopped ({self._stop})")
        if self._pending is None:
            raise OptimizerError(f"{self.registered_name}: ask() called twice without tell()")
        U, self._asked, self._pending = self._pending, self._pending, None
        return np.clip(self.lower + U * self._span, self.lower, self.upper)  # clip rounding

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        f = np.asarray(f, float).ravel()
        if self._asked is None or f.shape != (len(self._asked),):
            raise OptimizerError(f"{self.registered_name}: tell() needs the f of the last ask, got {f.shape}")
        self._best.update(X, f)
        finite = np.isfinite(f)
        if finite.any():
            self._worst = max(self._worst, float(np.max(f[finite])))
        # scipy needs finite numbers: a NaN/inf becomes the worst finite value seen (1e10 before any)
        f = np.where(finite, f, self._worst if np.isfinite(self._worst) else 1e10)
        self._asked = None
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

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f


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
        d = u.size
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
        if not 0 < fd_step < 0.5:
            raise OptimizerError(f"lbfgsb: fd_step must be in (0, 0.5) box widths, got {fd_step}")
        super().__init__(lower, upper, x0, "L-BFGS-B", {"ftol": ftol, "gtol": gtol, "maxiter": int(maxiter)},
                         jac=True, stencil=_stencil(float(fd_step), bool(central)))


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
        if not 0 < initial_step <= 0.5:
            raise OptimizerError(f"nelder_mead: initial_step must be in (0, 0.5] box widths, got {initial_step}")
        lo, hi = check_bounds(lower, upper)
        u0 = np.clip((np.asarray((lo + hi) / 2 if x0 is None else x0, float) - lo) / (hi - lo), 0.0, 1.0)
        h = np.where(u0 + initial_step <= 1.0, initial_step, -initial_step)
        simplex = np.vstack([u0, u0 + np.diag(h)])
        super().__init__(lower, upper, x0, "Nelder-Mead",
                         {"initial_simplex": simplex, "xatol": xatol, "fatol": fatol, "maxfev": int(maxfev)},
                         jac=False, stencil=lambda u: u[None, :])
