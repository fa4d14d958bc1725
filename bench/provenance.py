"""What made a record: code version, library versions, machine."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

_PACKAGES = ("numpy", "numba", "scipy", "pandas", "hydra-core", "omegaconf", "pymoo", "optuna", "cmaes",
             "nevergrad", "opencv-python-headless", "matplotlib", "tqdm")


def _git_commit(root: Path = Path(__file__).resolve().parents[1]) -> str:
    """HEAD's commit, with "-dirty" when a tracked file outside results/ differs from it. The
    committed results are outputs, not code: a sweep made while an earlier one's records or
    provenance lines are not yet committed (scripts/make_results.sh) is still made by HEAD."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                                ":(exclude)results"], cwd=root, capture_output=True, text=True, timeout=5).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def cpu_model() -> str:
    """The CPU's model name (numba compiles the filter for it): /proc/cpuinfo on Linux, sysctl on
    macOS, else ``platform.processor()``; "unknown" when none says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "Model", "cpu model", "Hardware") and value.strip():
                return value.strip()
    except OSError:
        pass
    try:
        out = subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True,
                             timeout=5).stdout.strip()
        if out:
            return out
    except (OSError, subprocess.SubprocessError):
        pass
    return platform.processor() or "unknown"


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def provenance() -> dict:
    """``{"git_commit", "versions", "machine"}`` for records (computed once per process); versions
    include numba's (it compiles the filter) and machine the CPU model it compiles for."""
    return {
        "git_commit": _git_commit(),
        "versions": {"python": platform.python_version(), **{p: _version(p) for p in _PACKAGES}},
        "machine": {"node": platform.node(), "platform": platform.platform(),
                    "processor": platform.machine(), "cpu_model": cpu_model(), "cpus": os.cpu_count()},
    }
