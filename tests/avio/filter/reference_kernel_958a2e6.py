"""THE REFERENCE: avio/_kernels.py as of commit 958a2e6 (the serial kernel, one filter after the
other), kept verbatim below this paragraph so tests/avio/filter/test_batch.py can check that the
threaded kernel gives the same bits. Do not edit; it is not used by the package. (Only change since:
the outlier functions it imported from avio/outliers.py are frozen copies below the imports.)

Compiled kernels of the batched VIO filter (avio/filter.py): the whole run of n filters
(:func:`run_filters`) and its per-filter steps: prediction of the covariance, the trifocal
update (measurement chain, outlier rejection, Kalman update, injection), the zero-velocity
update, the window slide and the divergence test.

Why compiled: per frame and filter the work is ~16 features x 4 residuals with 12-column
Jacobians, 16 hypotheses of 1-point RANSAC and a few 12x12 and 27x27 products: small work
that numpy spread over ~200 calls per frame, whose overhead cost more than the arithmetic.
numba with ``cache=True`` (compiled once, then loaded from avio/__pycache__; NB numba's cache
does not notice edits to functions of other modules called from a cached one: after editing
avio/measurement.py, avio/outliers.py, avio/_linalg.py or avio/imu_propagation.py, delete
avio/__pycache__/*.nbi and *.nbc), ``error_model="numpy"`` (a division by zero gives inf/NaN as
numpy did; such features are dropped) and no fastmath, so every run gives the same bits. Each
filter runs alone (a loop over the batch inside the kernel), so a batch gives the same numbers
as single runs.

Error state (27): ``[dp, dtheta, dv, db_a, db_g, dp1, dtheta1, dp2, dtheta2]`` (filter.py).
One filter: R (3, 3) ``R_world_imu``; p, v, ba, bg (3,); clones cp0, cp1 (3,), cR0, cR1 (3, 3)
(frames k-2, k-1); covariance P (27, 27); calibration fx, fy, cx, cy, td scalars, Rci
``R_cam_imu`` (3, 3), pic ``p_imu_cam_m`` (3,). ``*_all`` wrappers take the same with a
leading n axis (clones (2, n, ...)).
"""

from __future__ import annotations

import numba
import numpy as np

from avio.filter._linalg import matmul, so3_exp, solve
from avio.filter.measurement import feature_residuals, rot_t
from avio.filter.propagation import propagate_one, propagate_workspace

MODE_NONE, MODE_RANSAC, MODE_GATE, MODE_BOTH = 0, 1, 2, 3

# Frozen copies of avio/outliers.py's functions as this kernel called them (features first:
# r (F, m), H (F, m, d)), before the package moved them to the features-last layout (issue 13).

@numba.njit(cache=True, error_model="numpy")
def _cholesky(S, L):
    """Lower Cholesky factor L of the SPD matrix S (only its lower triangle is read); a pivot
    below 1e-300 is clamped, so a zero row gives zeros rather than NaN."""
    m = S.shape[0]
    for j in range(m):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        L[j, j] = np.sqrt(max(s, 1e-300))
        inv = 1.0 / L[j, j]
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s * inv
        for i in range(j):
            L[i, j] = 0.0


@numba.njit(cache=True, error_model="numpy")
def innovations_workspace(m, d):
    """Scratch arrays of :func:`feature_innovations_into` (m residuals per feature, d parameters):
    Lp (d, d), S (m, m), L (m, m), y (m,); allocated once per run, not per call."""
    return np.empty((d, d)), np.empty((m, m)), np.empty((m, m)), np.empty(m)


@numba.njit(cache=True, error_model="numpy")
def feature_innovations(r, H, P, Rm, B, z, logdet):
    """Per-feature ``B_j = H_j L`` (F, 4, d) with ``P = L L^T`` (so ``H_j P H_k^T = B_j B_k^T``),
    ``z_j = S_j^-1 r_j`` (F, 4) with ``S_j = H_j P H_j^T + R_j = B_j B_j^T + R_j`` and
    ``logdet_j = log det S_j`` (F,), written into B, z and logdet; shared by both tests. Through
    L the products cost half of ``H_j P`` (L is triangular). Allocates its scratch; the filter
    calls :func:`feature_innovations_into` with a workspace.
    """
    F, m, d = H.shape
    Lp, S, L, y = innovations_workspace(m, d)
    feature_innovations_into(r, H, P, Rm, B, z, logdet, Lp, S, L, y)


@numba.njit(cache=True, error_model="numpy")
def feature_innovations_into(r, H, P, Rm, B, z, logdet, Lp, S, L, y):
    """:func:`feature_innovations` with its scratch passed in (:func:`innovations_workspace`)."""
    F, m, d = H.shape
    _cholesky(P, Lp)
    for f in range(F):
        for a in range(m):
            for c in range(d):
                B[f, a, c] = 0.0
            for b in range(d):
                h = H[f, a, b]
                if h != 0.0:
                    for c in range(b + 1):
                        B[f, a, c] += h * Lp[b, c]
        for a in range(m):
            for b in range(a + 1):
                acc = 0.0
                for c in range(d):
                    acc += B[f, a, c] * B[f, b, c]
                S[a, b] = acc + Rm[f, a, b]
        _cholesky(S, L)
        ld = 0.0
        for i in range(m):
            ld += np.log(L[i, i])
        logdet[f] = 2.0 * ld
        for i in range(m):
            s = r[f, i]
            for k in range(i):
                s -= L[i, k] * y[k]
            y[i] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = y[i]
            for k in range(i + 1, m):
                s -= L[k, i] * z[f, k]
            z[f, i] = s / L[i, i]


