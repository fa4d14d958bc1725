"""Per-filter outlier rejection of the trifocal measurements (PAPER.md §2, "Outliers").

Both tests work on the whitened, linearised measurement of each feature (4 residuals:
two Sampson distances and the 2-D transfer error, pixels) and decide per filter:

- :func:`mahalanobis_gate`: chi-square gate of ``r_j^T S_j^-1 r_j`` with
  ``S_j = H_j P H_j^T + R_j`` (4 degrees of freedom; ``R_j`` the feature's own 4x4 measurement
  covariance, avio.measurement.feature_residuals);
- :func:`one_point_ransac`: the paper's 1-point RANSAC (Civera et al. 2010) with the filter's
  prediction: every feature in turn is a hypothesis (so no random draw, and a batch gives the
  same answer as single runs); the state is corrected with that feature alone (one Kalman
  step, linearised), the other features' residuals are predicted after the correction, and a
  feature is an inlier when each of its residuals is within ``threshold_sigma`` of its own
  measurement standard deviations ``sd_j = sqrt(diag R_j)``. The hypothesis with most inliers wins (ties: the first).

Compiled with numba (``cache=True``, no fastmath): the filter's update kernel
(avio/_kernels.py) calls these once per filter and frame. Shapes (one filter): r (F, 4),
H (F, 4, d), P (d, d) the covariance of the d parameters H differentiates against,
Rm (F, 4, 4) the measurement covariances, valid (F,) bool.
"""

from __future__ import annotations

import numba
import numpy as np


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
