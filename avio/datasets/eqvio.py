"""eqvio's processed EuRoC CSV (``eqvio_processed_30s.csv``): one table of ``imu`` rows (``t_abs``,
``gx gy gz`` rad/s, ``ax ay az`` m/s^2, IMU frame), ``vision_feature`` rows (``t_abs, frame_idx,
landmark_id, u_norm, v_norm``: *undistorted normalised* coordinates) and ``meta`` rows (``key,
value``). The readers raise ``error`` (a DatasetError by default; the EuRoC loader passes
EurocDataError) naming the file and line, or the meta key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from avio.datasets._io import DatasetError

FEATURE_COLUMNS = {"imu": ("t_abs", "gx", "gy", "gz", "ax", "ay", "az"),
                   "vision_feature": ("t_abs", "frame_idx", "landmark_id", "u_norm", "v_norm")}


def _numeric_column(frame: pd.DataFrame, column: str, path: Path, error: type[Exception]) -> np.ndarray:
    """(rows,) float values of ``column``; the first missing or non-numeric one is an error
    naming its line (pandas index + 2: the header is line 1 and blank lines are kept)."""
    values = pd.to_numeric(frame[column], errors="coerce").to_numpy(float)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = frame.index[bad[0]]
        raise error(f"{path}:{i + 2}: {frame['row_type'].iloc[bad[0]]} row has no valid "
                    f"{column} ({frame[column].iloc[bad[0]]!r})")
    return values


def read_eqvio_csv(path: Path, error: type[Exception] = DatasetError) -> tuple[dict, dict]:
    """``(columns per row type, meta key -> value)`` of an eqvio CSV (module doc); each row type's
    columns also hold ``line``, the file line of each row."""
    if not path.is_file():
        raise error(f"{path}: file not found")
    try:
        table = pd.read_csv(path, dtype=str, skip_blank_lines=False, keep_default_na=False)
    except (pd.errors.ParserError, UnicodeDecodeError) as err:
        raise error(f"{path}: not a readable CSV ({err})") from None
    needed = {"row_type", "key", "value", *(c for cols in FEATURE_COLUMNS.values() for c in cols)}
    missing = sorted(needed - set(table.columns))
    if missing:
        raise error(f"{path}:1: header lacks columns {missing}")
    table = table.replace("", np.nan)
    columns = {}
    for row_type, names in FEATURE_COLUMNS.items():
        rows = table[table["row_type"] == row_type]
        if rows.empty:
            raise error(f"{path}: no {row_type!r} rows")
        columns[row_type] = {c: _numeric_column(rows, c, path, error) for c in names}
        columns[row_type]["line"] = rows.index.to_numpy() + 2
    meta_rows = table[table["row_type"] == "meta"]
    meta = dict(zip(meta_rows["key"], meta_rows["value"]))
    return columns, meta


def meta_float(meta: dict, key: str, path: Path, error: type[Exception] = DatasetError) -> float:
    """The finite number of meta row ``key``."""
    try:
        value = float(meta[key])
    except KeyError:
        raise error(f"{path}: no meta row {key!r}") from None
    except (TypeError, ValueError):
        raise error(f"{path}: meta row {key!r} is not a number: {meta[key]!r}") from None
    if not np.isfinite(value):
        raise error(f"{path}: meta row {key!r} is not finite: {meta[key]!r}")
    return value