@numba.njit(cache=True, error_model="numpy")
def mahalanobis_gate(r, z, valid, chi2_threshold, out):
    """out (F,) True where the feature passes ``r^T S^-1 r <= chi2_threshold`` (and is valid);
    z from :func:`feature_innovations`."""
    for f in range(r.shape[0]):
        d2 = 0.0
        for a in range(r.shape[1]):
            d2 += r[f, a] * z[f, a]
        out[f] = valid[f] and d2 <= chi2_threshold


@numba.njit(cache=True, error_model="numpy")
def ransac_workspace(F, m, d):
    """Scratch arrays of :func:`one_point_ransac_into` for F features of m residuals and d
    parameters: Y (d, F), moved (F m, F), inlier (F, F) bool, count (F,) int64."""
    return np.empty((d, F)), np.empty((F * m, F)), np.empty((F, F), np.bool_), np.empty(F, np.int64)


@numba.njit(cache=True, error_model="numpy")
def one_point_ransac(r, B, z, sd, valid, threshold_sigma, out):
    """out (F,): low-innovation inliers of the best 1-point hypothesis (module docstring);
    B, z from :func:`feature_innovations`; sd (F, 4) the residuals' measurement standard deviations.
    Allocates its scratch; the filter calls :func:`one_point_ransac_into` with a workspace."""
    F, m, d = B.shape
    Y, moved, inlier, count = ransac_workspace(F, m, d)
    one_point_ransac_into(r, B, z, sd, valid, threshold_sigma, out, Y, moved, inlier, count)


@numba.njit(cache=True, error_model="numpy")
def one_point_ransac_into(r, B, z, sd, valid, threshold_sigma, out, Y, moved, inlier, count):
    """:func:`one_point_ransac` with its scratch passed in (:func:`ransac_workspace`)."""
    F, m, d = B.shape
    # Correction of hypothesis h alone: dx_h = P H_h^T S_h^-1 r_h = L y_h with y_h = B_h^T z_h
    # (columns of Y, (d, F)); every feature's residual then moves by
    # H_j dx_h = B_j y_h: moved = B Y, ((j, a), h).
    Y[:] = 0.0
    for h in range(F):
        for a in range(m):
            zh = z[h, a]
            for c in range(d):
                Y[c, h] += zh * B[h, a, c]
    moved[:] = 0.0
    for j in range(F):
        for a in range(m):
            row = moved[j * m + a]
            for c in range(d):
                bc = B[j, a, c]
                if bc != 0.0:
                    for h in range(F):
                        row[h] += bc * Y[c, h]
    # inlier[j, h]: every residual of feature j within the threshold after hypothesis h (loops
    # run along h, contiguous, without early exits, so they vectorise).
    for j in range(F):
        for h in range(F):
            inlier[j, h] = valid[j]
        for a in range(m):
            thr = threshold_sigma * sd[j, a]
            rja = r[j, a]
            row = moved[j * m + a]
            for h in range(F):
                inlier[j, h] &= abs(rja - row[h]) <= thr
    count[:] = 0
    for j in range(F):
        for h in range(F):
            count[h] += inlier[j, h]
    best, best_count = 0, -2
    for h in range(F):
        c = count[h] if valid[h] else -1
        if c > best_count:  # ties: the first
            best, best_count = h, c
    for j in range(F):
        out[j] = inlier[j, best]


@numba.njit(cache=True, error_model="numpy")
def shifted_pose(R, p, v, omega, td, R3, p3, J, E):
    """Exposure-time IMU pose of one filter, ``(p + v td, R exp(w td))``, into p3 (3,), R3 (3, 3),
    and its (6, 15) Jacobian J w.r.t. the core error ``[dp, dtheta, dv, db_a, db_g]``
    (E (3, 3): scratch)."""
    so3_exp(omega[0] * td, omega[1] * td, omega[2] * td, E)
    matmul(R, E, R3)
    J[:] = 0.0
    for i in range(3):
        p3[i] = p[i] + v[i] * td
        J[i, i] = 1.0
        J[i, 6 + i] = td
        J[3 + i, 12 + i] = -td
        for j in range(3):
            J[3 + i, 3 + j] = E[j, i]


