"""The one batched ask/tell contract every optimiser plugin implements, and the base class that owns it.

A plugin subclasses ``AskTell`` and writes only its method: ``_ask()`` returns the next batch
and ``_tell(X, f)`` learns from its values. The base owns everything the harness relies on:

- the bounds (validated once, ``self.lower``/``self.upper``/``self.span``, all (d,)) and the
  map to and from the unit box (``to_unit``/``from_unit``); asks are clipped into the box;
- the ask/tell guards: ``ask()`` twice without ``tell()``, a ``tell()`` without an ``ask()``,
  a tell whose X or f does not match the batch asked, all raise ``OptimizerError``;
- non-finite values: NaN/inf never become the best; what ``_tell`` receives depends on
  ``nonfinite`` ("inf": NaN becomes +inf, for methods that only rank; "worst": NaN/inf become the
  worst finite value told so far, 1e10 before any, for methods that model f's values);
- best tracking (``best`` is the lowest finite f told and the point that gave it);
- hyperparameter checks (``int_param``, ``float_param``, ``choice_param``) whose messages name
  the plugin, the key and the valid range.

``OptimizerError`` is the one base of every error a plugin raises on purpose (bad bounds, bad
hyperparameters, a tell that does not match its ask). It derives from ``Exception``, not
``ValueError``: the harness catches ``OptimizerError`` as bad input, so a ``ValueError`` from a
plugin's bug or its library (in ``_ask``, ``_tell``) keeps its traceback instead of passing for
a bad setting. A plugin that wraps a library's own checks catches the library's error locally
and raises an ``OptimizerError`` (or a subclass) naming the key.
"""

from __future__ import annotations

import abc
import numbers
from typing import Protocol, runtime_checkable

import numpy as np


class OptimizerError(Exception):
    """Invalid optimiser input (bounds, hyperparameters, a tell that does not match its ask); the
    base of every optimizers error (plugins subclass it for their own)."""


