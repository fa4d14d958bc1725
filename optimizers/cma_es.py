"""CMA-ES from the ``cmaes`` package (``cmaes.CMA`` with box bounds).

Chosen over pymoo's CMAES, which wraps the ``cma`` library: there seed 0 means "seed from the
clock" and it reseeds numpy's global generator. ``cmaes.CMA`` owns a ``RandomState(seed)``.
The search runs in normalised coordinates ``u = (x - lower) / (upper - lower)`` so one step
size ``sigma0`` fits variables in pixels, degrees and metres alike.
"""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell
from optimizers.registry import register


@register("cmaes")
class CmaEs(AskTell):
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

        super().__init__(lower, upper)
        sigma0 = self.float_param("sigma0", sigma0, 0, low_open=True)
        popsize = None if population_size is None else self.int_param("population_size", population_size, 2)
        mean = np.full(self.dim, 0.5) if x0 is None else self.to_unit(x0)
        # cmaes needs a seed in [0, 2**32); any int >= 0 the harness passes maps there reproducibly
        self._cma = CMA(mean=mean, sigma=sigma0, bounds=np.tile([0.0, 1.0], (self.dim, 1)),
                        seed=self.seed_param(seed) % 2**32, population_size=popsize)
        self._U: np.ndarray | None = None

    def _ask(self) -> np.ndarray:
        self._U = np.array([self._cma.ask() for _ in range(self._cma.population_size)])
        return self.from_unit(self._U)

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        self._cma.tell(list(zip(self._U, f)))  # NaN arrives as +inf: CMA-ES only uses the ranking

    @property
    def stop(self) -> str | None:
        if self._cma.should_stop():
            return f"converged: cmaes should_stop() at generation {self._cma.generation}"
        return None
