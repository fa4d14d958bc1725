"""Hydra's own per-job set-up, as one job's failure instead of the end of the sweep.

Before a job's code runs, Hydra's ``run_job`` creates the job folder, opens its log file and writes
``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml`` there. An error in that set-up (a
read-only job folder, a full disk, a path taken by a file) escaped the launcher: the sweep ended with
a traceback, the later jobs never ran and no ``Jobs:`` summary was printed. :func:`install` wraps the
``run_job`` that Hydra's launchers call (the basic one, ``hydra.mode=RUN``, and the joblib and
submitit plugins, in whichever process runs the job): such an error is written as that job's failed
record when its folder can take one (``bench.run.loop.record_failure``), counted as the job's outcome,
and the sweep goes on to its summary (exit code 1). An error raised after the job's own code started is
not Hydra's set-up and is left as it was (the job's code never raises: ``run_configured_job``).

How the launchers are reached: each module imports ``run_job`` by name, so the wrapper replaces that
name in every launcher module already imported and in ``hydra.core.utils`` for those imported later.
:func:`install` runs in the sweep's process (``bench.__main__``) and, through ``bench.run.job``, in a
launcher's worker process as soon as it unpickles the job (before it calls ``run_job``).
"""

from __future__ import annotations

import functools
import logging
import os
import sys
from pathlib import Path

import hydra.core.utils as hydra_utils
from hydra.core.utils import JobReturn, JobStatus
from omegaconf import OmegaConf

from bench.errors import BenchError
from bench.records import job_name

log = logging.getLogger(__name__)

#: The modules that call ``run_job`` by a name of their own.
CALLERS = ("hydra.core.utils", "hydra._internal.hydra", "hydra._internal.core_plugins.basic_launcher",
           "hydra_plugins.hydra_joblib_launcher._core", "hydra_plugins.hydra_submitit_launcher.submitit_launcher")


class JobSetupError(BenchError):
    """Hydra could not set up a job's folder (create it, open its log, write ``.hydra/``); the job failed."""


def _original(run_job):
    return getattr(run_job, "__wrapped__", run_job)


def install() -> None:
    """Wrap ``run_job`` in every loaded caller (idempotent)."""
    original = _original(hydra_utils.run_job)
    guarded = _guarded(original)
    for name in CALLERS:
        module = sys.modules.get(name)
        if module is not None and getattr(module, "run_job", None) is not None:
            if getattr(module.run_job, "__wrapped__", None) is None:
                module.run_job = guarded


def _guarded(original):
    @functools.wraps(original)
    def run_job(task_function, config, job_dir_key, job_subdir_key, hydra_context, configure_logging=True):
        started = []

        @functools.wraps(task_function)
        def task(cfg):
            started.append(True)
            return task_function(cfg)

        try:
            _refuse_links(config, job_dir_key, job_subdir_key)
            return original(task_function=task, config=config, job_dir_key=job_dir_key,
                            job_subdir_key=job_subdir_key, hydra_context=hydra_context,
                            configure_logging=configure_logging)
        except Exception as exc:
            if started:  # not Hydra's set-up: as it was
                raise
            return setup_failed(config, job_dir_key, job_subdir_key, exc)

    return run_job


def _refuse_links(config, job_dir_key: str, job_subdir_key: str | None) -> None:
    """JobSetupError naming the link when the job folder, its ``.hydra/`` files or its log file is a
    symbolic link: Hydra writes them with plain ``open``, which would follow it out of the sweep."""
    from hydra.core.hydra_config import HydraConfig

    previous = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(config)  # the folder's name may use ${hydra:...}
    try:
        job_dir = _job_dir(config, job_dir_key, job_subdir_key)
    finally:
        HydraConfig.instance().cfg = previous
    hydra_dir = job_dir / ".hydra"
    candidates = [job_dir, hydra_dir, *(hydra_dir.glob("*") if hydra_dir.is_dir() and not hydra_dir.is_symlink()
                                         else ()), *(job_dir.glob("*.log") if job_dir.is_dir() else ())]
    for path in candidates:
        if path.is_symlink():
            raise JobSetupError(f"{path} is a symbolic link (to {os.readlink(path)}); Hydra would write the job's "
                                "set-up through it, possibly outside the sweep: replace it by the file itself")


def _job_dir(config, job_dir_key: str, job_subdir_key: str | None) -> Path:
    known = OmegaConf.select(config, "hydra.runtime.output_dir", default=None)
    if known:  # set by run_job before it creates the folder
        return Path(str(known))
    base = Path(str(OmegaConf.select(config, job_dir_key)))
    return base / str(OmegaConf.select(config, job_subdir_key)) if job_subdir_key else base


def setup_failed(config, job_dir_key: str, job_subdir_key: str | None, exc: BaseException) -> JobReturn:
    """Record ``exc`` (Hydra's set-up of this job failed) as the job's failure and its outcome; the
    JobReturn of a job that ran and failed (completed, no value), so that the sweep goes on."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from bench.run import callbacks
    from bench.run.job import identity_of
    from bench.run.loop import record_failure

    job_dir = _job_dir(config, job_dir_key, job_subdir_key)
    num = OmegaConf.select(config, "hydra.job.num", default=0) or 0
    previous = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(config)  # the job's config may use ${hydra:...}
    try:
        cfg = OmegaConf.to_container(OmegaConf.masked_copy(config, [k for k in config if k != "hydra"]), resolve=True)
    finally:
        HydraConfig.instance().cfg = previous
    total = os.environ.get("BENCH_SWEEP_JOBS") or "?"
    problem, optimizer = ((cfg.get(k) or {}).get("name") if isinstance(cfg.get(k), dict) else cfg.get(k)
                          for k in ("problem", "optimizer"))
    label = f"job {num + 1}/{total} {problem}/{optimizer}/{job_name(cfg.get('instance'), cfg.get('seed'))}"
    try:
        raise JobSetupError(f"Hydra could not set up the job folder {job_dir} before the job started "
                            f"({type(exc).__name__}: {exc})") from exc
    except JobSetupError as err:
        failure = err
    log.error("%s failed: %s", label, failure)
    try:
        outcome = record_failure(job_dir, identity_of(cfg), cfg, failure)
    except BenchError as err:  # the folder cannot take a record either (e.g. the full disk)
        outcome = {"status": "failed", "error": {"type": type(failure).__name__, "message": f"{failure}; {err}"},
                   "job_dir": str(job_dir)}
    if OmegaConf.select(config, "hydra.mode") == RunMode.MULTIRUN:
        callbacks.note_outcome(Path(str(OmegaConf.select(config, "hydra.sweep.dir"))), num, label, outcome)
    else:
        callbacks.LAST_SWEEP.update(n_jobs=1, n_failed=1)
    ret = JobReturn(cfg=OmegaConf.create(cfg), hydra_cfg=config, working_dir=os.getcwd(), status=JobStatus.COMPLETED,
                    task_name=OmegaConf.select(config, "hydra.job.name", default=None))
    ret.overrides = OmegaConf.to_container(config.hydra.overrides.task)
    ret.return_value = None
    return ret
