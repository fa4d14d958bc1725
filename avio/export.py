"""Trajectories to the text formats evo reads (TUM and KITTI), and back.

- TUM: one line per pose, ``t tx ty tz qx qy qz qw`` (seconds to 1 ns, metres, unit quaternion with
  the scalar last), space-separated; lines starting with ``#`` are comments.
- KITTI: one line per pose, the 3x4 matrix ``[R | t]`` row-major (12 numbers), no time stamps.

The pose written is ``T_world_imu``: ``R_world_imu`` (maps IMU vectors into the world frame) and
``p_world_imu_m``. Numbers are written with 17 significant digits (they read back bit for bit). Files are
written atomically (temporary file, then rename).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from avio.errors import AvioError


class ExportError(AvioError):
    """A trajectory cannot be written or a file cannot be read back; the message says where."""


def _atomic_write(path: Path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _check(p_world_imu_m, R_world_imu, t_s=None):
    p = np.asarray(p_world_imu_m, float)
    R = np.asarray(R_world_imu, float)
    N = p.shape[0]
    if p.shape != (N, 3) or R.shape != (N, 3, 3):
        raise ExportError(f"need positions (N, 3) and rotations (N, 3, 3), got {p.shape} and {R.shape}")
    if t_s is not None and np.asarray(t_s).shape != (N,):
        raise ExportError(f"need times (N,) = ({N},), got {np.asarray(t_s).shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
        raise ExportError("trajectory has non-finite values (a diverged filter?)")
    return p, R


def write_tum(path, t_s, p_world_imu_m, R_world_imu) -> None:
    """Write ``t tx ty tz qx qy qz qw`` lines; t_s (N,) s, p (N, 3) m, R (N, 3, 3)."""
    p, R = _check(p_world_imu_m, R_world_imu, t_s)
    xyzw = Rotation.from_matrix(R).as_quat()
    rows = np.column_stack([np.asarray(t_s, float), p, xyzw])
    lines = ["# timestamp tx ty tz qx qy qz qw  (T_world_imu)"]
    lines += [" ".join(f"{x:.9f}" if i == 0 else f"{x:.17g}" for i, x in enumerate(r)) for r in rows]
    _atomic_write(path, "\n".join(lines) + "\n")


def write_kitti(path, p_world_imu_m, R_world_imu) -> None:
    """Write the 3x4 ``[R | t]`` of each pose row-major, 12 numbers a line."""
    p, R = _check(p_world_imu_m, R_world_imu)
    M = np.concatenate([R, p[:, :, None]], axis=2).reshape(len(p), 12)
    _atomic_write(path, "\n".join(" ".join(f"{x:.17g}" for x in r) for r in M) + "\n")


def _read_rows(path, width: int) -> np.ndarray:
    rows = []
    with open(path) as f:
        for lineno, line in enumerate(f, start=1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split()
            if len(parts) != width:
                raise ExportError(f"{path}:{lineno}: expected {width} numbers, got {len(parts)}")
            try:
                rows.append([float(x) for x in parts])
            except ValueError as err:
                raise ExportError(f"{path}:{lineno}: {err}") from None
    return np.array(rows, float).reshape(-1, width)


def read_tum(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_s (N,), p (N, 3), R (N, 3, 3))`` from a TUM file."""
    rows = _read_rows(path, 8)
    return rows[:, 0], rows[:, 1:4], Rotation.from_quat(rows[:, 4:8]).as_matrix()


def read_kitti(path) -> tuple[np.ndarray, np.ndarray]:
    """``(p (N, 3), R (N, 3, 3))`` from a KITTI pose file."""
    M = _read_rows(path, 12).reshape(-1, 3, 4)
    return M[:, :, 3], M[:, :, :3]
