"""The benchmark harness: ``python -m bench`` (or ``avio-bench``) runs sweeps; see the README.

Importing it sets ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` to 1 where the environment does not
set them: the harness's numpy works on small arrays and the filter's own threads take the cores, so
BLAS's worker threads only spin beside them (4 % of a default job's CPU; benchmarks/README.md). It
takes effect where numpy is not imported yet, as in ``python -m bench`` and its workers.
"""

from __future__ import annotations

import os

# An environment variable, read once when numpy loads its BLAS: threadpoolctl's limits would have to be
# set again after every library that loads one (scipy's is loaded later, with its first linear algebra).
for _name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")


def version() -> str:
    """avio-bench's version: from a source checkout its ``pyproject.toml`` (an editable install's
    metadata keeps the version of its last ``pip install``), else the installed distribution's."""
    import tomllib
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version
    from pathlib import Path

    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        return tomllib.loads(pyproject.read_text())["project"]["version"]
    except (OSError, KeyError, tomllib.TOMLDecodeError):
        pass
    try:
        return dist_version("avio-bench")
    except PackageNotFoundError:
        return "unknown"
