"""From a composed job config to a finished record: build the problem and optimiser, run the job.

Hydra stops here: everything below receives plain values.
"""

from __future__ import annotations

import importlib
import logging
import math
import os
import re
import socket
import sys
import threading
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

import optimizers
from bench.errors import BenchError
from bench.problems.base import build_problem
from bench.run import hydra_guard
from bench.run.bookkeeping import LOG_METRICS
from bench.run.identity import job_key
from bench.run.loop import Budget, JobFolderError, RunError, record_failure, run_job

log = logging.getLogger(__name__)
hydra_guard.install()  # here too for a launcher's worker, which imports this module to unpickle its job

# settings that change how a job is shown or run, not what it computes: left out of its identity
PRESENTATION_KEYS = ("progress_every_s", "progress", "report", "plugins", "hydra", "verdict", "log_metrics",
                     "threads", "filter_block")
FILTER_BLOCKS = (1, 2, 4, 8)  # avio.filter.batch.set_block: 1 numba's per-filter kernel, 2, 4, 8 lock-step blocks
_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


class ConfigError(BenchError):
    """An invalid job config; the message names the key and the valid choices."""


def import_plugins(cfg: dict) -> None:
    """Import the modules listed in ``plugins`` so their ``@register`` decorators run.

    ``plugins`` must be a list of absolute module names (``pkg.module``); config is trusted code,
    so they are imported as they are, but nothing else in a job folder ever is.
    """
    modules = cfg.get("plugins")
    if modules is None:
        return
    if not isinstance(modules, (list, tuple)):
        raise ConfigError(f"plugins must be a list of module names, got {modules!r}")
    for module in modules:
        if not isinstance(module, str) or not _MODULE.fullmatch(module):
            raise ConfigError(f"plugins: {module!r} is not an absolute module name (like mypackage.my_optimizer)")
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
    b = cfg.get("budget")
    if not isinstance(b, dict):
        raise ConfigError(f"budget must be a section with evals and seconds, got {b!r}")
    unknown = sorted(set(b) - {"evals", "seconds"})
    if unknown:
        raise ConfigError(f"budget: unknown setting(s) {unknown}; valid: evals, seconds")
    try:
        return Budget(evals=b.get("evals"), seconds=b.get("seconds"))
    except RunError as err:
        raise ConfigError(str(err)) from None


def instance_of(cfg: dict) -> int:
    """The job's problem instance (``instance``, an integer >= 0); ConfigError naming the key otherwise."""
    instance = cfg.get("instance", 0)
    if not isinstance(instance, int) or isinstance(instance, bool) or not 0 <= instance < 2**63:
        raise ConfigError(f"instance must be an integer in [0, 2**63) (the problem instance), got {instance!r}")
    return instance


def seed_of(cfg: dict) -> int:
    seed = cfg.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise ConfigError(f"seed must be an integer in [0, 2**63), got {seed!r}")
    return seed