@runtime_checkable
class Optimizer(Protocol):
    """A minimiser over the box ``[lower, upper]``, driven by the harness.

    Constructed as ``Cls(lower, upper, seed=seed, x0=x0, **hyperparameters)``: ``lower`` and
    ``upper`` are (d,) bounds, ``seed`` an int >= 0 that fixes every random choice (the optimiser
    owns a ``numpy.random.Generator``; it never reads or seeds global state), ``x0`` the (d,)
    reference point (the harness always passes it; local methods start there, others may ignore it).
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
    """Keeps the best (x, f) seen in tells (NaN/inf never become best)."""

    def __init__(self, d: int) -> None:
        self.x = np.full(d, np.nan)
        self.f = np.inf

    def update(self, X: np.ndarray, f: np.ndarray) -> None:
        f = np.where(np.isfinite(np.asarray(f, float)), f, np.inf)
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


_NONFINITE = ("inf", "worst")


class AskTell(abc.ABC):
    """Base of every plugin: bounds, ask/tell guards, NaN handling, best tracking (module doc).

    Subclasses call ``super().__init__(lower, upper)`` first, then implement ``_ask() -> X (n, d)``
    (raw units; clipped to the box here) and ``_tell(X, f)`` (f (n,) after the ``nonfinite``
    policy), and may override ``stop``.
    """

    registered_name = "optimizer"  # set by @register
    nonfinite = "inf"

    def __init__(self, lower, upper) -> None:
        if self.nonfinite not in _NONFINITE:
            raise OptimizerError(f"{self.registered_name}: nonfinite must be one of {_NONFINITE}")
        self.lower, self.upper = check_bounds(lower, upper)
        self.span = self.upper - self.lower
        self.dim = self.lower.size
        self._best_tracker = BestTracker(self.dim)
        self._fill = WorstFiniteFill()
        self._pending: np.ndarray | None = None

    # --- the contract ----------------------------------------------------------------------

    def ask(self) -> np.ndarray:
        if self._pending is not None:
            raise OptimizerError(f"{self.registered_name}: ask() called twice without tell()")
        X = np.asarray(self._ask(), float)
        if X.ndim != 2 or X.shape[1] != self.dim or len(X) == 0:
            raise OptimizerError(f"{self.registered_name}: produced a batch of shape {X.shape}, "
                                 f"expected (n >= 1, {self.dim})")
        X = np.clip(X, self.lower, self.upper)  # rounding of a unit-box map can leave the box by 1 ulp
        self._pending = X
        return X.copy()

    def tell(self, X: np.ndarray, f: np.ndarray) -> None:
        asked = self._pending
        if asked is None:
            raise OptimizerError(f"{self.registered_name}: tell() without a pending ask()")
        X = np.asarray(X, float)
        f = np.asarray(f, float).ravel()
        if f.shape != (len(asked),) or X.shape != asked.shape:
            raise OptimizerError(f"{self.registered_name}: tell() needs X {asked.shape} and f ({len(asked)},) "
                                 f"of the last ask, got X {X.shape} and f {f.shape}")
        self._pending = None
        self._best_tracker.update(X, f)
        if self.nonfinite == "inf":
            f = np.where(np.isnan(f), np.inf, f)  # NaN ranks as worst; +inf already does
        else:
            f = self._fill(f)
        self._tell(X, f)

    @property
    def stop(self) -> str | None:
        return None

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return self._best_tracker.x.copy(), self._best_tracker.f

    @abc.abstractmethod
    def _ask(self) -> np.ndarray:
        """The next batch (n, d) in raw units (the plugin's own algorithm)."""

    @abc.abstractmethod
    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        """Take the values f (n,) of the last batch X (n, d) (the plugin's own algorithm)."""

    # --- coordinates -----------------------------------------------------------------------

    def to_unit(self, X) -> np.ndarray:
        """Raw points (n, d) or (d,) -> the unit box, clipped to [0, 1]."""
        return np.clip((np.asarray(X, float) - self.lower) / self.span, 0.0, 1.0)

    def from_unit(self, U) -> np.ndarray:
        """Unit-box points (n, d) or (d,) -> raw units, clipped to the bounds."""
        return np.clip(self.lower + np.asarray(U, float) * self.span, self.lower, self.upper)

    # --- hyperparameter checks -------------------------------------------------------------

    def int_param(self, key: str, value, low: int, high: int | None = None, *, even: bool = False) -> int:
        """``value`` as an int in [low, high] (``even``: also even); OptimizerError naming the key otherwise."""
        valid = (isinstance(value, numbers.Integral) and not isinstance(value, bool)
                 and value >= low and (high is None or value <= high) and (not even or value % 2 == 0))
        if not valid:
            rng = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise OptimizerError(f"{self.registered_name}: {key} must be an{' even' if even else ''} integer "
                                 f"{rng}, got {value!r}")
        return int(value)

    def float_param(self, key: str, value, low: float | None = None, high: float | None = None, *,
                    low_open: bool = False, high_open: bool = False) -> float:
        """``value`` as a finite float in the interval; OptimizerError naming the key and the interval otherwise."""
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and np.isfinite(value)
        if ok and low is not None:
            ok = value > low if low_open else value >= low
        if ok and high is not None:
            ok = value < high if high_open else value <= high
        if not ok:
            interval = (("(" if low_open else "[") + ("-inf" if low is None else f"{low:g}") + ", "
                        + ("inf" if high is None else f"{high:g}") + (")" if high_open or high is None else "]"))
            raise OptimizerError(f"{self.registered_name}: {key} must be a number in {interval}, got {value!r}")
        return float(value)

    def bool_param(self, key: str, value) -> bool:
        if not isinstance(value, (bool, np.bool_)):
            raise OptimizerError(f"{self.registered_name}: {key} must be true or false, got {value!r}")
        return bool(value)

    def choice_param(self, key: str, value, choices) -> str:
        if value not in choices:
            raise OptimizerError(f"{self.registered_name}: {key} must be one of {', '.join(map(str, choices))}, "
                                 f"got {value!r}")
        return value

    def seed_param(self, seed) -> int:
        """The seed as an int >= 0 (what numpy's generators accept)."""
        return self.int_param("seed", seed, 0)
