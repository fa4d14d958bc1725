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
                                ":(exclude)results"], cwd=root, capture_output=True, text=True,
                               timeout=5).stdout.strip()
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


def cpu_features() -> dict:
    """What a record's last bits depend on beside the code and the versions: the vector
    extensions numpy dispatches its math to (``numpy``: the highest found, e.g. AVX512_ICL or
    AVX2), OpenBLAS's kernel set (``openblas``, e.g. SkylakeX or Haswell) and the CPU LLVM compiles
    the filter for (``llvm``, e.g. znver4). A drive simulated with AVX-512 differs in the last bits
    from one simulated with AVX2 (docs/guide/running.md: "Bit-exact on one machine, not across vector extensions")."""
    import numpy  # noqa: F401  (loads numpy's OpenBLAS, whose kernel set threadpoolctl reads)
    from llvmlite import binding
    from threadpoolctl import threadpool_info

    try:  # numpy keeps them private: numpy._core from 2.0, numpy.core before
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    # __cpu_dispatch__ lists the extensions from the lowest to the highest
    found = [name for name in __cpu_dispatch__ if __cpu_features__.get(name)]
    blas = [i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"]
    return {"numpy": found[-1] if found else "baseline", "openblas": blas[0] if blas else None,
            "llvm": binding.get_host_cpu_name()}


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def provenance() -> dict:
    """``{"git_commit", "versions", "machine"}`` for records (computed once per process); versions
    include numba's (it compiles the filter) and machine the CPU model it compiles for and the
    vector extensions the floating-point bits depend on (:func:`cpu_features`)."""
    return {
        "git_commit": _git_commit(),
        "versions": {"python": platform.python_version(), **{p: _version(p) for p in _PACKAGES}},
        "machine": {"node": platform.node(), "platform": platform.platform(),
                    "processor": platform.machine(), "cpu_model": cpu_model(), "cpus": os.cpu_count(),
                    "cpu_features": cpu_features()},
    }
