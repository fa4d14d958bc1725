"""CMA-ES from the ``cmaes`` package (``cmaes.CMA`` with box bounds).

Chosen over pymoo's CMAES, which wraps the ``cma`` library: there seed 0 means "seed from the
clock" and it reseeds numpy's global generator. ``cmaes.CMA`` owns a ``RandomState(seed)``.
The search runs in normalised coordinates ``u = (x - lower) / (upper - lower)`` so one step
size ``sigma0`` fits variables in pixels, degrees and metres alike.
"""

from __future__ import annotations

import numpy as np

from optimizers.base import BestTracker, OptimizerError, check_bounds
from optimizers.registry import register


@register("cmaes")
class CmaEs:
    """CMA-ES; the batch is one generation (``population_size`` points, default 4 + 3 ln d).

    Starts at ``x0`` when given (the reference calibration), else at the box centre, with step
    ``sigma0`` in units of the box width. Stops when ``cmaes`` reports convergence
    (``should_stop``: tolerances on f, x, or a degenerate covariance).

    >>> opt = CmaEs([0, 0], [1, 1], seed=0, population_size=6)
    >>> X = opt.ask(); opt.tell(X, (X ** 2).sum(axis=1)); X.shape
    (6, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, sigma0: float = 0.3,
                 population_size: int | None = None) -> None:
        from cmaes import CMA

        self.lower, self.upper = check_bounds(lower, upper)
        d = self.lower.size
        if not sigma0 > 0:
            raise OptimizerError(f"cmaes: sigma0 must be > 0 (fraction of the box), got {sigma0}")
        self._span = self.upper - self.lower
        mean = np.full(d, 0.5) if x0 is None else (np.asarray(x0, float) - self.lower) / self._span
        mean = np.clip(mean, 0.0, 1.0)
        # cmaes needs a seed in [0, 2**32); any int the harness passes maps there reproducibly
        popsize = None if population_size is None else int(population_size)
        self._cma = CMA(mean=mean, sigma=float(sigma0), bounds=np.tile([0.0, 1.0], (d, 1)),
                        seed=int(seed) % 2**32, population_size=popsize)
        self._pending: np.ndarray | None = None
        self._best = BestTracker(d)

    def ask(self) -> np.ndarray:
        if self._pending is not None:
            raise OptimizerError("cmaes: ask() called twice without tell()")
        self._pending = np.array([self._cma.ask() for _ in range(self._cma.population_size)])
        return np.clip(self.lower + self._pending * self._span, self.lower, self.upper)  # clip rounding

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        U, self._pending = self._pending, None
        f = np.asarray(f, float).ravel()
        if U is None or f.shape != (len(U),):
            raise OptimizerError(f"cmaes: tell() needs the f of the last ask "
                                 f"({self._cma.population_size},), got {f.shape}")
        f = np.where(np.isnan(f), np.inf, f)  # NaN ranks as worst; CMA-ES only uses the ranking
        self._cma.tell(list(zip(U, f)))
        self._best.update(X, f)

    @property
    def stop(self) -> str | None:
        if self._cma.should_stop():
            return f"converged: cmaes should_stop() at generation {self._cma.generation}"
        return None

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best.x, self._best.f