def progress_every_s_of(cfg: dict) -> float:
    value = cfg.get("progress_every_s", 5.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ConfigError(f"progress_every_s must be a positive number of seconds, got {value!r}")
    return float(value)


def log_metrics_of(cfg: dict) -> str:
    value = cfg.get("log_metrics", "improvements")
    if value not in LOG_METRICS:
        raise ConfigError(f"log_metrics must be one of {', '.join(LOG_METRICS)}, got {value!r}")
    return value


def check_thread_environment() -> None:
    """ConfigError when NUMBA_NUM_THREADS (what ``threads: auto`` follows; numba reads it at import and fails
    deep in a job on 0) is set but not an integer >= 1; empty counts as unset."""
    value = os.environ.get("NUMBA_NUM_THREADS", "").strip()
    if value and not (value.isdigit() and int(value) >= 1):
        raise ConfigError(f"NUMBA_NUM_THREADS={value!r} (environment): must be an integer >= 1 (numba reads it; "
                          "threads=auto follows it); unset it for the machine's cores")


def threads_of(cfg: dict) -> int | None:
    """The VIO filter's threads per job (``threads``): an integer from 1 to this machine's cores, or
    None for ``auto`` (avio.filter.batch.default_threads); ConfigError naming the key otherwise."""
    check_thread_environment()  # whatever ``threads`` says: numba reads it when it is imported
    value = cfg.get("threads", "auto")
    if value == "auto" or value is None:
        return None
    cores = os.cpu_count() or 1
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= cores:
        raise ConfigError(f"threads must be auto or an integer from 1 to {cores} (this machine's cores), got {value!r}")
    return value


def block_of(cfg: dict) -> int | None:
    """The VIO filter's lock-step block (``filter_block``): one of FILTER_BLOCKS, or None for ``auto``
    (avio.filter.batch.block_size); ConfigError naming the key otherwise."""
    value = cfg.get("filter_block", "auto")
    if value == "auto" or value is None:
        return None
    if isinstance(value, bool) or value not in FILTER_BLOCKS:
        raise ConfigError(f"filter_block must be auto or one of {', '.join(map(str, FILTER_BLOCKS))}, got {value!r}")
    return value


def check_presentation(cfg: dict) -> None:
    """ConfigError naming the first invalid presentation setting (``progress_every_s``, ``log_metrics``,
    ``threads``, ``filter_block``)."""
    progress_every_s_of(cfg)
    log_metrics_of(cfg)
    threads_of(cfg)
    block_of(cfg)


def identity_of(cfg: dict) -> dict:
    """What defines a job: the whole resolved config but its presentation settings
    (``PRESENTATION_KEYS``). Resuming or skipping compares this (with the data and the code)."""
    return {k: v for k, v in cfg.items() if k not in PRESENTATION_KEYS}


def optimizer_factory(cfg: dict, space):
    """A function building the configured optimiser on ``space`` from the job's seed.

    The harness passes ``(lower, upper, seed=seed, x0=reference, **params)``: lower/upper (d,)
    bounds, the job's seed (int >= 0), x0 the space's reference point (d,) and the yaml's params.
    """
    cls = optimizers.get(cfg["optimizer"]["name"])
    params = cfg["optimizer"].get("params") or {}
    seed = int(cfg["seed"])
    return lambda: cls(space.lower, space.upper, seed=seed, x0=space.reference, **params)


def _apply_threads(n: int | None, block: int | None = None) -> None:
    """Set the filter's thread count and lock-step block for this process's jobs (``threads``,
    ``filter_block``; auto: their default rules)."""
    if n is None and block is None and "avio.filter.batch" not in sys.modules:
        return  # auto and no filter loaded yet: nothing to restore, and no reason to import numba here
    from avio.filter.batch import set_block, set_threads

    set_threads(n)
    set_block(block)


def run_configured_job(cfg: dict, job_dir: Path, label: str = "job") -> dict:
    """Run one composed job config into ``job_dir`` and return its outcome; never raises.

    The outcome is the record (``status`` "ok" or "failed") or, when the job could not be run or
    its folder not written, ``{"status": "refused" | "failed", "error": {"type", "message"},
    "job_dir": ...}`` with nothing written to the folder.
    """
    identity = identity_of(cfg)
    try:
        import_plugins(cfg)
        _apply_threads(threads_of(cfg), block_of(cfg))
        print(f"{label}: building problem {cfg['problem']['name']}", file=sys.stderr, flush=True)
        try:
            problem = build_problem(cfg)
        except Exception as exc:
            log.error("%s: problem %r failed to build: %s", label, cfg["problem"].get("name"), exc)
            return record_failure(job_dir, identity, cfg, exc)
        return run_job(
            problem,
            optimizer_factory(cfg, problem.space),
            budget_of(cfg),
            job_dir,
            identity,
            config=cfg,
            label=label,
            progress_every_s=progress_every_s_of(cfg),
            optimizer_class=optimizers.get(cfg["optimizer"]["name"]),
            progress=bool(cfg.get("progress", True)),
            log_metrics=log_metrics_of(cfg),
        )
    except JobFolderError as err:
        log.error("%s failed: %s", label, err)
        return {"status": "failed", "error": {"type": type(err).__name__, "message": str(err)}, "job_dir": str(job_dir)}
    except (RunError, ConfigError) as err:
        log.error("%s refused: %s", label, err)
        return {"status": "refused", "error": {"type": type(err).__name__, "message": str(err)},
                "job_dir": str(job_dir)}
    except Exception as err:
        log.exception("%s failed outside its run loop", label)
        return {"status": "failed", "error": {"type": type(err).__name__, "message": str(err)}, "job_dir": str(job_dir)}


_watching = threading.Event()


def exit_with_the_sweep() -> None:
    """In a launcher's worker process: exit as soon as the sweep's main process is gone.

    joblib's (loky) and submitit's workers would otherwise run their job to the end after the
    sweep was killed, writing into a folder the user believes idle.
    """
    sweep_pid = int(os.environ.get("BENCH_SWEEP_PID") or 0)
    if not sweep_pid or sweep_pid == os.getpid() or _watching.is_set():
        return
    # only a direct child on the sweep's own machine (joblib's and submitit-local's workers);
    # a SLURM job inherits the variables on another host, where that pid means nothing
    if os.environ.get("BENCH_SWEEP_HOST") != socket.gethostname() or os.getppid() != sweep_pid:
        return
    _watching.set()
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(0.5)
            try:
                os.kill(sweep_pid, 0)
                alive = os.getppid() == parent
            except ProcessLookupError:
                alive = False
            except PermissionError:  # exists, owned by someone else: not ours any more
                alive = False
            if not alive:
                print(f"bench worker {os.getpid()}: the sweep (pid {sweep_pid}) is gone; exiting",
                      file=sys.stderr, flush=True)
                os._exit(3)

    threading.Thread(target=watch, daemon=True, name="bench-sweep-watch").start()


__all__ = ["ConfigError", "build_problem", "budget_of", "exit_with_the_sweep", "identity_of", "instance_of", "job_key",
           "check_presentation", "log_metrics_of",
           "plain", "run_configured_job"]
