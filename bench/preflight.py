"""Validate every job of a sweep before any work starts.

Hydra composes and launches jobs one by one, so a typo in the fifth optimiser name, a budget
of 0 or a missing data file would surface only after the first jobs ran. Here the command
line is expanded exactly as Hydra's basic sweeper expands it, each job config is composed
with Hydra's compose API, and each is checked: registered names, budget, seed, no NaN, the
problem's own cheap checks (its search space, its data files). The first problem found is
one clear message and exit code 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import OmegaConf

import optimizers
from bench import problems
from bench.job import ConfigError, budget_of, import_plugins

CONF_DIR = Path(__file__).resolve().parent / "conf"
_HYDRA_FLAGS_WITHOUT_JOBS = {"--help", "-h", "--hydra-help", "--version", "--info", "-i", "--cfg", "-c",
                             "--shell-completion", "-sc", "--resolve"}


def expand_jobs(argv: list[str]) -> list[list[str]]:
    """The override lists of every job the sweep will run (config sweeper params + command line)."""
    overrides = [a for a in argv if not a.startswith("-")]
    # hydra.searchpath decides which configs exist; Hydra's other settings do not change jobs
    app_overrides = [o for o in overrides
                     if not o.lstrip("+~").startswith("hydra") or o.startswith("hydra.searchpath")]
    parser = OverridesParser.create()
    # The sweeper params of the primary config, read as data: composing it would need a
    # valid default for every swept group first.
    primary = OmegaConf.load(CONF_DIR / "config.yaml")
    params = OmegaConf.select(primary, "hydra.sweeper.params") or {}
    sweep_params = [f"{k}={v}" for k, v in params.items()]
    parsed = parser.parse_overrides(sweep_params + app_overrides)
    return BasicSweeper.split_arguments(parsed, None)[0]


def check_job(cfg: dict) -> None:
    """Raise ConfigError if one composed job config is invalid."""
    _check_finite(cfg, "")
    import_plugins(cfg)
    name = cfg["optimizer"].get("name")
    if name not in optimizers.available():
        raise ConfigError(f"optimizer={name!r} is not registered; valid names: {', '.join(optimizers.available())}")
    pname = cfg["problem"].get("name")
    if pname not in problems.available():
        raise ConfigError(f"problem={pname!r} is not registered; valid names: {', '.join(problems.available())}")
    budget_of(cfg)
    if not isinstance(cfg.get("seed"), int) or isinstance(cfg.get("seed"), bool):
        raise ConfigError(f"seed must be an integer, got {cfg.get('seed')!r}")
    factory = problems.get(pname)
    checker = getattr(factory, "preflight", None)
    if checker is not None:
        try:
            checker(**(cfg["problem"].get("params") or {}))
        except (ValueError, OSError, TypeError) as err:
            raise ConfigError(f"problem={pname}: {err}") from None


def _check_finite(node, path: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            _check_finite(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            _check_finite(value, f"{path}[{i}]")
    elif isinstance(node, float) and not math.isfinite(node):
        raise ConfigError(f"{path} is {node}: numbers in the config must be finite")


def preflight(argv: list[str]) -> int:
    """Validate every job the command line would run; 0 if all are valid, else print why and return 2."""
    if any(a.split("=")[0] in _HYDRA_FLAGS_WITHOUT_JOBS for a in argv):
        return 0
    GlobalHydra.instance().clear()
    seen: set[str] = set()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="preflight"):
            for job_overrides in expand_jobs(argv):
                cfg = OmegaConf.to_container(compose("config", overrides=job_overrides), resolve=True)
                key = json.dumps({k: cfg[k] for k in ("problem", "optimizer", "budget", "seed")}, sort_keys=True,
                                 default=str)
                if key not in seen:
                    seen.add(key)
                    check_job(cfg)
    except ConfigError as err:
        print(f"error: {err}")
        return 2
    except HydraException as err:
        print(f"error: {str(err).split(chr(10) + 'Config search path')[0].strip()}")
        return 2
    finally:
        GlobalHydra.instance().clear()
    return 0


def compose_job(overrides: list[str]) -> dict:
    """One job's config as plain data, composed from ``conf/`` with ``overrides`` (for scripts)."""
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="script"):
            return OmegaConf.to_container(compose("config", overrides=overrides), resolve=True)
    finally:
        GlobalHydra.instance().clear()
