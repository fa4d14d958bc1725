"""Batched wrappers of the kernel's per-filter steps, for tests only: the measurement chain and the
injection of n filters, checked against finite differences in test_measurement.py."""

from __future__ import annotations

import numba
import numpy as np

from avio.calibration import Calibration
from avio.filter.batch import _cal_arrays, _f64, _State
from avio.filter.measurement import measure, measure_workspace
from avio.filter.update import inject


@numba.njit(cache=True, error_model="numpy")
def measure_all(R, p, v, cp, cR, omega, td, fx, fy, cx, cy, Rci, pic, uv):
    """:func:`avio.filter.measurement.measure` of the n filters for the features uv (F, 3, 2) shared
    by the batch: (r (n, F, 4), J (n, F, 4, 12), C (n, 12, 27), t12 (n, 3), t13 (n, 3))."""
    n, F = R.shape[0], uv.shape[0]
    r, J, C = np.empty((n, F, 4)), np.empty((n, F, 4, 12)), np.empty((n, 12, 27))
    rT, JT, Gp = np.empty((4, F)), np.empty((4, 12, F)), np.empty((4, 6, F))
    t12, t13 = np.empty((n, 3)), np.empty((n, 3))
    ws = measure_workspace()
    for i in range(n):
        measure(R[i], p[i], v[i], cp[0, i], cR[0, i], cp[1, i], cR[1, i], omega[i], td[i], fx[i], fy[i],
                cx[i], cy[i], Rci[i], pic[i], uv, rT, JT, Gp, C[i], t12[i], t13[i], ws, True)
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
        return measure_all(st.R, st.p, st.v, st.cp, st.cR, _f64(omega), _f64(td), *_cal_arrays(cal), _f64(uv_px))


def inject_correction(st: _State, dx) -> None:
    """Add the error-state correction dx (n, 27) to the nominal states (local rotation errors)."""
    inject_all(st.R, st.p, st.v, st.ba, st.bg, st.cp, st.cR, _f64(dx))



State = _State  # the initial states of n filters (avio.filter.batch)
