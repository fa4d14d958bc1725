"""From a composed job config to a finished record: build the problem and optimiser, run the job.

Hydra stops here: everything below receives plain values.
"""

from __future__ import annotations

import functools
import importlib
import json
import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

import optimizers
from bench import problems
from bench.run import Budget, RunError, job_key, run_job

log = logging.getLogger(__name__)


class ConfigError(ValueError):
    """An invalid job config; the message names the key and the valid choices."""


def import_plugins(cfg: dict) -> None:
    """Import the modules listed in ``plugins`` so their ``@register`` decorators run."""
    for module in cfg.get("plugins") or []:
        try:
            importlib.import_module(module)
        except ImportError as err:
            raise ConfigError(f"plugins: cannot import {module!r} ({err})") from None


def plain(cfg: DictConfig) -> dict:
    """The job's config as plain data (Hydra's own section dropped)."""
    data = OmegaConf.to_container(cfg, resolve=True)
    data.pop("hydra", None)
    return data


def budget_of(cfg: dict) -> Budget:
    b = cfg.get("budget") or {}
    try:
        return Budget(evals=b.get("evals"), seconds=b.get("seconds"))
    except RunError as err:
        raise ConfigError(str(err)) from None


def identity_of(cfg: dict) -> dict:
    """What defines a job: resuming or skipping compares this, nothing else."""
    return {
        "problem": cfg["problem"]["name"],
        "problem_params": cfg["problem"].get("params") or {},
        "optimizer": cfg["optimizer"]["name"],
        "optimizer_params": cfg["optimizer"].get("params") or {},
        "seed": cfg["seed"],
        "budget": cfg.get("budget"),
    }


@functools.lru_cache(maxsize=8)
def _problem_cached(name: str, params_json: str):
    # Jobs of one sweep in one process share the problem (its data and caches are built once).
    return problems.get(name)(**json.loads(params_json))


def build_problem(cfg: dict):
    """The registered problem named by ``cfg["problem"]``, built from its params (cached per process)."""
    name = cfg["problem"]["name"]
    params = cfg["problem"].get("params") or {}
    return _problem_cached(name, json.dumps(params, sort_keys=True))


def optimizer_factory(cfg: dict, space):
    """A function building the configured optimiser on ``space`` from the job's seed."""
    cls = optimizers.get(cfg["optimizer"]["name"])
    params = cfg["optimizer"].get("params") or {}
    seed = int(cfg["seed"])
    return lambda: cls(space.lower, space.upper, seed=seed, x0=space.reference, **params)


def run_configured_job(cfg: dict, job_dir: Path, label: str = "job") -> dict:
    """Run one composed job config into ``job_dir``; failures are recorded, not raised."""
    identity = identity_of(cfg)
    import_plugins(cfg)
    try:
        problem = build_problem(cfg)
    except Exception as exc:  # noqa: BLE001 - a problem that cannot be built fails this job only
        from bench.run import record_failure

        log.error("%s: problem %r failed to build: %s", label, identity["problem"], exc)
        return record_failure(job_dir, identity, cfg, exc)
    return run_job(
        problem,
        optimizer_factory(cfg, problem.space),
        budget_of(cfg),
        job_dir,
        identity,
        config=cfg,
        label=label,
        progress_every_s=float(cfg.get("progress_every_s", 5.0)),
    )


__all__ = ["ConfigError", "build_problem", "budget_of", "identity_of", "job_key", "plain", "run_configured_job"]
