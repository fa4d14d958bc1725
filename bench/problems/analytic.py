"""Cheap analytic test problems on the paper's 10-D calibration bounds (Table 1).

Each function is evaluated on normalised coordinates ``u = (x - lower) / (upper - lower)``
shifted so that its minimum (f = 0) sits at the paper's PSO–GA point, inside the box and away
from its centre, so that no method is favoured by a centred optimum.

``instance`` (the sweep's ``instance``) draws COCO-style instances (Hansen et al. 2021, "COCO: a
platform for comparing continuous optimizers"): instance 0 is the plain function above; instance
k > 0 moves the optimum to u* drawn uniformly in [0.1, 0.9]^d and rotates the function about it,
``f(x) = g(Q scale (u - u*))`` with Q a uniformly drawn rotation (scipy's ``special_ortho_group``),
both from ``numpy.random.default_rng([k, crc32(name)])``, so that each function has its own draw.
"""

from __future__ import annotations

import time
import zlib

import numpy as np

from avio.reference import PAPER_TABLE1
from bench.problems.base import ProblemError, register
from bench.space import Space

_UNITS = {"fx": "px", "fy": "px", "cx": "px", "cy": "px", "roll": "deg", "pitch": "deg",
          "yaw": "deg", "tx": "m", "ty": "m", "tz": "m"}


def paper_box_space() -> Space:
    """The paper's Table 1 variables, bounds and reference."""
    names = tuple(PAPER_TABLE1)
    def col(i):
        return np.array([PAPER_TABLE1[n][i] for n in names])
    return Space(names, tuple(_UNITS[n] for n in names), col(1), col(2), col(0))


def _sphere(z: np.ndarray) -> np.ndarray:
    return np.sum(z**2, axis=1)


def _rastrigin(z: np.ndarray) -> np.ndarray:
    return 10.0 * z.shape[1] + np.sum(z**2 - 10.0 * np.cos(2 * np.pi * z), axis=1)


def _rosenbrock(z: np.ndarray) -> np.ndarray:
    y = z + 1.0  # minimum of the classic function is at y = 1
    return np.sum(100.0 * (y[:, 1:] - y[:, :-1] ** 2) ** 2 + (1.0 - y[:, :-1]) ** 2, axis=1)


_FUNCTIONS = {"sphere": (_sphere, 10.0), "rastrigin": (_rastrigin, 5.12), "rosenbrock": (_rosenbrock, 2.0)}


class AnalyticProblem:
    """``f(x) = g(scale * (u(x) - u*))`` for g in sphere/rastrigin/rosenbrock.

    delay_s_per_batch: optional sleep per evaluate() call (seconds), to imitate an expensive
    objective in harness-overhead benchmarks. instance: 0 the plain function, k > 0 a shifted and
    rotated one (module docstring).
    """

    f_unit = ""  # dimensionless

    def __init__(self, function: str, delay_s_per_batch: float = 0.0, instance: int = 0) -> None:
        if function not in _FUNCTIONS:
            raise ProblemError(f"unknown analytic function {function!r}; valid: {sorted(_FUNCTIONS)}")
        if not delay_s_per_batch >= 0:
            raise ProblemError(f"delay_s_per_batch must be >= 0, got {delay_s_per_batch}")
        if not isinstance(instance, int) or isinstance(instance, bool) or instance < 0:
            raise ProblemError(f"instance must be an integer >= 0, got {instance!r}")
        self.name = function
        self.instance = instance
        self.space = paper_box_space()
        self._g, self._scale = _FUNCTIONS[function]
        self._delay_s = float(delay_s_per_batch)
        self._span = self.space.upper - self.space.lower
        d = self.space.dim
        if instance == 0:
            self.truth = np.array([PAPER_TABLE1[n][3] for n in self.space.names])
            self._u_star = (self.truth - self.space.lower) / self._span
            self._rotation = np.eye(d)
        else:
            rng = np.random.default_rng([instance, zlib.crc32(function.encode())])
            self._u_star = rng.uniform(0.1, 0.9, d)
            from scipy.stats import special_ortho_group  # here: importing scipy.stats costs ~0.5 s of every job's start

            self._rotation = special_ortho_group.rvs(d, random_state=rng)
            self.truth = self.space.lower + self._u_star * self._span
        self.f_truth = 0.0
        self.f_reference = float(self.evaluate(self.space.reference[None])[0][0])

    @property
    def identity(self) -> dict:
        return {"function": self.name, "instance": self.instance, "optimum": self.truth.tolist(),
                "rotation": self._rotation.tolist()}

    def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """f (n,) and one metric: the distance to the optimum in normalised units."""
        X = self.space.check(X)
        if self._delay_s:
            time.sleep(self._delay_s)
        z = self._scale * ((X - self.space.lower) / self._span - self._u_star)
        if self.instance:
            z = z @ self._rotation.T
        dist = np.linalg.norm((X - self.truth) / self._span, axis=1)
        return self._g(z), {"distance_to_optimum": dist}


@register("sphere")
def sphere(delay_s_per_batch: float = 0.0, instance: int = 0) -> AnalyticProblem:
    return AnalyticProblem("sphere", delay_s_per_batch, instance)


@register("rastrigin")
def rastrigin(delay_s_per_batch: float = 0.0, instance: int = 0) -> AnalyticProblem:
    return AnalyticProblem("rastrigin", delay_s_per_batch, instance)


@register("rosenbrock")
def rosenbrock(delay_s_per_batch: float = 0.0, instance: int = 0) -> AnalyticProblem:
    return AnalyticProblem("rosenbrock", delay_s_per_batch, instance)
