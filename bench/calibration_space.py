"""The two search spaces over a camera + camera–IMU calibration, and their decoding.

- ``paper``: the paper's 10 variables with its Table 1 bounds: fx, fy, cx, cy (px),
  ZYX Euler angles roll, pitch, yaw (deg, ``R_cam_imu = Rz(yaw) Ry(pitch) Rx(roll)``, Eq. 9)
  and the camera origin in the IMU frame tx, ty, tz (m, Eq. 10). Near pitch = -90 deg only
  roll + yaw is well determined (gimbal lock, PAPER.md §6).
- ``local``: well conditioned: the same intrinsics, a small rotation vector ``rx, ry, rz``
  (deg, in the camera frame: ``R_cam_imu = Exp(r) R_nominal``) and a translation offset
  ``dx, dy, dz`` (m) around a nominal calibration (the reference).

Either can add the camera–IMU time offset ``td`` (s) as an 11th variable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avio.geometry import euler_zyx_deg_to_matrix, matrix_to_euler_zyx_deg, so3_exp, so3_log
from avio.reference import PAPER_TABLE1
from avio.sequence import Calibration
from bench.space import Space, SpaceError

SPACES = ("paper", "local")
_INTRINSICS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class CalibrationSpace:
    """A ``Space`` plus the map from its points to calibrations.

    kind: "paper" or "local"; nominal: the batch-of-1 calibration the local space is centred on
    (and whose values are the reference point of either space).
    """

    kind: str
    space: Space
    nominal: Calibration

    def decode(self, X: np.ndarray) -> Calibration:
        """(n, d) points → a batch of n calibrations."""
        X = np.asarray(X, float)
        n = len(X)
        col = {name: X[:, i] for i, name in enumerate(self.space.names)}
        if self.kind == "paper":
            R = euler_zyx_deg_to_matrix(col["roll"], col["pitch"], col["yaw"])
            p = np.stack([col["tx"], col["ty"], col["tz"]], axis=1)
        else:
            r = np.radians(np.stack([col["rx"], col["ry"], col["rz"]], axis=1))
            R = so3_exp(r) @ self.nominal.R_cam_imu[0]
            p = self.nominal.p_imu_cam_m[0] + np.stack([col["dx"], col["dy"], col["dz"]], axis=1)
        td = col["td"] if "td" in col else np.full(n, float(self.nominal.time_offset_s[0]))
        return Calibration(col["fx"], col["fy"], col["cx"], col["cy"], R, p, td)

    def encode(self, calibration: Calibration) -> np.ndarray:
        """A batch of calibrations → (n, d) points (the inverse of ``decode``)."""
        c = calibration
        if self.kind == "paper":
            parts = list(paper_parameters(c, self.nominal).T)
        else:
            parts = [c.fx_px, c.fy_px, c.cx_px, c.cy_px]
            r = np.degrees(so3_log(c.R_cam_imu @ self.nominal.R_cam_imu[0].T))
            parts += list(r.T) + list((c.p_imu_cam_m - self.nominal.p_imu_cam_m[0]).T)
        if "td" in self.space.names:
            parts.append(c.time_offset_s)
        return np.stack(parts, axis=1)


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


def _euler_near(R: np.ndarray, R_nominal: np.ndarray) -> np.ndarray:
    """(n, 3) (roll, pitch, yaw) deg of ``R`` on the Euler branch nearest the nominal's angles.

    Every rotation has two ZYX triples, (r, p, y) and (r + 180, -180 - p, y + 180); near the
    paper's pitch of -90 deg both are in play, and scipy always returns |p| <= 90.
    """
    nominal = matrix_to_euler_zyx_deg(R_nominal)
    first = matrix_to_euler_zyx_deg(R)
    second = np.stack([first[:, 0] + 180.0, -180.0 - first[:, 1], first[:, 2] + 180.0], axis=1)
    candidates = np.stack([first, second])  # (2, n, 3)
    distance = np.abs(_wrap_deg(candidates - nominal)).sum(axis=-1)
    chosen = candidates[np.argmin(distance, axis=0), np.arange(len(first))]
    return nominal + _wrap_deg(chosen - nominal)


def paper_parameters(calibration: Calibration, nominal: Calibration) -> np.ndarray:
    """(n, 10) the paper's variables (fx, fy, cx, cy px; roll, pitch, yaw deg; tx, ty, tz m) of a
    batch of calibrations, the Euler angles on the branch nearest the nominal's."""
    c = calibration
    angles = _euler_near(c.R_cam_imu, nominal.R_cam_imu[0])
    return np.column_stack([c.fx_px, c.fy_px, c.cx_px, c.cy_px, angles, c.p_imu_cam_m])


def make_calibration_space(
    kind: str,
    nominal: Calibration,
    with_time_offset: bool = False,
    rotation_bound_deg: float = 5.0,
    translation_bound_m: float = 0.25,
    time_offset_bound_s: float = 0.05,
    bounds: dict | None = None,
) -> CalibrationSpace:
    """Build the ``paper`` or ``local`` space around ``nominal`` (batch of 1).

    ``bounds`` overrides any variable's ``[lower, upper]``; the paper space's defaults are its
    Table 1, the local space's are Table 1 for the intrinsics and ``±rotation_bound_deg``,
    ``±translation_bound_m`` for the extrinsic offsets.
    """
    if kind not in SPACES:
        raise SpaceError(f"unknown space {kind!r}; valid: {', '.join(SPACES)}")
    if len(nominal) != 1:
        raise SpaceError(f"the nominal calibration must be a batch of 1, got {len(nominal)}")
    table = {k: (v[1], v[2]) for k, v in PAPER_TABLE1.items()}
    if kind == "paper":
        names = list(PAPER_TABLE1)
        units = ["px"] * 4 + ["deg"] * 3 + ["m"] * 3
        limits = dict(table)
    else:
        names = list(_INTRINSICS) + ["rx", "ry", "rz", "dx", "dy", "dz"]
        units = ["px"] * 4 + ["deg"] * 3 + ["m"] * 3
        limits = {k: table[k] for k in _INTRINSICS}
        limits.update({k: (-rotation_bound_deg, rotation_bound_deg) for k in ("rx", "ry", "rz")})
        limits.update({k: (-translation_bound_m, translation_bound_m) for k in ("dx", "dy", "dz")})
    if with_time_offset:
        names.append("td")
        units.append("s")
        limits["td"] = (-time_offset_bound_s, time_offset_bound_s)
    for name, pair in (bounds or {}).items():
        if name not in limits:
            raise SpaceError(f"bounds given for unknown variable {name!r}; variables: {', '.join(names)}")
        limits[name] = (float(pair[0]), float(pair[1]))
    provisional = CalibrationSpace(kind, Space(tuple(names), tuple(units), np.zeros(len(names)),
                                              np.ones(len(names)), np.zeros(len(names))), nominal)
    reference = provisional.encode(nominal)[0]
    lower = np.array([limits[n][0] for n in names], float)
    upper = np.array([limits[n][1] for n in names], float)
    return CalibrationSpace(kind, Space(tuple(names), tuple(units), lower, upper, reference), nominal)
