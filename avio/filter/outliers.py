"""Per-filter outlier rejection of the trifocal measurements (docs/model.md, "Outlier rejection",
Eqs. 37-39).

Both tests work on the whitened, linearised measurement of each feature (m residuals;
the filter uses 3: the 1–2 Sampson distance and the 2-D transfer error, pixels) and decide per filter:

- :func:`mahalanobis_gate`: chi-square gate of ``r_j^T S_j^-1 r_j`` with
  ``S_j = H_j P H_j^T + R_j`` (m degrees of freedom; ``R_j`` the feature's own m x m measurement
  covariance, avio/filter/update.py: _noise_model; Eqs. 37, 39);
- :func:`one_point_ransac`: the paper's 1-point RANSAC (Civera et al. 2010) with the filter's
  prediction: every feature in turn is a hypothesis (so no random draw, and a batch gives the
  same answer as single runs); the state is corrected with that feature alone (one Kalman
  step, linearised), the other features' residuals are predicted after the correction, and a
  feature is an inlier when each of its residuals is within ``threshold_sigma`` of its own
  measurement standard deviations ``sd_j = sqrt(diag R_j)``. The hypothesis with most inliers
  wins (ties: the first). (Eq. 38.)

Compiled with numba (``cache=True``, no fastmath): the filter's update kernel
(avio/filter/update.py) calls these once per filter and frame. Layout "features last" (one filter,
m residuals per feature, F features): r (m, F), H (m, d, F), Rm (m, m, F) the measurement
covariances, P (d, d) the covariance of the d parameters H differentiates against, valid (F,)
bool. The feature axis is innermost so that each step runs over all F features at once in
contiguous memory, which the compiler turns into SIMD code (issue 13: twice as fast as one
feature after the other); every feature still sees the same operations in the same order, so
the bits are those of the feature-by-feature code it replaced (tests/avio/filter/test_batch.py).
"""

from __future__ import annotations

import numpy as np

from avio.filter._simd import kernel_jit


@kernel_jit
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


@kernel_jit
def cholesky_lanes(S, L):
    """:func:`_cholesky` of F matrices at once: S, L (m, m, F), the matrix of feature f in
    ``[:, :, f]`` (same operations per matrix; the upper triangle of L is not written)."""
    m, F = S.shape[0], S.shape[2]
    for j in range(m):
        for f in range(F):
            s = S[j, j, f]
            for k in range(j):
                s -= L[j, k, f] * L[j, k, f]
            L[j, j, f] = np.sqrt(max(s, 1e-300))
        for i in range(j + 1, m):
            for f in range(F):
                s = S[i, j, f]
                for k in range(j):
                    s -= L[i, k, f] * L[j, k, f]
                L[i, j, f] = s * (1.0 / L[j, j, f])


@kernel_jit
def log_det_lanes(L, out):
    """out (F,) = log det of each L L^T, ``2 sum_i log L[i, i, f]``, from Cholesky factors L
    (m, m, F) (:func:`cholesky_lanes`)."""
    m, F = L.shape[0], L.shape[2]
    for f in range(F):
        out[f] = 0.0
    for i in range(m):
        for f in range(F):
            out[f] += np.log(L[i, i, f])
    for f in range(F):
        out[f] *= 2.0


@kernel_jit
def forward_lanes(L, b, y):
    """y (m, F) = L^-1 b for each feature: forward substitution with lower factors L (m, m, F)."""
    m, F = b.shape
    for i in range(m):
        for f in range(F):
            s = b[i, f]
            for k in range(i):
                s -= L[i, k, f] * y[k, f]
            y[i, f] = s / L[i, i, f]


@kernel_jit(allocates=True)
def innovations_workspace(m, d, F):
    """Scratch arrays of :func:`feature_innovations_into` (m residuals per feature, d parameters,
    F features): Lp (d, d), S (m, m, F), L (m, m, F), y (m, F); allocated once per run."""
    return np.empty((d, d)), np.empty((m, m, F)), np.empty((m, m, F)), np.empty((m, F))


@kernel_jit(allocates=True)
def feature_innovations(r, H, P, Rm, B, z, logdet):
    """Per-feature ``B_j = H_j L`` (m, d, F) with ``P = L L^T`` (so ``H_j P H_k^T = B_j B_k^T``),
    ``z_j = S_j^-1 r_j`` (m, F) with ``S_j = H_j P H_j^T + R_j = B_j B_j^T + R_j`` and
    ``logdet_j = log det S_j`` (F,) (docs/model.md, Eq. 37), written into B, z and logdet; shared by
    both tests. Through
    L the products cost half of ``H_j P`` (L is triangular). Allocates its scratch; the filter
    calls :func:`feature_innovations_into` with a workspace.
    """
    m, d, F = H.shape
    Lp, S, L, y = innovations_workspace(m, d, F)
    feature_innovations_into(r, H, P, Rm, B, z, logdet, Lp, S, L, y)


