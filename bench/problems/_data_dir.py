"""Where a VIO problem's data is, and the missing-data message that says how to point at it."""

from __future__ import annotations

from pathlib import Path

from avio.datasets.paths import data_root
from bench.problems.base import ProblemError

#: How to point a problem at its data, appended to every missing-data message.
DATA_HINT = ("point at the folder holding it with AVIO_DATA=/path/to/data or problem.params.data_dir=/path/to/data; "
             "`python -m bench.data` lists the files and where to get them")


def default_data_dir(data_dir: str | None = None) -> Path:
    """``data_dir``, else avio.datasets.paths.data_root(): ``$AVIO_DATA``, else ``../shared/data``
    beside the repository from a source checkout, else a user data folder (a wheel's install has
    no repository beside it)."""
    return Path(data_dir).expanduser() if data_dir else data_root()


def require_data(data_dir: str | None, folder: str, files: tuple[str, ...], what: str) -> Path:
    """``<data dir>/<folder>`` once it holds ``files``; else a ProblemError naming the first
    missing file and how to point at the data (:data:`DATA_HINT`)."""
    root = default_data_dir(data_dir)
    for path in (root / folder / name for name in files):
        if not path.is_file():
            raise ProblemError(f"{path}: {what} data file not found (data folder {root}); {DATA_HINT}")
    return root / folder


def with_data_hint(params, err: ProblemError) -> ProblemError:
    """``err`` with :data:`DATA_HINT` when it is a missing file of a source that reads ``data_dir``
    (a loader's "file not found", e.g. EuRoC's Kalibr file read for the nominal calibration)."""
    text = str(err)
    if hasattr(params, "data_dir") and "not found" in text and DATA_HINT not in text:
        return ProblemError(f"{text}; {DATA_HINT}")
    return err


def checked_data(params):
    """``params`` after its :meth:`~bench.problems.vio.VioParams.check_data` (missing data: with the hint)."""
    try:
        params.check_data()
    except ProblemError as err:
        raise with_data_hint(params, err) from None
    return params
