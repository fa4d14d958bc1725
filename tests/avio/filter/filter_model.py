"""Batched wrappers of the kernel's per-filter steps, for tests only: the measurement chain and the
injection of n filters, checked against finite differences in test_measurement.py; and the
trifocal residuals of F features for n filters' relative poses (test_measurement.py, test_euroc.py)."""

from __future__ import annotations

import numba
import numpy as np

from avio.calibration import Calibration
from avio.filter.batch import _calibrations, _f64, _State
from avio.filter.measurement import MeasurementError, measure, measure_workspace
from avio.filter.trifocal import feature_residuals, rot_t
from avio.filter.update import inject


@numba.njit(cache=True, error_model="numpy")
def measure_all(R, p, v, cp, cR, omega, td, fx, fy, cx, cy, Rci, pic, uv):
    """:func:`avio.filter.measurement.measure` of the n filters for the features uv (F, 3, 2) shared
    by the batch: (r (n, F, 4), J (n, F, 4, 12), C (n, 12, 27), t12 (n, 3), t13 (n, 3))."""
    n, F = R.shape[0], uv.shape[0]
    r, J, C = np.empty((n, F, 4)), np.empty((n, F, 4, 12)), np.empty((n, 12, 27))
    rT, JT, Gp = np.empty((4, F)), np.empty((4, 12, F)), np.empty((4, 6, F))
    r1, J1, G1 = np.empty(4), np.empty((4, 12)), np.empty((4, 6))
    t12, t13 = np.empty((n, 3)), np.empty((n, 3))
    ws = measure_workspace()
    for i in range(n):
        measure(R[i], p[i], v[i], cp[0, i], cR[0, i], cp[1, i], cR[1, i], omega[i], td[i], fx[i], fy[i],
                cx[i], cy[i], Rci[i], pic[i], uv, rT, JT, Gp, C[i], t12[i], t13[i], ws)
        # measure leaves residual 1 (the Sampson distance 2-3) zero: it, from the same relative poses
        a12 = (t12[i, 0], t12[i, 1], t12[i, 2])
        a13 = (t13[i, 0], t13[i, 1], t13[i, 2])
        a23 = rot_t(ws.R12, (a13[0] - a12[0], a13[1] - a12[1], a13[2] - a12[2]))
        for f in range(F):
            feature_residuals(uv[f], ws.R12, a12, ws.R13, a13, ws.R23, a23, fx[i], fy[i], cx[i], cy[i], r1, J1, G1)
            rT[1, f] = r1[1]
            for b in range(12):
                JT[1, b, f] = J1[1, b]
        for f in range(F):
            for a in range(4):
                r[i, f, a] = rT[a, f]
                for b in range(12):
                    J[i, f, a, b] = JT[a, b, f]
    return r, J, C, t12, t13


@numba.njit(cache=True, error_model="numpy")
def inject_all(R, p, v, ba, bg, cp, cR, dx):
    """:func:`avio.filter.update.inject` of the n filters, dx (n, 27)."""
    E, T = np.empty((3, 3)), np.empty((3, 3))
    for i in range(R.shape[0]):
        inject(R[i], p[i], v[i], ba[i], bg[i], cp[0, i], cR[0, i], cp[1, i], cR[1, i], dx[i], E, T)


def measurement_model(st: _State, cal: Calibration, uv_px, omega, td):
    """Innovations r (n, F, 4) pixels, their Jacobian J (n, F, 4, 12) w.r.t. the relative-pose
    errors of the triplet and the map C (n, 12, 27) from the error state to those, so that the
    measurement Jacobian is ``H = J C`` (``dr = -H dx``); also t12, t13 (n, 3)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return measure_all(st.R, st.p, st.v, st.cp, st.cR, _f64(omega), _f64(td), *_calibrations(cal)[:6], _f64(uv_px))


def inject_correction(st: _State, dx) -> None:
    """Add the error-state correction dx (n, 27) to the nominal states (local rotation errors)."""
    inject_all(st.R, st.p, st.v, st.ba, st.bg, st.cp, st.cR, _f64(dx))



State = _State  # the initial states of n filters (avio.filter.batch)


@numba.njit(cache=True, error_model="numpy")
def _triplet_residuals(uv_px, R12, t12, R13, t13, fx, fy, cx, cy, r, J, G):
    """:func:`feature_residuals` of every feature for each of the n relative poses, into r, J, G."""
    for i in range(R12.shape[0]):
        R23 = np.empty((3, 3))
        for a in range(3):
            for b in range(3):
                R23[a, b] = R12[i, 0, a] * R13[i, 0, b] + R12[i, 1, a] * R13[i, 1, b] + R12[i, 2, a] * R13[i, 2, b]
        d = t13[i] - t12[i]
        t23 = rot_t(R12[i], (d[0], d[1], d[2]))
        a12 = (t12[i, 0], t12[i, 1], t12[i, 2])
        a13 = (t13[i, 0], t13[i, 1], t13[i, 2])
        for f in range(uv_px.shape[0]):
            feature_residuals(uv_px[f], R12[i], a12, R13[i], a13, R23, t23, fx[i], fy[i], cx[i], cy[i],
                              r[i, f], J[i, f], G[i, f])


def triplet_residuals(uv_px, R12, t12, R13, t13, fx, fy, cx, cy, with_pixel_jacobian: bool = False):
    """Innovations (n, F, 4) pixels and Jacobians (n, F, 4, 12) of F features (uv_px (F, 3, 2),
    shared by the batch) for n filters' relative poses R12, R13 (n, 3, 3), t12, t13 (n, 3) and
    intrinsics (n,); :func:`feature_residuals` per feature (what the filter's update runs).
    ``with_pixel_jacobian`` also returns G (n, F, 4, 6), d residuals / d pixels."""
    if uv_px.ndim != 3 or uv_px.shape[1:] != (3, 2):
        raise MeasurementError(f"triplet_residuals: uv_px must be (F, 3, 2) pixels, got {uv_px.shape}")
    n, F = R12.shape[0], uv_px.shape[0]
    r = np.empty((n, F, 4))
    J = np.empty((n, F, 4, 12))
    G = np.empty((n, F, 4, 6))
    _triplet_residuals(_f64(uv_px), _f64(R12), _f64(t12), _f64(R13), _f64(t13), _f64(fx), _f64(fy), _f64(cx),
                       _f64(cy), r, J, G)
    return (r, J, G) if with_pixel_jacobian else (r, J)


def relative_poses(Rc, pc):
    """Camera poses of the triplet -> ``(R12, t12, R13, t13)``.

    Rc (3, n, 3, 3) ``R_world_cam`` and pc (3, n, 3) ``p_world_cam`` of images 1, 2, 3.
    """
    R1t = np.swapaxes(Rc[0], 1, 2)
    R12, R13 = R1t @ Rc[1], R1t @ Rc[2]
    t12 = (R1t @ (pc[1] - pc[0])[..., None])[..., 0]
    t13 = (R1t @ (pc[2] - pc[0])[..., None])[..., 0]
    return R12, t12, R13, t13
