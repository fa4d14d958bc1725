"""A search space: named, bounded, real variables with units and a reference point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.errors import BenchError


class SpaceError(BenchError):
    """Invalid bounds or a point outside the space; the message names the variable."""


@dataclass(frozen=True)
class Space:
    """Box ``[lower, upper]`` over named variables.

    names: (d,) variable names; units: (d,) unit strings; lower, upper, reference: (d,).
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    reference: np.ndarray

    def __post_init__(self) -> None:
        d = len(self.names)
        for what in ("units", "lower", "upper", "reference"):
            if len(getattr(self, what)) != d:
                raise SpaceError(f"space has {d} names but {len(getattr(self, what))} {what}")
        for i, name in enumerate(self.names):
            lo, hi, ref = float(self.lower[i]), float(self.upper[i]), float(self.reference[i])
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise SpaceError(f"variable {name!r}: bounds must be finite, got [{lo}, {hi}]")
            if not lo < hi:
                raise SpaceError(f"variable {name!r}: lower bound {lo} is not below upper bound {hi}")
            if not lo <= ref <= hi:
                raise SpaceError(f"variable {name!r}: reference {ref} outside [{lo}, {hi}]")

    @property
    def dim(self) -> int:
        return len(self.names)

    def check(self, X: np.ndarray) -> np.ndarray:
        """``X`` as a float (n, d) array; SpaceError if its shape is wrong or it leaves the box."""
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[1] != self.dim:
            raise SpaceError(f"expected a batch of shape (n, {self.dim}), got {X.shape}")
        outside = (X < self.lower) | (X > self.upper) | ~np.isfinite(X)
        if outside.any():
            row, col = map(int, np.argwhere(outside)[0])
            raise SpaceError(
                f"point {row} has {self.names[col]}={X[row, col]} outside "
                f"[{self.lower[col]}, {self.upper[col]}]"
            )
        return X

    @classmethod
    def from_dict(cls, variables: dict) -> "Space":
        """From ``{name: {unit, lower, upper, reference}}`` (the shape of the yaml configs)."""
        names = tuple(variables)
        def get(key):
            return np.array([float(variables[n][key]) for n in names])
        try:
            return cls(names, tuple(str(variables[n].get("unit", "")) for n in names),
                       get("lower"), get("upper"), get("reference"))
        except KeyError as err:
            raise SpaceError(f"space variable is missing the field {err}") from None
