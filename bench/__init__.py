"""The benchmark harness: ``python -m bench`` (or ``avio-bench``) runs sweeps; see the README."""

from __future__ import annotations


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
