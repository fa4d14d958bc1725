"""Check a sweep's launcher settings before anything is submitted (``python -m bench`` runs it after preflight).

For ``hydra/launcher=bench_slurm``, ``bench_local``, ``submitit_slurm`` and ``submitit_local``: every
``hydra.launcher.*`` key must be a setting of the chosen launcher, ``pack`` and ``max_array_size``
integers >= 1, ``wait`` a boolean (``false`` on SLURM only: a local worker ends with the sweep). On SLURM
the very batch script the launcher would submit (the first array, at its size) goes through
``sbatch --test-only``, which asks the controller without submitting: a partition the cluster does not
have, an account the user may not charge, a time limit over the partition's, an array over
``MaxArraySize`` are refused there. Any of these is one message naming the key; exit code 2.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import tempfile
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import HydraException
from omegaconf import OmegaConf

from bench.run.job import ConfigError

LAUNCHERS = ("bench_slurm", "bench_local", "submitit_slurm", "submitit_local")
#: sbatch settings worth naming when sbatch --test-only refuses the script
NAMED = ("partition", "account", "qos", "timeout_min", "constraint", "gres", "mem_gb", "cpus_per_task")


def chosen_launcher(argv: list[str]) -> str | None:
    """The launcher the command line selects (``hydra/launcher=NAME``), or None for Hydra's basic one."""
    for arg in argv:
        if arg.lstrip("+").startswith("hydra/launcher="):
            return arg.split("=", 1)[1]
    return None


def launcher_settings(argv: list[str], conf_dir: Path) -> dict:
    """The launcher's settings as Hydra composes them (an unknown key is a ConfigError naming it)."""
    wanted = [a for a in argv if a.lstrip("+").startswith(("hydra/launcher=", "hydra.launcher."))
              or a.startswith("hydra.sweep.dir=")]
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(conf_dir), version_base="1.3", job_name="bench"):
            try:
                cfg = compose("config", overrides=wanted, return_hydra_config=True)
            except HydraException as err:
                launcher = chosen_launcher(argv)
                bad = next((a for a in wanted if a.split("=")[0].split(".")[-1] in str(err)), None)
                key = bad.split("=")[0] if bad else "hydra.launcher"
                base = compose("config", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
                valid = sorted(k for k in base.hydra.launcher if k != "_target_")
                raise ConfigError(f"{key}: not a setting of hydra/launcher={launcher} "
                                  f"({str(err).splitlines()[0]}); valid settings: {', '.join(valid)}") from None
            return OmegaConf.to_container(cfg.hydra.launcher, resolve=True)
    finally:
        GlobalHydra.instance().clear()


def check_packing(settings: dict, launcher: str) -> None:
    for key in ("pack", "max_array_size"):
        value = settings.get(key, 1)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"hydra.launcher.{key} must be an integer >= 1, got {value!r}")
    wait = settings.get("wait", True)
    if not isinstance(wait, bool):
        raise ConfigError(f"hydra.launcher.wait must be true or false, got {wait!r}")
    if not wait and not launcher.endswith("slurm"):
        raise ConfigError(f"hydra.launcher.wait=false needs a cluster (hydra/launcher=bench_slurm): the workers of "
                          f"hydra/launcher={launcher} end with the sweep's process")


def sbatch_test_only(settings: dict, launcher: str, n_tasks: int) -> None:
    """Ask the SLURM controller whether it would take the first array the launcher submits (nothing submitted)."""
    import submitit

    from hydra_plugins.bench_launcher.launcher import BenchSlurmLauncher

    if shutil.which("sbatch") is None:
        raise ConfigError(f"hydra/launcher={launcher}: sbatch is not on PATH (not on a SLURM login node?)")
    params = {k: v for k, v in settings.items() if k != "_target_"}
    executor = BenchSlurmLauncher(**params)._executor(submitit)
    size = min(n_tasks, int(settings.get("max_array_size", 1000)) if launcher == "bench_slurm" else n_tasks)
    if size > 1:
        executor._executor.parameters["map_count"] = size
    with tempfile.TemporaryDirectory(prefix="bench-sbatch-") as tmp:
        script = Path(tmp) / "test.sh"
        script.write_text(executor._executor._make_submission_file_text("true", "test"))
        proc = subprocess.run(["sbatch", "--test-only", str(script)], capture_output=True, text=True, timeout=60)
    if proc.returncode != 0:
        reason = " ".join(line.strip() for line in proc.stderr.splitlines() if line.strip()) or "no reason given"
        named = ", ".join(f"{k}={settings[k]}" for k in NAMED if settings.get(k) is not None)
        extra = "" if launcher != "bench_slurm" else f", array of {size} task(s)"
        raise ConfigError(f"hydra.launcher: the cluster refuses the sweep's jobs ({named}{extra}): {reason}")


def check_launcher(argv: list[str], conf_dir: Path, n_jobs: int) -> None:
    """Raise ConfigError when the chosen launcher's settings are invalid or the cluster would refuse them."""
    launcher = chosen_launcher(argv)
    if launcher not in LAUNCHERS:
        return
    settings = launcher_settings(argv, conf_dir)
    check_packing(settings, launcher)
    if launcher.endswith("slurm"):
        pack = int(settings.get("pack", 1))
        sbatch_test_only(settings, launcher, max(1, math.ceil(n_jobs / pack)))