@kernel_jit
def feature_innovations_into(r, H, P, Rm, B, z, logdet, Lp, S, L, y):
    """:func:`feature_innovations` with its scratch passed in (:func:`innovations_workspace`)."""
    m, d, F = H.shape
    # Eq. (37): B = H L with P = L L^T, S = B B^T + Rm, its Cholesky factor, log det S, z = S^-1 r.
    _cholesky(P, Lp)
    for a in range(m):
        for c in range(d):
            for f in range(F):
                B[a, c, f] = 0.0
        for b in range(d):
            for c in range(b + 1):
                lbc = Lp[b, c]
                for f in range(F):
                    B[a, c, f] += H[a, b, f] * lbc
        for b in range(a + 1):
            for f in range(F):
                S[a, b, f] = 0.0
            for c in range(d):
                for f in range(F):
                    S[a, b, f] += B[a, c, f] * B[b, c, f]
            for f in range(F):
                S[a, b, f] += Rm[a, b, f]
    cholesky_lanes(S, L)
    log_det_lanes(L, logdet)
    forward_lanes(L, r, y)
    for i in range(m - 1, -1, -1):
        for f in range(F):
            s = y[i, f]
            for k in range(i + 1, m):
                s -= L[k, i, f] * z[k, f]
            z[i, f] = s / L[i, i, f]


@kernel_jit
def mahalanobis_gate(r, z, valid, chi2_threshold, out):
    """out (F,) True where the feature passes ``r^T S^-1 r <= chi2_threshold`` (and is valid);
    z from :func:`feature_innovations`. docs/model.md, Eq. 39."""
    m, F = r.shape
    for f in range(F):
        d2 = 0.0
        for a in range(m):
            d2 += r[a, f] * z[a, f]
        out[f] = valid[f] and d2 <= chi2_threshold


@kernel_jit(allocates=True)
def ransac_workspace(F, m, d):
    """Scratch arrays of :func:`one_point_ransac_into` for F features of m residuals and d
    parameters: Y (d, F), moved (F m, F), inlier (F, F) bool, count (F,) int64."""
    return np.empty((d, F)), np.empty((F * m, F)), np.empty((F, F), np.bool_), np.empty(F, np.int64)


@kernel_jit(allocates=True)
def one_point_ransac(r, B, z, sd, valid, threshold_sigma, out):
    """out (F,): low-innovation inliers of the best 1-point hypothesis (module docstring);
    B, z from :func:`feature_innovations`; sd (m, F) the residuals' measurement standard
    deviations. Allocates its scratch; the filter calls :func:`one_point_ransac_into`.
    docs/model.md, Eq. 38."""
    m, d, F = B.shape
    Y, moved, inlier, count = ransac_workspace(F, m, d)
    one_point_ransac_into(r, B, z, sd, valid, threshold_sigma, out, Y, moved, inlier, count)


@kernel_jit(inline="always")
def _moved_rows(B, Y, moved, d):
    """moved[(j, a), h] = sum_c B[a, c, j] Y[c, h] over the nonzero B[a, c, j] (c in order), for
    B (m, d, F), Y (d, F), moved (F m, F). Each sum is kept in a register (with d a literal the loop
    over c unrolls and the loop over h vectorises; issue 30: summed in memory, each step waited for
    the store of the one before) and a zero B[a, c, j] is skipped by a select, so the bits are
    those of the row updates this replaced."""
    m, F = B.shape[0], B.shape[2]
    for j in range(F):
        for a in range(m):
            for h in range(F):
                acc = 0.0
                for c in range(d):
                    bc = B[a, c, j]
                    y = Y[c, h]
                    acc = acc + bc * y if bc != 0.0 else acc
                moved[j * m + a, h] = acc


@kernel_jit
def one_point_ransac_into(r, B, z, sd, valid, threshold_sigma, out, Y, moved, inlier, count):
    """:func:`one_point_ransac` with its scratch passed in (:func:`ransac_workspace`)."""
    m, d, F = B.shape
    # Eq. (38). Correction of hypothesis h alone: dx_h = P H_h^T S_h^-1 r_h = L y_h with y_h = B_h^T z_h
    # (columns of Y, (d, F)); every feature's residual then moves by
    # H_j dx_h = B_j y_h: moved = B Y, ((j, a), h).
    for c in range(d):
        for h in range(F):
            Y[c, h] = 0.0
    for a in range(m):
        for c in range(d):
            for h in range(F):
                Y[c, h] += z[a, h] * B[a, c, h]
    if d == 12:  # the filter's: a literal trip count, so the sum over c unrolls into registers
        _moved_rows(B, Y, moved, 12)
    else:
        _moved_rows(B, Y, moved, d)
    # inlier[j, h]: every residual of feature j within the threshold after hypothesis h (loops
    # run along h, contiguous, without early exits, so they vectorise).
    for j in range(F):
        for h in range(F):
            inlier[j, h] = valid[j]
        for a in range(m):
            thr = threshold_sigma * sd[a, j]
            rja = r[a, j]
            row = moved[j * m + a]
            for h in range(F):
                inlier[j, h] &= abs(rja - row[h]) <= thr
    for h in range(F):
        count[h] = 0
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
