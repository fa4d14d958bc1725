"""The two search spaces over a camera + camera–IMU calibration, and their decoding.

- ``paper``: the paper's 10 variables with its Table 1 bounds: fx, fy, cx, cy (px),
  ZYX Euler angles roll, pitch, yaw (deg, ``R_cam_imu = Rz(yaw) Ry(pitch) Rx(roll)``, Eq. 9)
  and the camera origin in the IMU frame tx, ty, tz (m, Eq. 10). Near pitch = -90 deg only
  roll + yaw is well determined (gimbal lock, docs/model.md, Eq. 4).
- ``local``: well conditioned: the same intrinsics, a small rotation vector ``rx, ry, rz``
  (deg, in the camera frame: ``R_cam_imu = Exp(r) R_nominal``) and a translation offset
  ``dx, dy, dz`` (m) around a nominal calibration (the reference).

Either can add the camera–IMU time offset ``td`` (s) as an 11th variable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avio.calibration import Calibration
from avio.geometry import euler_zyx_deg_to_matrix, matrix_to_euler_zyx_deg, so3_exp, so3_log
from avio.reference import PAPER_TABLE1
from bench.space import Space, SpaceError

SPACES = ("paper", "local")
_INTRINSICS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class CalibrationSpace:
    """A ``Space`` plus the map from its points to calibrations.

    kind: "paper" or "local"; nominal: the batch-of-1 calibration the local space is centred on
    (and whose values are the reference point of either space).
    full: every variable of the kind; ``space`` holds the free ones the optimiser sees: the
    ``fixed`` variables stay at the nominal's values, and with ``tie_focal`` fy is not a
    variable but equals fx (square pixels).
    """

    kind: str
    space: Space
    nominal: Calibration
    full: Space | None = None
    fixed: tuple[str, ...] = ()
    tie_focal: bool = False

    @property
    def full_space(self) -> Space:
        return self.space if self.full is None else self.full

    def expand(self, X: np.ndarray) -> np.ndarray:
        """(n, d_free) points of ``space`` -> (n, d_full) points of ``full_space``."""
        X = np.asarray(X, float)
        full = self.full_space
        if full is self.space:
            return X
        out = np.repeat(full.reference[None], len(X), axis=0)
        for j, name in enumerate(self.space.names):
            out[:, full.names.index(name)] = X[:, j]
        if self.tie_focal:
            out[:, full.names.index("fy")] = out[:, full.names.index("fx")]
        return out

    def decode(self, X: np.ndarray) -> Calibration:
        """(n, d) points → a batch of n calibrations."""
        X = self.expand(X)
        n = len(X)
        col = {name: X[:, i] for i, name in enumerate(self.full_space.names)}
        if self.kind == "paper":
            R = euler_zyx_deg_to_matrix(col["roll"], col["pitch"], col["yaw"])
            p = np.stack([col["tx"], col["ty"], col["tz"]], axis=1)
        else:
            r = np.radians(np.stack([col["rx"], col["ry"], col["rz"]], axis=1))
            R = so3_exp(r) @ self.nominal.R_cam_imu[0]
            p = self.nominal.p_imu_cam_m[0] + np.stack([col["dx"], col["dy"], col["dz"]], axis=1)
        td = col["td"] if "td" in col else np.full(n, float(self.nominal.time_offset_s[0]))
        return Calibration(col["fx"], col["fy"], col["cx"], col["cy"], R, p, td)

    def encode_full(self, calibration: Calibration) -> np.ndarray:
        """A batch of calibrations → (n, d_full) points of ``full_space``."""
        c = calibration
        if self.kind == "paper":
            parts = list(paper_parameters(c, self.nominal).T)
        else:
            parts = [c.fx_px, c.fy_px, c.cx_px, c.cy_px]
            r = np.degrees(so3_log(c.R_cam_imu @ self.nominal.R_cam_imu[0].T))
            parts += list(r.T) + list((c.p_imu_cam_m - self.nominal.p_imu_cam_m[0]).T)
        if "td" in self.full_space.names:
            parts.append(c.time_offset_s)
        return np.stack(parts, axis=1)

    def encode(self, calibration: Calibration) -> np.ndarray:
        """A batch of calibrations → (n, d) points of ``space`` (the inverse of ``decode`` on the
        free variables; frozen and tied ones are dropped)."""
        X = self.encode_full(calibration)
        full = self.full_space
        return X[:, [full.names.index(name) for name in self.space.names]]


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


#: Half-widths of the local space's intrinsics around the nominal: focal lengths as a fraction
#: of the nominal focal, the principal point as a fraction of the larger image side. For KITTI
#: (718.9 px, 1241 px) that is +-21.6 px and +-24.8 px, about Table 1's ranges; for EuRoC
#: (458 px, 752 px) +-13.8 px and +-15.0 px.
LOCAL_FOCAL_FRACTION, LOCAL_PRINCIPAL_FRACTION = 0.03, 0.02


def _check_bounds_are_free(bounds: dict | None, fixed: tuple[str, ...], tie_focal: bool) -> None:
    """SpaceError naming the variable when bounds are given for one that is not a variable (fixed, or fy
    tied to fx): they would be dropped silently, and the user meant something else."""
    for name in bounds or {}:
        if name in fixed:
            raise SpaceError(f"bounds.{name} given, but {name} is fixed (frozen at the nominal, so it has no bounds): "
                             f"drop bounds.{name} or take {name} out of fixed")
        if tie_focal and name == "fy":
            raise SpaceError("bounds.fy given, but tie_focal makes fy equal fx (fy is not a variable): "
                             "bound fx instead, or set tie_focal: false")


def make_calibration_space(
    kind: str,
    nominal: Calibration,
    with_time_offset: bool = False,
    rotation_bound_deg: float = 5.0,
    translation_bound_m: float = 0.25,
    time_offset_bound_s: float = 0.05,
    bounds: dict | None = None,
    image_size_px: tuple[int, int] | None = None,
    fixed: tuple[str, ...] | list[str] = (),
    tie_focal: bool = False,
) -> CalibrationSpace:
    """Build the ``paper`` or ``local`` space around ``nominal`` (batch of 1).

    ``bounds`` overrides any variable's ``[lower, upper]``. The paper space's defaults are its
    Table 1 (the KITTI rig's numbers); the local space's come from the rig itself: the nominal
    intrinsics ``+- LOCAL_FOCAL_FRACTION`` of the focal length and ``+- LOCAL_PRINCIPAL_FRACTION``
    of the larger side of ``image_size_px`` (required), ``+-rotation_bound_deg`` and
    ``+-translation_bound_m`` for the extrinsic offsets. ``fixed`` variables are frozen at the
    nominal's values; ``tie_focal`` makes fy equal fx (fy is then not a variable); bounds for a fixed
    or tied variable are refused. SpaceError names the variable for anything invalid (unknown names,
    a focal bound <= 0, ...).
    """
    if kind not in SPACES:
        raise SpaceError(f"unknown space {kind!r}; valid: {', '.join(SPACES)}")
    if len(nominal) != 1:
        raise SpaceError(f"the nominal calibration must be a batch of 1, got {len(nominal)}")
    units = ["px"] * 4 + ["deg"] * 3 + ["m"] * 3
    if kind == "paper":
        names = list(PAPER_TABLE1)
        limits = {k: (v[1], v[2]) for k, v in PAPER_TABLE1.items()}
    else:
        if image_size_px is None:
            raise SpaceError("the local space needs the image size (its principal-point range)")
        names = list(_INTRINSICS) + ["rx", "ry", "rz", "dx", "dy", "dz"]
        f_half = LOCAL_FOCAL_FRACTION * float(max(nominal.fx_px[0], nominal.fy_px[0]))
        c_half = LOCAL_PRINCIPAL_FRACTION * float(max(image_size_px))
        limits = {"fx": (nominal.fx_px[0] - f_half, nominal.fx_px[0] + f_half),
                  "fy": (nominal.fy_px[0] - f_half, nominal.fy_px[0] + f_half),
                  "cx": (nominal.cx_px[0] - c_half, nominal.cx_px[0] + c_half),
                  "cy": (nominal.cy_px[0] - c_half, nominal.cy_px[0] + c_half)}
        limits.update({k: (-rotation_bound_deg, rotation_bound_deg) for k in ("rx", "ry", "rz")})
        limits.update({k: (-translation_bound_m, translation_bound_m) for k in ("dx", "dy", "dz")})
    if with_time_offset:
        names.append("td")
        units.append("s")
        limits["td"] = (-time_offset_bound_s, time_offset_bound_s)
    for name, pair in (bounds or {}).items():
        if name not in limits:
            raise SpaceError(f"bounds given for unknown variable {name!r}; variables: {', '.join(names)}")
        try:
            lo, hi = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise SpaceError(f"bounds.{name} must be [lower, upper] numbers, got {pair!r}") from None
        limits[name] = (lo, hi)
    for name in ("fx", "fy"):
        if not limits[name][0] > 0:
            raise SpaceError(f"bounds.{name}: the lower bound {limits[name][0]} admits a non-positive focal length")
    fixed = tuple(fixed or ())
    for name in fixed:
        if name not in names:
            raise SpaceError(f"fixed: unknown variable {name!r}; variables: {', '.join(names)}")
    if tie_focal and ("fx" in fixed) != ("fy" in fixed):
        raise SpaceError("tie_focal with only one of fx, fy fixed: fix both or neither")
    _check_bounds_are_free(bounds, fixed, tie_focal)
    provisional = CalibrationSpace(kind, Space(tuple(names), tuple(units), np.zeros(len(names)),
                                              np.ones(len(names)), np.zeros(len(names))), nominal)
    reference = provisional.encode(nominal)[0]
    lower = np.array([limits[n][0] for n in names], float)
    upper = np.array([limits[n][1] for n in names], float)
    full = Space(tuple(names), tuple(units), lower, upper, reference)
    drop = set(fixed) | ({"fy"} if tie_focal else set())
    if len(drop) >= len(names):
        raise SpaceError("fixed: every variable is frozen; nothing left to calibrate")
    if not drop:
        return CalibrationSpace(kind, full, nominal)
    keep = [i for i, n in enumerate(names) if n not in drop]
    free = Space(tuple(names[i] for i in keep), tuple(units[i] for i in keep), lower[keep], upper[keep],
                 reference[keep])
    return CalibrationSpace(kind, free, nominal, full=full, fixed=fixed, tie_focal=bool(tie_focal))
