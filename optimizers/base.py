"""The one batched ask/tell contract every optimiser plugin implements."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class OptimizerError(ValueError):
    """Invalid optimiser input (bounds, hyperparameters, a tell that does not match its ask)."""


@runtime_checkable
class Optimizer(Protocol):
    """A minimiser over the box ``[lower, upper]``, driven by the harness.

    Constructed as ``Cls(lower, upper, seed, x0=None, **hyperparameters)``: ``lower`` and
    ``upper`` are (d,) bounds, ``seed`` an int that fixes every random choice (the optimiser
    owns a ``numpy.random.Generator``; it never reads or seeds global state), ``x0`` an
    optional (d,) starting point (the reference calibration, for local methods).
    """

    def ask(self) -> np.ndarray:
        """The next batch ``X`` of shape (n, d), inside the bounds."""

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        """The objective values (n,) of the batch returned by the last ``ask``."""

    @property
    def stop(self) -> str | None:
        """Why the optimiser would stop on its own (e.g. ``"converged: ..."``), else None."""

    @property
    def best(self) -> tuple[np.ndarray, float]:
        """The best point told so far and its value."""


def check_bounds(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """Validated float copies of the bounds: same shape (d,), finite, ``lower < upper``."""
    lower = np.asarray(lower, float).ravel().copy()
    upper = np.asarray(upper, float).ravel().copy()
    if lower.shape != upper.shape or lower.size == 0:
        raise OptimizerError(f"bounds must be two (d,) arrays, got {lower.shape} and {upper.shape}")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise OptimizerError(f"bounds must be finite: lower={lower}, upper={upper}")
    bad = np.flatnonzero(lower >= upper)
    if bad.size:
        raise OptimizerError(f"lower >= upper for variable(s) {bad.tolist()}: lower={lower}, upper={upper}")
    return lower, upper


class BestTracker:
    """Keeps the best (x, f) seen in tells; a small helper for plugins without their own."""

    def __init__(self, d: int) -> None:
        self.x = np.full(d, np.nan)
        self.f = np.inf

    def update(self, X: np.ndarray, f: np.ndarray) -> None:
        f = np.where(np.isfinite(np.asarray(f, float)), f, np.inf)  # NaN/inf never become best
        if f.size and f.min() < self.f:
            i = int(np.argmin(f))
            self.x, self.f = np.array(X[i], float), float(f[i])


class WorstFiniteFill:
    """Replaces NaN/inf values by the worst finite value told so far (1e10 before any).

    For library optimisers that would drop a non-finite trial or average it into their model:
    as the worst value it still teaches them where not to go.
    """

    def __init__(self) -> None:
        self.worst = -np.inf

    def __call__(self, f: np.ndarray) -> np.ndarray:
        f = np.asarray(f, float)
        finite = np.isfinite(f)
        if finite.any():
            self.worst = max(self.worst, float(np.max(f[finite])))
        return np.where(finite, f, self.worst if np.isfinite(self.worst) else 1e10)