@numba.njit(cache=True, error_model="numpy")
def measure_workspace():
    """Scratch arrays of :func:`measure` (allocated once per batch, not per filter)."""
    return (np.empty((3, 3)), np.empty(3), np.empty((6, 15)), np.empty((3, 3, 3)), np.empty((3, 3)),
            np.zeros((18, 27)), np.empty((6, 6)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.zeros((12, 18)), np.empty((3, 3)))


@numba.njit(cache=True, error_model="numpy")
def measure(R, p, v, cp0, cR0, cp1, cR1, omega, td, fx, fy, cx, cy, Rci, pic, uv, r, J, Gp, C, t12, t13, ws):
    """Innovations r (F, 4) pixels, their Jacobians J (F, 4, 12) w.r.t. the relative-pose errors
    ``[psi12, dt12, psi13, dt13]``, their pixel sensitivities Gp (F, 4, 6) (the measurement
    noise model, avio.measurement.feature_residuals) and the map C (12, 27) from the error
    state to those (so ``H = J C``, ``dr = -H dx``) of one filter, written into the arrays;
    also t12, t13 (3,).

    Chain: state error -> exposure-time IMU poses of images 1, 2, 3 (clones, shifted current
    pose) -> camera pose errors ``[dp_cam, phi]`` (``phi = R_cam_imu dtheta``,
    ``dp_cam = dp - R_world_imu [p_imu_cam]x dtheta``) -> relative-pose errors
    (``psi1j = phi_j - R1j^T phi_1``, ``dt1j = [t1j]x phi_1 + R_world_cam1^T (dp_cam_j - dp_cam_1)``)
    -> residuals (avio.measurement.feature_residuals).
    """
    R3, p3, Jsh, Rc, pc, G, M, R12, R13, R23, D, E = ws
    shifted_pose(R, p, v, omega, td, R3, p3, Jsh, E)
    # G (18, 27): camera pose errors of images 1, 2, 3 <- state error; D (12, 18): camera pose
    # errors -> relative-pose errors. Both keep their zero pattern between calls (the
    # workspace starts at zero), only the blocks below are rewritten.
    for a in range(3):
        Ri = cR0 if a == 0 else (cR1 if a == 1 else R3)
        pi = cp0 if a == 0 else (cp1 if a == 1 else p3)
        for i in range(3):
            for j in range(3):
                Rc[a, i, j] = Ri[i, 0] * Rci[j, 0] + Ri[i, 1] * Rci[j, 1] + Ri[i, 2] * Rci[j, 2]
            pc[a, i] = pi[i] + Ri[i, 0] * pic[0] + Ri[i, 1] * pic[1] + Ri[i, 2] * pic[2]
        # M = [[I, -R_imu [pic]x], [0, R_cam_imu]]
        M[:] = 0.0
        for i in range(3):
            M[i, i] = 1.0
            col = (Ri[i, 1] * pic[2] - Ri[i, 2] * pic[1], Ri[i, 2] * pic[0] - Ri[i, 0] * pic[2],
                   Ri[i, 0] * pic[1] - Ri[i, 1] * pic[0])  # row i of R_imu [pic]x
            for j in range(3):
                M[i, 3 + j] = -col[j]
                M[3 + i, 3 + j] = Rci[i, j]
        if a == 2:
            matmul(M, Jsh, G[12:18, 0:15])
        else:
            G[6 * a:6 * a + 6, 15 + 6 * a:21 + 6 * a] = M
    for i in range(3):
        for j in range(3):
            R12[i, j] = Rc[0, 0, i] * Rc[1, 0, j] + Rc[0, 1, i] * Rc[1, 1, j] + Rc[0, 2, i] * Rc[1, 2, j]
            R13[i, j] = Rc[0, 0, i] * Rc[2, 0, j] + Rc[0, 1, i] * Rc[2, 1, j] + Rc[0, 2, i] * Rc[2, 2, j]
    for i in range(3):
        for j in range(3):
            R23[i, j] = R12[0, i] * R13[0, j] + R12[1, i] * R13[1, j] + R12[2, i] * R13[2, j]
    R1 = Rc[0]
    a12 = rot_t(R1, (pc[1, 0] - pc[0, 0], pc[1, 1] - pc[0, 1], pc[1, 2] - pc[0, 2]))
    a13 = rot_t(R1, (pc[2, 0] - pc[0, 0], pc[2, 1] - pc[0, 1], pc[2, 2] - pc[0, 2]))
    a23 = rot_t(R12, (a13[0] - a12[0], a13[1] - a12[1], a13[2] - a12[2]))
    for i in range(3):
        t12[i], t13[i] = a12[i], a13[i]
    for f in range(uv.shape[0]):
        feature_residuals(uv[f], R12, a12, R13, a13, R23, a23, fx, fy, cx, cy, r[f], J[f], Gp[f])
    for jj in range(2):
        row, Rj, t = 6 * jj, (R12 if jj == 0 else R13), (a12 if jj == 0 else a13)
        col = 6 * (jj + 1)
        for i in range(3):
            D[row + i, col + 3 + i] = 1.0
            for k in range(3):
                D[row + i, 3 + k] = -Rj[k, i]  # -R1j^T
                D[row + 3 + i, col + k] = R1[k, i]  # R_world_cam1^T
                D[row + 3 + i, k] = -R1[k, i]
        D[row + 3, 4], D[row + 3, 5] = -t[2], t[1]  # [t1j]x
        D[row + 4, 3], D[row + 4, 5] = t[2], -t[0]
        D[row + 5, 3], D[row + 5, 4] = -t[1], t[0]
    # C = D G, each row of G only over its block's columns (images 1, 2: clones; 3: core).
    for i in range(12):
        for j in range(27):
            C[i, j] = 0.0
        for k in range(18):
            f = D[i, k]
            if f != 0.0:
                lo, hi = (15, 21) if k < 6 else ((21, 27) if k < 12 else (0, 15))
                for j in range(lo, hi):
                    C[i, j] += f * G[k, j]


@numba.njit(cache=True, error_model="numpy")
def measure_all(R, p, v, cp, cR, omega, td, fx, fy, cx, cy, Rci, pic, uv):
    """:func:`measure` of the n filters for the features uv (F, 3, 2) shared by the batch:
    (r (n, F, 4), J (n, F, 4, 12), C (n, 12, 27), t12 (n, 3), t13 (n, 3))."""
    n, F = R.shape[0], uv.shape[0]
    r, J, C = np.empty((n, F, 4)), np.empty((n, F, 4, 12)), np.empty((n, 12, 27))
    Gp = np.empty((F, 4, 6))
    t12, t13 = np.empty((n, 3)), np.empty((n, 3))
    ws = measure_workspace()
    for i in range(n):
        measure(R[i], p[i], v[i], cp[0, i], cR[0, i], cp[1, i], cR[1, i], omega[i], td[i], fx[i], fy[i],
                cx[i], cy[i], Rci[i], pic[i], uv, r[i], J[i], Gp, C[i], t12[i], t13[i], ws)
    return r, J, C, t12, t13


@numba.njit(cache=True, error_model="numpy")
def _rotate(Rm, dtheta, E, T):
    so3_exp(dtheta[0], dtheta[1], dtheta[2], E)
    matmul(Rm, E, T)
    Rm[:] = T


@numba.njit(cache=True, error_model="numpy")
def inject(R, p, v, ba, bg, cp0, cR0, cp1, cR1, dx, E, T):
    """Add the error-state correction dx (27,) to one filter's nominal state (local rotation
    errors, ``R <- R exp(dtheta)``), in place (E, T (3, 3): scratch)."""
    for i in range(3):
        p[i] += dx[i]
        v[i] += dx[6 + i]
        ba[i] += dx[9 + i]
        bg[i] += dx[12 + i]
        cp0[i] += dx[15 + i]
        cp1[i] += dx[21 + i]
    _rotate(R, dx[3:6], E, T)
    _rotate(cR0, dx[18:21], E, T)
    _rotate(cR1, dx[24:27], E, T)


@numba.njit(cache=True, error_model="numpy")
def inject_all(R, p, v, ba, bg, cp, cR, dx):
    """:func:`inject` of the n filters, dx (n, 27)."""
    E, T = np.empty((3, 3)), np.empty((3, 3))
    for i in range(R.shape[0]):
        inject(R[i], p[i], v[i], ba[i], bg[i], cp[0, i], cR[0, i], cp[1, i], cR[1, i], dx[i], E, T)


@numba.njit(cache=True, error_model="numpy")
def update_workspace(F):
    """Scratch arrays of :func:`update` for F features (allocated once per run)."""
    d = 12
    return (np.empty((F, 4)), np.empty((F, 4, d)), np.empty((d, 27)), np.empty((27, d)), np.empty((d, d)),
            np.empty(3), np.empty(3), np.empty((F, M, d)), np.empty((F, M)), np.empty(F, np.bool_),
            np.empty(F, np.bool_), np.empty(F, np.bool_), np.empty((d, d)), np.empty((d, d)), np.empty((d, d + 1)),
            np.empty((27, d)), np.empty(27), np.empty((d, 27)), np.empty((3, 3)), np.empty((3, 3)), np.empty(d))


@numba.njit(cache=True, error_model="numpy")
def noise_workspace(F):
    """Scratch arrays of the measurement-noise model of :func:`update` for F features: the
    pixel sensitivities of the 4 residuals (F, 4, 6); the M used residuals, their Jacobians
    and pixel sensitivities (F, M), (F, M, 12), (F, M, 6); covariances R_f and their Cholesky
    factors (F, M, M), standard deviations (F, M), log det R_f and log det S_f (F,), and an (M,)
    and a (12,) vector."""
    return (np.empty((F, 4, 6)), np.empty((F, M)), np.empty((F, M, 12)), np.empty((F, M, 6)),
            np.empty((F, M, M)), np.empty((F, M)), np.zeros((F, M, M)), np.empty(F), np.empty(F), np.empty(M),
            np.empty(12))


LOG_2PI = np.log(2.0 * np.pi)
#: The residuals the update uses, of the 4 of avio.measurement: the 1-2 Sampson distance and the
#: two transfer coordinates. A point seen in three images gives 3 independent constraints (6
#: measured coordinates minus its 3 coordinates): to first order the 2-3 Sampson distance is
#: a combination of the other three, so the 4x4 covariance from the pixel noise is singular
#: (smallest eigenvalue ~1e-4 sigma^2 against ~0.6 sigma^2 for these three on the default drive)
#: and whitening all four would turn linearisation error into near-certain information.
USED_RESIDUALS = (0, 2, 3)
M = 3
#: R_f gets (NOISE_FLOOR * sigma)^2 on its diagonal: keeps it positive definite when a
#: geometry makes two residuals react to the pixels in the same way (it changes no decision).
NOISE_FLOOR = 0.01


@numba.njit(cache=True, error_model="numpy")
def _noise_model(Gp, sigma_px, Rm, sd, Lm, ldR, f):
    """R_f = sigma^2 G G^T + (NOISE_FLOOR sigma)^2 I of feature f (G (F, M, 6) the used
    residuals' pixel sensitivities), its Cholesky factor, the standard deviations and
    log det R_f, into the workspace arrays."""
    s2 = sigma_px * sigma_px
    for a in range(M):
        for b in range(a + 1):
            acc = 0.0
            for c in range(6):
                acc += Gp[f, a, c] * Gp[f, b, c]
            Rm[f, a, b] = s2 * acc
            Rm[f, b, a] = s2 * acc
        Rm[f, a, a] += s2 * NOISE_FLOOR * NOISE_FLOOR
        sd[f, a] = np.sqrt(Rm[f, a, a])
    _cholesky(Rm[f], Lm[f])
    ld = 0.0
    for a in range(M):
        ld += np.log(Lm[f, a, a])
    ldR[f] = 2.0 * ld


@numba.njit(cache=True, error_model="numpy")
def update(R, p, v, ba, bg, cp0, cR0, cp1, cR1, Pi, omega, td, fx, fy, cx, cy, Rci, pic, uv, valid, sigma_px,
           max_transfer_gain, min_parallax_m, mode, ransac_threshold_sigma, chi2_threshold, ws, mws, nws):
    """One trifocal update of one filter (state and covariance Pi (27, 27) in place).

    Residuals and Jacobians of the F features uv (F, 3, 2) (invalid, non-finite, without
    baseline or with a degenerate transfer: not used), each feature's measurement covariance
    ``R_f = sigma_px^2 G G^T`` from the pixel noise (avio.measurement.feature_residuals), outlier
    rejection (``mode``: MODE_* of this module) on the linearised measurement, then the Kalman
    update. A transfer is degenerate when it amplifies the pixel noise more than
    ``max_transfer_gain`` times (the line through m2 nearly through the epipole: tiny changes of
    m1, m2 move the transferred point by hundreds of pixels, whatever the residual).
    The measurement depends on the state only through the 12 relative-pose errors ``C dx``, so
    gates and update work with ``Sigma = C P C^T`` (12x12) and J: ``P+ = P - P C^T (I + A
    Sigma)^-1 A C P``, ``dx = P C^T (I + A Sigma)^-1 J^T R^-1 r`` with ``A = J^T R^-1 J`` — the
    information form ``(P^-1 + H^T R^-1 H)^-1`` with ``H = J C``, at the price of a 12x12 solve.
    The same factors give the innovation likelihood of the update (avio/objectives.py):
    ``NIS = r^T S^-1 r = r^T R^-1 r - beta^T Sigma (I + A Sigma)^-1 beta`` (Woodbury, ``beta =
    J^T R^-1 r``) and ``log det S = log det R + log det(I + A Sigma)``.
    Returns (used, rejected, nis, log_det_S, dof, nll, slots): the numbers of features used and
    rejected, the update's NIS, log det S and residual count, its NLL contribution with the
    capped terms of the valid features it did not use, and the residual slots (4 per valid
    feature). ws: :func:`update_workspace`, mws: :func:`measure_workspace`, nws:
    :func:`noise_workspace`.
    """
    F, d = uv.shape[0], 12
    r4, J4, C, PCt, Sig, t12, t13, HP, z, ok, inl, gate, A, Mx, X, K, dx, CP, E3, T3, jw = ws
    G4, r, J, Gp, Rm, sd, Lm, ldR, ldS, rw, beta = nws
    measure(R, p, v, cp0, cR0, cp1, cR1, omega, td, fx, fy, cx, cy, Rci, pic, uv, r4, J4, G4, C, t12, t13, mws)
    # Without baseline the epipolar geometry and the transfer are undefined (standing still).
    b12 = np.sqrt(t12[0] ** 2 + t12[1] ** 2 + t12[2] ** 2)
    b23 = np.sqrt((t13[0] - t12[0]) ** 2 + (t13[1] - t12[1]) ** 2 + (t13[2] - t12[2]) ** 2)
    moving = b12 > min_parallax_m and b23 > min_parallax_m
    n_ok = 0
    n_valid = 0
    gain_limit2 = (max_transfer_gain * sigma_px) ** 2
    log_s2 = np.log(sigma_px * sigma_px)
    for f in range(F):
        n_valid += valid[f]
        for a in range(M):
            u = USED_RESIDUALS[a]
            r[f, a] = r4[f, u]
            for b in range(d):
                J[f, a, b] = J4[f, u, b]
            for b in range(6):
                Gp[f, a, b] = G4[f, u, b]
        # Degenerate geometry (a point at the epipole, a wild candidate) is non-finite.
        good = valid[f] and moving
        for a in range(M):
            good = good and np.isfinite(r[f, a])
            for b in range(d):
                good = good and np.isfinite(J[f, a, b])
            for b in range(6):
                good = good and np.isfinite(Gp[f, a, b])
        if good:
            _noise_model(Gp, sigma_px, Rm, sd, Lm, ldR, f)
            good = Rm[f, 1, 1] <= gain_limit2 and Rm[f, 2, 2] <= gain_limit2  # the transfer's rows
        ok[f] = good
        n_ok += good
        if not good:
            ldR[f] = M * log_s2
            for a in range(M):
                r[f, a] = 0.0
                sd[f, a] = sigma_px
                for b in range(d):
                    J[f, a, b] = 0.0
                for b in range(M):
                    Rm[f, a, b] = sigma_px * sigma_px if a == b else 0.0
    # CP = C P (C is ~60 % zeros, which matmul skips), PCt = its transpose (P is
    # symmetric), Sigma = C P C^T (symmetrised).
    matmul(C, Pi, CP)
    for a in range(27):
        for b in range(d):
            PCt[a, b] = CP[b, a]
    matmul(C, PCt, Sig)
    for a in range(d):
        for b in range(a):
            s = 0.5 * (Sig[a, b] + Sig[b, a])
            Sig[a, b], Sig[b, a] = s, s
    inl[:] = ok
    feature_innovations(r, J, Sig, Rm, HP, z, ldS)
    # The score (avio/objectives.py): every valid feature's own innovation likelihood, its
    # squared Mahalanobis distance capped at the gate, whatever the update does with it.
    nll = 0.0
    for f in range(F):
        if valid[f]:
            if ok[f]:
                d2 = 0.0
                for a in range(M):
                    d2 += r[f, a] * z[f, a]
                nll += 0.5 * (min(d2, chi2_threshold) + ldS[f] + M * LOG_2PI)
            else:
                nll += 0.5 * (chi2_threshold + M * log_s2 + M * LOG_2PI)
    if mode == MODE_RANSAC or mode == MODE_BOTH:
        one_point_ransac(r, HP, z, sd, ok, ransac_threshold_sigma, inl)
    if mode == MODE_GATE or mode == MODE_BOTH:
        mahalanobis_gate(r, z, inl, chi2_threshold, gate)
        inl[:] = gate
    # Information form over the inliers: A = Jw^T Jw, beta = Jw^T rw with the whitened
    # Jw = L_f^-1 J_f, rw = L_f^-1 r_f (R_f = L_f L_f^T).
    A[:] = 0.0
    X[:] = 0.0
    used = 0
    rr = 0.0
    log_det_R = 0.0
    for f in range(F):
        if not inl[f]:
            continue
        used += 1
        log_det_R += ldR[f]
        L = Lm[f]
        for a in range(M):  # forward substitution, one residual row at a time
            acc = r[f, a]
            for k in range(a):
                acc -= L[a, k] * rw[k]
            rw[a] = acc / L[a, a]
            rr += rw[a] * rw[a]
        for a in range(M):
            for b in range(d):
                acc = J[f, a, b]
                for k in range(a):
                    acc -= L[a, k] * HP[f, k, b]  # HP rows of earlier residuals hold Jw already
                jw[b] = acc / L[a, a]
            for b in range(d):
                HP[f, a, b] = jw[b]
            for b in range(d):
                jb = jw[b]
                if jb != 0.0:
                    X[b, d] += jb * rw[a]
                    for c in range(b, d):
                        A[b, c] += jb * jw[c]
    for b in range(d):
        beta[b] = X[b, d]
        for c in range(b):
            A[b, c] = A[c, b]
    # X = (I + A Sigma)^-1 [A | beta]
    matmul(A, Sig, Mx)
    for a in range(d):
        Mx[a, a] += 1.0
        for b in range(d):
            X[a, b] = A[a, b]
    solve(Mx, X)
    log_det_S = log_det_R
    for a in range(d):
        log_det_S += np.log(abs(Mx[a, a]))  # the pivots of the elimination: det(I + A Sigma) > 0
    nis = rr
    for a in range(d):
        acc = 0.0
        for b in range(d):
            acc += Sig[a, b] * X[b, d]
        nis -= beta[a] * acc
    dof = M * used
    for a in range(27):
        acc = 0.0
        for b in range(d):
            acc += PCt[a, b] * X[b, d]
        dx[a] = acc
    # P -= (PCt X[:, :12]) CP: the lower triangle, mirrored (P stays exactly symmetric).
    for a in range(27):
        for b in range(d):
            K[a, b] = 0.0
        for c in range(d):
            f = PCt[a, c]
            for b in range(d):
                K[a, b] += f * X[c, b]
    for a in range(27):
        for b in range(d):
            kab = K[a, b]
            for c in range(a + 1):
                Pi[a, c] -= kab * CP[b, c]
        for c in range(a):
            Pi[c, a] = Pi[a, c]
    inject(R, p, v, ba, bg, cp0, cR0, cp1, cR1, dx, E3, T3)
    return used, n_ok - used, nis, log_det_S, dof, nll, M * n_valid


@numba.njit(cache=True, error_model="numpy")
def propagate_covariance(Pi, Phi, Qd, T, U):
    """Covariance prediction of one filter, in place: ``P <- F P F^T + Q`` with
    ``F = blockdiag(Phi, I_12)`` (clones have no dynamics), Phi (15, 15) the core error
    transition of the interval, Qd (15, 15) its discrete process noise (T (15, 27), U (15, 15):
    scratch)."""
    # Written out (matmul on slices would use strided views); zeros of Phi are skipped.
    # T = Phi P[0:15, :] (rows of the new cross-covariances and of W = Phi P15), U = W^T.
    for a in range(15):
        for b in range(27):
            T[a, b] = 0.0
        for c in range(15):
            f = Phi[a, c]
            if f != 0.0:
                for b in range(27):
                    T[a, b] += f * Pi[c, b]
    for a in range(15):
        for b in range(15):
            U[a, b] = T[b, a]
    # P15 <- Phi W^T + Q = Phi P15 Phi^T + Q; cross blocks <- T[:, 15:27].
    for a in range(15):
        for b in range(15):
            Pi[a, b] = Qd[a, b]
        for c in range(15):
            f = Phi[a, c]
            if f != 0.0:
                for b in range(15):
                    Pi[a, b] += f * U[c, b]
        for b in range(15, 27):
            Pi[a, b] = T[a, b]
            Pi[b, a] = T[a, b]


@numba.njit(cache=True, error_model="numpy")
def slide(R, p, v, omega, td, cp, cR, Pi, R3, p3, J, E, NR):
    """Slide the window of one filter, in place: drop clone k-2 (cp (2, 3), cR (2, 3, 3)), move
    k-1 down, clone the current exposure-time pose (:func:`shifted_pose`); its covariance rows
    are ``J P[0:15]`` (R3, p3, J, E, NR (6, 27): scratch)."""
    shifted_pose(R, p, v, omega, td, R3, p3, J, E)
    cp[0] = cp[1]
    cR[0] = cR[1]
    cp[1] = p3
    cR[1] = R3
    for a in range(6):
        for b in range(27):
            NR[a, b] = 0.0
        for c in range(15):
            f = J[a, c]
            if f != 0.0:
                for b in range(27):
                    NR[a, b] += f * Pi[c, b]  # NR = J P[0:15, :]
    for a in range(6):
        for b in range(15, 21):
            NR[a, b] = NR[a, b + 6]
    # Clone k-1 (rows/columns 21:27) moves to 15:21; in place is safe because each entry is
    # read from the same or a later, not yet written position.
    for a in range(21):
        ma = a if a < 15 else a + 6
        for b in range(21):
            Pi[a, b] = Pi[ma, b if b < 15 else b + 6]
    for a in range(6):
        for b in range(21):
            Pi[21 + a, b] = NR[a, b]
            Pi[b, 21 + a] = NR[a, b]
        for b in range(6):
            acc = 0.0
            for c in range(15):
                acc += NR[a, c] * J[b, c]
            Pi[21 + a, 21 + b] = acc


@numba.njit(cache=True, error_model="numpy")
def zero_velocity_update(R, p, v, ba, bg, cp0, cR0, cp1, cR1, Pi, sigma_mps, E, T):
    """Pseudo-measurement v = 0 with noise sigma_mps (m/s) of one filter, in place: the
    Kalman update ``S = P_vv + sigma^2 I``, ``dx = -P_xv S^-1 v``, ``P -= P_xv S^-1 P_vx``
    (symmetrised), then the injection. A full update: the position error accumulated while
    braking is corrected through the position-velocity correlation (a "consider" update of
    the velocity and biases only was tried: 4.9 m instead of 1.4 m at the truth, seed 0)."""
    S, Z, dx = np.empty((3, 3)), np.empty((3, 28)), np.empty(27)
    for a in range(3):
        for b in range(3):
            S[a, b] = Pi[6 + a, 6 + b] + (sigma_mps * sigma_mps if a == b else 0.0)
        for b in range(27):
            Z[a, b] = Pi[6 + a, b]
        Z[a, 27] = -v[a]
    solve(S, Z)
    for a in range(27):
        dx[a] = Pi[a, 6] * Z[0, 27] + Pi[a, 7] * Z[1, 27] + Pi[a, 8] * Z[2, 27]
    K = np.empty((27, 27))
    for a in range(27):
        for b in range(27):
            K[a, b] = Pi[a, 6] * Z[0, b] + Pi[a, 7] * Z[1, b] + Pi[a, 8] * Z[2, b]
    for a in range(27):
        for b in range(a + 1):
            s = 0.5 * ((Pi[a, b] - K[a, b]) + (Pi[b, a] - K[b, a]))
            Pi[a, b], Pi[b, a] = s, s
    inject(R, p, v, ba, bg, cp0, cR0, cp1, cR1, dx, E, T)


@numba.njit(cache=True, error_model="numpy")
def _bad(R, p, v, Pi, max_variance, max_speed):
    """Divergence test of one filter (avio/filter.py): non-finite state or covariance, a
    covariance diagonal above max_variance, or a speed above max_speed."""
    nonfinite = False  # x - x is NaN exactly for inf and NaN; no early exit, so it vectorises
    for a in range(27):
        for b in range(27):
            nonfinite |= (Pi[a, b] - Pi[a, b]) != 0.0
    for a in range(3):
        nonfinite |= (p[a] - p[a]) != 0.0 or (v[a] - v[a]) != 0.0
        for b in range(3):
            nonfinite |= (R[a, b] - R[a, b]) != 0.0
    if nonfinite:
        return True
    for a in range(27):
        if Pi[a, a] > max_variance:
            return True
    return np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) > max_speed


