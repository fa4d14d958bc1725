"""The batched problem contract and the problem registry."""

from __future__ import annotations

import functools
import json
from typing import Protocol, runtime_checkable

import numpy as np

from bench.errors import BenchError
from bench.space import Space
from optimizers.registry import Registry


class ProblemError(BenchError):
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


PROBLEMS = Registry("problem", "bench.problems", skip=frozenset({"base", "calibration_space", "vio"}))
#: ``@register("name")`` on a problem class, built as ``Cls(**params)`` with the yaml's keys other than ``name``.
register, available, get = PROBLEMS.register, PROBLEMS.available, PROBLEMS.get


@functools.lru_cache(maxsize=8)
def _problem_cached(name: str, params_json: str):
    # Jobs of one sweep in one process share the problem (its data and caches are built once).
    return get(name)(**json.loads(params_json))


def build_problem(cfg: dict):
    """The registered problem named by ``cfg["problem"]``, built from its params (cached per process)."""
    name = cfg["problem"]["name"]
    params = cfg["problem"].get("params") or {}
    return _problem_cached(name, json.dumps(params, sort_keys=True))
