"""``bench.problems.make(name, **params)``: a registered problem as a plain vectorised callable.

The object it returns scores exactly what the harness scores for ``problem=name`` with the same
params: the params of ``bench/conf/problem/<name>.yaml`` (when there is one) merged with the
given ones as Hydra merges command-line overrides, then ``build_problem`` (the harness's own
builder, cached per process). Use it to drive the objective from another library (nevergrad,
pymoo, optuna, ioh; see docs/guide/interop.md)::

    from bench.problems import make

    problem = make("sphere")
    problem(problem.x0)                   # a float
    problem(X)                            # X (n, d) -> f (n,)
    problem(X, with_metrics=True)         # (f, {metric: (n,)})
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.problems.base import build_problem

CONF_DIR = Path(__file__).resolve().parent.parent / "conf" / "problem"


def problem_config(name: str, params: dict | None = None, instance: int = 0) -> dict:
    """``{"name", "params"}`` as the harness composes it for ``problem=name instance=instance`` plus
    ``params`` overrides.

    The yaml's params are the defaults (``${instance}`` in them resolved to ``instance``, as the
    sweep resolves it); ``params`` are merged over them with OmegaConf (a dict merges into a dict
    key by key, anything else replaces). Without a yaml, ``params`` alone.
    """
    from omegaconf import OmegaConf

    path = CONF_DIR / f"{name}.yaml"
    if not path.is_file():
        return {"name": name, "params": dict(params or {})}
    conf = OmegaConf.load(path)
    root = OmegaConf.create({"instance": instance, "params": conf.get("params") or {}})
    merged = OmegaConf.merge(root, {"params": params or {}})
    return {"name": str(conf.get("name", name)), "params": OmegaConf.to_container(merged, resolve=True)["params"]}


class CallableProblem:
    """A registered problem as ``f = problem(X)``; deterministic, like the problem it wraps.

    Attributes: ``name``, ``config`` ({"name", "params"} as built), ``problem`` (the registered
    problem itself), ``space``, ``lower``, ``upper``, ``x0`` (the space's reference point),
    ``names``, ``units`` (tuples), ``d`` (dimension), ``truth`` ((d,) or None), ``f_unit``.
    Points outside ``[lower, upper]`` raise ``SpaceError``, as in the harness.
    """

    def __init__(self, problem, config: dict) -> None:
        self.problem = problem
        self.config = config
        self.name = problem.name
        self.space = problem.space
        self.lower = np.array(self.space.lower, float)
        self.upper = np.array(self.space.upper, float)
        self.x0 = np.array(self.space.reference, float)
        self.names = tuple(self.space.names)
        self.units = tuple(self.space.units)
        self.d = self.space.dim
        truth = getattr(problem, "truth", None)
        self.truth = None if truth is None else np.array(truth, float)
        self.f_unit = getattr(problem, "f_unit", None)

    def __call__(self, X, with_metrics: bool = False):
        """f of ``X``: (n, d) -> (n,) array; a single point (d,) -> float.

        with_metrics: return ``(f, metrics)`` instead, metrics ``{name: (n,) array}`` (floats for
        a single point), the values the harness logs beside f.
        """
        X = np.asarray(X, float)
        single = X.ndim == 1
        f, metrics = self.problem.evaluate(self.space.check(X[None] if single else X))
        f = np.asarray(f, float)
        metrics = {k: np.asarray(v, float) for k, v in metrics.items()}
        if single:
            f = float(f[0])
            metrics = {k: float(v[0]) for k, v in metrics.items()}
        return (f, metrics) if with_metrics else f

    def metrics(self, X) -> dict:
        """The metrics of ``X`` (``{name: (n,) array}``; floats for a single point)."""
        return self(X, with_metrics=True)[1]

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.config['name']} d={self.d} params={self.config['params']}>"


def make(name: str, instance: int = 0, **params) -> CallableProblem:
    """The problem registered as ``name`` (or configured in ``bench/conf/problem/<name>.yaml``) on
    ``instance`` (the sweep's ``instance=``), built with ``params`` over the yaml's defaults, as a
    :class:`CallableProblem`.

    An unknown name raises the registry's KeyError (listing the valid names); bad params the
    problem's own error (TypeError for an unknown keyword, ProblemError for a bad value).
    """
    config = problem_config(name, params, instance)
    return CallableProblem(build_problem({"problem": config}), config)
