"""What every dataset loader shares: the dataset error, a numeric-table reader that names the bad
line, the increasing-time check, and the content hash a loaded sequence carries as its identity."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from avio.errors import AvioError
from avio.sequence import Sequence, content_hash


class DatasetError(AvioError):
    """A data file is missing or malformed, or a request does not fit the data; the message names
    the file and line (or key), or the frames."""


def read_numeric_table(
    path: str | Path, n_cols: int, skip_rows: int = 0, delimiter: str | None = None,
    error: type[Exception] = DatasetError,
) -> np.ndarray:
    """(n_rows, n_cols) float array from a text table; ``error`` names file and line on failure.

    The fast path is ``np.loadtxt``; only when it fails are the lines scanned one by one, to
    name the first bad line (loadtxt's own message does not say which file).
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: file not found")
    try:
        table = np.loadtxt(path, skiprows=skip_rows, delimiter=delimiter, ndmin=2, dtype=float)
    except ValueError:
        table = None
    if table is not None and table.shape[1] == n_cols and np.all(np.isfinite(table)):
        return table
    with open(path) as handle:
        for line_no, line in enumerate(handle, start=1):
            if line_no <= skip_rows or not line.strip():
                continue
            fields = line.strip().split(delimiter)
            try:
                values = [float(x) for x in fields]
            except ValueError:
                raise error(f"{path}:{line_no}: not a number in {line.strip()[:80]!r}") from None
            if len(values) != n_cols:
                raise error(f"{path}:{line_no}: expected {n_cols} numbers, got {len(values)}")
            if not np.all(np.isfinite(values)):
                raise error(f"{path}:{line_no}: non-finite value in {line.strip()[:80]!r}")
    raise error(f"{path}: no data rows")


def check_increasing(t: np.ndarray, path: Path, lines: np.ndarray | int, what: str = "",
                     error: type[Exception] = DatasetError) -> None:
    """``error`` naming the first sample whose time does not increase, by its file line.

    lines: (n,) the file line of each sample, or the line of the first sample (the rest follow).
    """
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        line = lines + i if isinstance(lines, int) else lines[i]
        label = f"{what} time" if what else "time"
        raise error(f"{path}:{line}: {label} {t[i]!r} does not increase (previous {t[i - 1]!r})")


def with_content_hash(seq: Sequence, extra_arrays: list[np.ndarray] | None = None,
                      extra_settings: dict | None = None) -> Sequence:
    """``seq`` with the content hash of everything a filter run reads in ``meta["content_hash"]``:
    the IMU, frame times, ground truth and tracks, then ``extra_arrays``; the settings are the
    sequence's meta (less its folder: identity, not location) updated with ``extra_settings``."""
    arrays = [seq.imu.t_s, seq.imu.accel_imu_mps2, seq.imu.gyro_imu_radps, seq.frame_t_s,
              seq.truth.p_world_imu_m, seq.truth.R_world_imu, seq.truth.v_world_imu_mps,
              seq.tracks.frame_index, seq.tracks.uv_px, seq.tracks.valid, *(extra_arrays or [])]
    settings = {k: v for k, v in seq.meta.items() if k != "data_dir"}
    settings.update(extra_settings or {})
    return replace(seq, meta={**seq.meta, "content_hash": content_hash(arrays, settings)})
