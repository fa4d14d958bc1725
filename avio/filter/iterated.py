"""The iterated trifocal update (compiled): the update's correction re-linearised at the corrected
state, Gauss–Newton on the update's maximum a posteriori (docs/model.md, Eq. 43a), for
``FilterConfig.update_iterations > 1``.

The first pass (avio/filter/update.py) linearises at the predicted state, scores the innovations
(NIS, log det S, the NLL: the prior-predictive likelihood, unchanged by the iterations), takes the
outlier decisions and the correction ``dx_1``. Each further pass re-measures the residuals r_i and
Jacobians (J_i, C_i) at ``x_i = x_pred (+) dx_i`` with the first pass's noise model and inliers, and
takes ``dx_{i+1} = P C_i^T (I + A_i Sigma_i)^-1 (beta_i + A_i C_i dx_i)`` (Eq. 43a: the Kalman
update of ``r_i + H_i dx_i``, H_i = J_i C_i, with the predicted P); the covariance update (Eq. 42)
and the injection (Eq. 8) then use the last linearisation. A pass whose residuals are not finite
(a wild candidate calibration) ends the iterations with the first pass's correction. Called by
:func:`avio.filter.kernels.run_filters` after :func:`avio.filter.update.update`, which leaves the
correction to it.
"""

from __future__ import annotations

import numpy as np

from avio.filter._linalg import matmul, solve
from avio.filter._simd import kernel_jit
from avio.filter.measurement import measure
from avio.filter.outliers import forward_lanes
from avio.filter.update import USED_RESIDUALS, M, apply_correction, inject


@kernel_jit
def _copy_nominal(x, nominal, save):
    """The nominal state of FilterState x into nominal (45,) (save) or back from it: R, p, v, b_a,
    b_g, the clones' positions and rotations."""
    k = 0
    for arr in (x.p, x.v, x.ba, x.bg, x.cp0, x.cp1):
        for a in range(3):
            if save:
                nominal[k] = arr[a]
            else:
                arr[a] = nominal[k]
            k += 1
    for R in (x.R, x.cR0, x.cR1):
        for a in range(3):
            for b in range(3):
                if save:
                    nominal[k] = R[a, b]
                else:
                    R[a, b] = nominal[k]
                k += 1


@kernel_jit
def relinearised_update(x, omega, cal, i, uv, n_iter, ws):
    """Passes 2..n_iter of filter i's update at this frame (module docstring), then the covariance
    update and the injection; x (FilterState) holds the predicted state, ws (UpdateWorkspaces) the
    first pass of :func:`avio.filter.update.update` (its inliers, noise model and correction)."""
    F, d = uv.shape[0], 12
    u_, n_ = ws.update, ws.noise
    r4, J4, C, PCt, CP, Sig, t12, t13 = u_.r4, u_.J4, u_.C, u_.PCt, u_.CP, u_.Sig_i, u_.t12, u_.t13
    A, Mx, X, dx, dlin, nominal, inl = u_.A, u_.Mx, u_.X, u_.dx, u_.dlin, u_.nominal, u_.inl
    G4, r, J, Lm, rw, Jw = n_.G4, n_.r, n_.J, n_.Lm, n_.rw, n_.Jw
    P = x.P
    _copy_nominal(x, nominal, True)
    fallback = False
    for _ in range(1, n_iter):
        # The linearisation point: the predicted state corrected by the last pass (fallback: itself).
        for a in range(27):
            dlin[a] = 0.0 if fallback else dx[a]
        inject(x.R, x.p, x.v, x.ba, x.bg, x.cp0, x.cR0, x.cp1, x.cR1, dlin, u_.E3, u_.T3)
        measure(x.R, x.p, x.v, x.cp0, x.cR0, x.cp1, x.cR1, omega, cal.td_s[i], cal.fx[i], cal.fy[i], cal.cx[i],
                cal.cy[i], cal.R_cam_imu[i], cal.p_imu_cam_m[i], uv, r4, J4, G4, C, t12, t13, ws.measure, False)
        _copy_nominal(x, nominal, False)
        finite = True
        for a in range(M):
            for f in range(F):
                if inl[f]:
                    r[a, f] = r4[USED_RESIDUALS[a], f]
                    finite &= np.isfinite(r[a, f])
                    for b in range(d):
                        J[a, b, f] = J4[USED_RESIDUALS[a], b, f]
                        finite &= np.isfinite(J[a, b, f])
        if not finite:
            if fallback:
                break
            fallback = True
            continue
        # Whitened with the first pass's R_f (Eq. 40), summed over its inliers.
        forward_lanes(Lm, r, rw)
        for a in range(M):
            for b in range(d):
                for f in range(F):
                    acc = J[a, b, f]
                    for k in range(a):
                        acc -= Lm[a, k, f] * Jw[k, b, f]
                    Jw[a, b, f] = acc / Lm[a, a, f]
        A[:] = 0.0
        X[:] = 0.0
        for f in range(F):
            if inl[f]:
                for a in range(M):
                    for b in range(d):
                        X[b, d] += Jw[a, b, f] * rw[a, f]
                        for c in range(b, d):
                            A[b, c] += Jw[a, b, f] * Jw[a, c, f]
        for b in range(d):
            for c in range(b):
                A[b, c] = A[c, b]
        # Eq. (43a): beta_i + A_i C_i dx_i, Sigma_i = C_i P C_i^T, then Eq. (41).
        matmul(C, P, CP)
        for a in range(27):
            for b in range(d):
                PCt[a, b] = CP[b, a]
        matmul(C, PCt, Sig)
        for b in range(d):
            acc = 0.0
            for a in range(27):
                acc += C[b, a] * dlin[a]
            for c in range(d):
                X[c, d] += A[c, b] * acc
        matmul(A, Sig, Mx)
        for a in range(d):
            Mx[a, a] += 1.0
            for b in range(d):
                X[a, b] = A[a, b]
        solve(Mx, X)
        for a in range(27):
            acc = 0.0
            for b in range(d):
                acc += PCt[a, b] * X[b, d]
            dx[a] = acc
        if fallback:
            break
    apply_correction(x, ws.update)
