"""Where the data lives by default: ``$AVIO_DATA`` always; else ``../shared/data`` beside the
repository when running from a source checkout; else a per-user data folder (an installed wheel
must not look for data inside ``site-packages``)."""

from __future__ import annotations

import os
from pathlib import Path

#: The repository root of a source checkout (``site-packages`` when installed from a wheel).
PACKAGE_PARENT = Path(__file__).resolve().parents[2]


def is_checkout(root: Path = PACKAGE_PARENT) -> bool:
    """Whether the packages run from a source checkout: a ``pyproject.toml`` beside them."""
    return (root / "pyproject.toml").is_file()


def user_data_dir() -> Path:
    """``$XDG_DATA_HOME/avio-bench`` (default ``~/.local/share/avio-bench``). By hand, not
    through platformdirs: one line, and no dependency for the VIO package."""
    return Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share") / "avio-bench"


def data_root() -> Path:
    """The data folder (the one holding ``kitti00/``, ``euroc_v1_01/``): ``$AVIO_DATA``, else
    ``../shared/data`` beside a source checkout, else :func:`user_data_dir`."""
    if os.environ.get("AVIO_DATA"):
        return Path(os.environ["AVIO_DATA"]).expanduser()
    return PACKAGE_PARENT.parent / "shared" / "data" if is_checkout() else user_data_dir()


__all__ = ["data_root", "is_checkout", "user_data_dir"]
