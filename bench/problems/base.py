"""The batched problem contract and the problem registry."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from bench.space import Space


class ProblemError(ValueError):
    """A problem could not be built (bad config, missing data); the message names what and where."""


@runtime_checkable
class Problem(Protocol):
    """A minimisation problem evaluated a batch at a time.

    ``evaluate(X)`` takes (n, d) points of ``space`` and returns ``(f, metrics)``: f (n,) the
    objective, metrics a dict of (n,) arrays reported beside f and never charged to the budget
    (e.g. calibration errors against a known truth). Deterministic for a given X.
    ``truth`` is the (d,) point of the true solution when known, else None.
    ``identity`` is a dict describing the problem's data (e.g. a content hash), stored in records.
    """

    name: str
    space: Space
    truth: np.ndarray | None

    def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]: ...

    @property
    def identity(self) -> dict: ...


_REGISTRY: dict[str, type] = {}


def register(name: str):
    """Class decorator that registers a problem factory under ``name`` (its yaml's ``name``).

    The class is built as ``Cls(**params)`` with the yaml's keys other than ``name``.
    """

    def decorate(cls: type) -> type:
        _REGISTRY[name] = cls
        return cls

    return decorate


def _discover() -> None:
    import importlib
    import pkgutil

    import bench.problems as pkg

    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name != "base" and not info.name.startswith("_"):
            importlib.import_module(f"bench.problems.{info.name}")


def available() -> list[str]:
    _discover()
    return sorted(_REGISTRY)


def get(name: str) -> type:
    _discover()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown problem {name!r}; valid names: {', '.join(sorted(_REGISTRY))}") from None
