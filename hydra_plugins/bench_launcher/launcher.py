"""``hydra/launcher=bench_slurm`` (and ``bench_local``): Hydra's submitit launchers, packed and non-blocking.

Settings beside the submitit plugin's own (``hydra.launcher.*``):

- ``pack`` (int >= 1): jobs run one after the other in one array task. Each job keeps its own folder,
  identity, lock and record (each is Hydra's own ``run_job``, as with the plain launcher); fewer tasks
  mean less scheduling overhead and fewer files for short jobs.
- ``max_array_size`` (int >= 1): no array holds more tasks than this (a cluster's ``MaxArraySize``);
  a larger sweep is submitted as several arrays.
- ``wait`` (bool): ``false`` returns as soon as every array is submitted (SLURM only); follow the
  sweep with ``python -m bench.status DIR`` and build its report with ``python -m bench.report DIR``.
- ``use_srun`` (bench_slurm, bool): ``false`` runs each task in the batch step itself, without ``srun``.

The settings are checked before any submission by ``bench.run.slurm_check`` (``python -m bench`` runs it).
"""

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from hydra.core.config_store import ConfigStore
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus
from hydra_plugins.hydra_submitit_launcher.config import LocalQueueConf, SlurmQueueConf
from hydra_plugins.hydra_submitit_launcher.submitit_launcher import BaseSubmititLauncher
from omegaconf import OmegaConf

log = logging.getLogger(__name__)

#: the settings this launcher adds to the submitit plugin's
PACKING_KEYS = ("pack", "max_array_size", "wait")


@dataclass
class BenchSlurmConf(SlurmQueueConf):
    _target_: str = "hydra_plugins.bench_launcher.launcher.BenchSlurmLauncher"
    pack: int = 1
    max_array_size: int = 1000
    wait: bool = True
    # false: the task runs in the batch step itself, not under srun (a cluster without cgroups cannot
    # kill an srun task that ignores SIGTERM, as submitit's does: scancel would leave it running)
    use_srun: bool = True


@dataclass
class BenchLocalConf(LocalQueueConf):
    _target_: str = "hydra_plugins.bench_launcher.launcher.BenchLocalLauncher"
    pack: int = 1
    max_array_size: int = 1000
    wait: bool = True


def chunks(items: Sequence, size: int) -> list[list]:
    """``items`` cut into consecutive lists of ``size`` (the last one shorter)."""
    return [list(items[i:i + size]) for i in range(0, len(items), size)]


class PackedJobs:
    """One array task: run its jobs one after the other, each through the launcher (its own ``run_job``)."""

    def __init__(self, launcher: "BenchSubmititLauncher", jobs: list[tuple]) -> None:
        self.launcher = launcher
        self.jobs = jobs

    def __call__(self) -> list[JobReturn]:
        if len(self.jobs) > 1:  # Hydra's composition once per kind of job (checked), not once per job
            from bench.run.compose_cache import SweepConfigCache

            loader = self.launcher.hydra_context.config_loader
            loader.load_sweep_config = SweepConfigCache(loader)
        return [self.launcher(*job) for job in self.jobs]

    def checkpoint(self, *args: Any, **kwargs: Any) -> Any:
        import submitit

        return submitit.helpers.DelayedSubmission(self, *args, **kwargs)


class BenchSubmititLauncher(BaseSubmititLauncher):
    """The submitit launcher with ``pack``, ``max_array_size`` and ``wait`` (see the module doc)."""

    def __init__(self, **params: Any) -> None:
        self.packing = {k: params.pop(k) for k in PACKING_KEYS if k in params}
        super().__init__(**params)

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        import submitit

        assert self.config is not None
        pack, max_array, wait = (int(self.packing.get("pack", 1)), int(self.packing.get("max_array_size", 1000)),
                                 bool(self.packing.get("wait", True)))
        executor = self._executor(submitit)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        state = Singleton.get_state()
        jobs = [(list(o), "hydra.sweep.dir", initial_job_idx + i, f"job_id_for_{initial_job_idx + i}", state)
                for i, o in enumerate(job_overrides)]
        tasks = [PackedJobs(self, group) for group in chunks(jobs, pack)]
        submitted = []
        for array in chunks(tasks, max_array):  # each array within the cluster's MaxArraySize
            with executor.batch():
                submitted += [executor.submit(task) for task in array]
        ids = sorted({str(j.job_id).split("_")[0] for j in submitted})
        log.info("Submitted %d jobs in %d array tasks (%d per task) as SLURM/submitit job(s) %s",
                 len(jobs), len(tasks), pack, ", ".join(ids))
        if not wait:
            from bench.run import callbacks

            callbacks.LAST_SWEEP["submitted"] = {"n_jobs": len(jobs), "n_tasks": len(tasks), "job_ids": ids}
            return [self._submitted_return(overrides) for overrides in job_overrides]
        return [ret for job in submitted for ret in job.results()[0]]

    def _executor(self, submitit):
        """The submitit executor with the plugin's parameters (as the submitit plugin builds it)."""
        from hydra_plugins.hydra_submitit_launcher.config import BaseQueueConf

        init = {"folder": self.params["submitit_folder"]}
        if "max_num_timeout" in self.params:
            init[f"{self._EXECUTOR}_max_num_timeout"] = self.params["max_num_timeout"]
        executor = submitit.AutoExecutor(cluster=self._EXECUTOR, **init)
        base = set(OmegaConf.structured(BaseQueueConf).keys())
        executor.update_parameters(**{k if k in base else f"{self._EXECUTOR}_{k}": v for k, v in self.params.items()
                                      if k not in ("submitit_folder", "max_num_timeout")})
        return executor

    def _submitted_return(self, overrides) -> JobReturn:
        ret = JobReturn(overrides=list(overrides), status=JobStatus.COMPLETED)
        ret.return_value = None
        return ret


class BenchSlurmLauncher(BenchSubmititLauncher):
    _EXECUTOR = "slurm"


class BenchLocalLauncher(BenchSubmititLauncher):
    _EXECUTOR = "local"


ConfigStore.instance().store(group="hydra/launcher", name="bench_slurm", node=BenchSlurmConf,
                             provider="bench_launcher")
ConfigStore.instance().store(group="hydra/launcher", name="bench_local", node=BenchLocalConf,
                             provider="bench_launcher")