@numba.njit(cache=True, error_model="numpy")
def run_filters(R0, p0, v0, P0, ba0, bg0, g, dR, dv, dp, S, SS, Vbg, Pbg, T_s, gyro_frame, Qd, triplet_of_frame, uv,
                valid, stationary, fx, fy, cx, cy, Rci, pic, td, frozen, sigma_px, max_transfer_gain, min_parallax_m,
                mode, ransac_threshold_sigma, chi2_threshold, zero_velocity_sigma_mps, max_variance, max_speed,
                out_p, out_R, out_v, out_sig, out_ba, out_bg, n_upd, n_out, div_at, out_nis, out_ldS, out_dof,
                out_nll, out_slots):
    """All frames of the n filters (avio/filter.py: run): each filter alone, one after the
    other (so a batch gives the same bits as single runs), its frames in order: prediction
    (:func:`avio.imu_propagation.propagate_one`, :func:`propagate_covariance`), the trifocal
    :func:`update` or, standing still, :func:`zero_velocity_update`, :func:`slide`, the
    divergence test. A diverged filter (or one with ``frozen`` set: a non-finite calibration)
    keeps the estimates of its last good frame, reports the initial sigmas and no updates
    from then on. Writes the out_* arrays (n, N, ...), n_upd, n_out (n, N), div_at (n,) and the
    innovation statistics of each frame's update (n, N): NIS, log det S, residual count, NLL
    contribution and residual slots (:func:`update`; zero where no trifocal update ran).
    The biases start at ba0, bg0 (3,), the prior means.
    """
    n, N, F = fx.shape[0], T_s.shape[0], uv.shape[1]
    ws, mws, pws, nws = update_workspace(F), measure_workspace(), propagate_workspace(), noise_workspace(F)
    R, p, v, ba, bg = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    cp, cR, P = np.empty((2, 3)), np.empty((2, 3, 3)), np.empty((27, 27))
    R_new, v_new, p_new, Phi = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty((15, 15))
    E, T3, Tq, U = np.empty((3, 3)), np.empty((3, 3)), np.empty((15, 27)), np.empty((15, 15))
    R3, p3, Jsh, NR = np.empty((3, 3)), np.empty(3), np.empty((6, 15)), np.empty((6, 27))
    ba_s, bg_s = np.empty(3), np.empty(3)
    sig0 = np.sqrt(np.abs(np.diag(P0)[:15]))
    for i in range(n):
        R[:] = R0
        p[:] = p0
        v[:] = v0
        P[:] = P0
        ba[:] = ba0
        bg[:] = bg0
        cp[:] = 0.0
        cR[:] = 0.0
        for a in range(3):
            cR[0, a, a] = 1.0
            cR[1, a, a] = 1.0
        n_upd[i, :] = 0
        n_out[i, :] = 0
        out_nis[i, :] = 0.0
        out_ldS[i, :] = 0.0
        out_dof[i, :] = 0
        out_nll[i, :] = 0.0
        out_slots[i, :] = 0
        div_at[i] = 0 if frozen[i] else -1
        k_stop = 0 if frozen[i] else N
        omega = np.empty(3)
        for k in range(k_stop):
            ba_s[:] = ba
            bg_s[:] = bg
            if k > 0:
                propagate_one(R, v, p, ba, bg, g, dR[k], dv[k], dp[k], S[k], SS[k], Vbg[k], Pbg[k], T_s[k],
                              R_new, v_new, p_new, Phi, pws)
                propagate_covariance(P, Phi, Qd[k], Tq, U)
            else:
                R_new[:] = R
                v_new[:] = v
                p_new[:] = p
            for a in range(3):
                omega[a] = gyro_frame[k, a] - bg[a]
            j = triplet_of_frame[k]
            if k >= 2 and stationary[k] and zero_velocity_sigma_mps > 0:
                zero_velocity_update(R_new, p_new, v_new, ba, bg, cp[0], cR[0], cp[1], cR[1], P,
                                     zero_velocity_sigma_mps, E, T3)
            elif k >= 2 and j >= 0:
                used, rej, nis, ldS, dof, nll, slots = update(
                    R_new, p_new, v_new, ba, bg, cp[0], cR[0], cp[1], cR[1], P, omega, td[i], fx[i], fy[i], cx[i],
                    cy[i], Rci[i], pic[i], uv[j], valid[j], sigma_px, max_transfer_gain, min_parallax_m, mode,
                    ransac_threshold_sigma, chi2_threshold, ws, mws, nws)
                n_upd[i, k], n_out[i, k] = used, rej
                out_nis[i, k], out_ldS[i, k], out_dof[i, k], out_nll[i, k], out_slots[i, k] = nis, ldS, dof, nll, slots
            slide(R_new, p_new, v_new, omega, td[i], cp, cR, P, R3, p3, Jsh, E, NR)
            if _bad(R_new, p_new, v_new, P, max_variance, max_speed):
                div_at[i] = k
                n_upd[i, k] = 0
                n_out[i, k] = 0
                out_nis[i, k] = 0.0
                out_ldS[i, k] = 0.0
                out_dof[i, k] = 0
                out_nll[i, k] = 0.0
                out_slots[i, k] = 0
                ba[:] = ba_s
                bg[:] = bg_s
                k_stop = k
                break
            R[:] = R_new
            p[:] = p_new
            v[:] = v_new
            out_p[i, k] = p
            out_R[i, k] = R
            out_v[i, k] = v
            out_ba[i, k] = ba
            out_bg[i, k] = bg
            for a in range(15):
                out_sig[i, k, a] = np.sqrt(abs(P[a, a]))
        # From the divergence on: the last good state (biases included), the initial sigmas.
        for k in range(k_stop, N):
            out_p[i, k] = p
            out_R[i, k] = R
            out_v[i, k] = v
            out_ba[i, k] = ba
            out_bg[i, k] = bg
            out_sig[i, k] = sig0
