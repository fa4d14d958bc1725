"""``python -m bench [overrides]``: validate every job, then run the sweep with Hydra.

Examples::

    python -m bench                                   # the default comparison
    python -m bench optimizer=psoga,pso,cmaes seed='range(10)'
    python -m bench problem=rastrigin budget.evals=500 hydra.sweep.dir=runs/mine   # resumable folder
"""

from __future__ import annotations

import logging
import os
import sys
import uuid
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from bench.job import plain, run_configured_job
from bench.preflight import preflight

log = logging.getLogger("bench")

# Part of the default sweep folder name: a timestamp alone lets two sweeps started in the
# same second share a folder. Cached by OmegaConf, and Hydra copies the cache into every job.
OmegaConf.register_new_resolver("bench_unique", lambda: f"{os.getpid()}-{uuid.uuid4().hex[:6]}",
                                use_cache=True, replace=True)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def _job(cfg: DictConfig) -> float | None:
    hc = HydraConfig.get()
    job_dir = Path(hc.runtime.output_dir)
    label = f"job #{hc.job.num} {cfg.problem.name}/{cfg.optimizer.name}/seed{cfg.seed}"
    log.info("%s -> %s", label, job_dir)
    record = run_configured_job(plain(cfg), job_dir, label=label)
    return record.get("best_f")


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    code = preflight(argv)
    if code:
        raise SystemExit(code)
    _job()


if __name__ == "__main__":
    main()
