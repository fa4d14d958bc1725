"""What made a record: code version, library versions, machine."""

from __future__ import annotations

import functools
import platform
import subprocess
from importlib import metadata
from pathlib import Path

_PACKAGES = ("numpy", "scipy", "pandas", "hydra-core", "omegaconf", "pymoo", "optuna", "cmaes",
             "nevergrad", "opencv-python-headless", "matplotlib")


def _git_commit() -> str:
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def provenance() -> dict:
    """``{"git_commit", "versions", "machine"}`` for records (computed once per process)."""
    return {
        "git_commit": _git_commit(),
        "versions": {"python": platform.python_version(), **{p: _version(p) for p in _PACKAGES}},
        "machine": {"node": platform.node(), "platform": platform.platform(),
                    "processor": platform.machine(), "cpus": __import__("os").cpu_count()},
    }
