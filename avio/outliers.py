"""Per-filter outlier rejection of the trifocal measurements (PAPER.md §2, "Outliers").

Both tests work on the whitened, linearised measurement of each feature (4 residuals:
two Sampson distances and the 2-D transfer error, pixels) and decide per filter:

- :func:`mahalanobis_gate`: chi-square gate of ``r_j^T S_j^-1 r_j`` with
  ``S_j = H_j P H_j^T + R_j`` (4 degrees of freedom);
- :func:`one_point_ransac`: the paper's 1-point RANSAC (Civera et al. 2010) with the filter's
  prediction: every feature in turn is a hypothesis (so no random draw, and a batch gives the
  same answer as single runs); the state is corrected with that feature alone (one Kalman
  step, linearised), the other features' residuals are predicted after the correction, and a
  feature is an inlier when each of its residuals is within ``threshold_sigma`` standard
  deviations of measurement noise. The hypothesis with most inliers wins (ties: the first).

Shapes: r (n, F, 4), H (n, F, 4, d), P (n, d, d) the covariance of the d parameters H
differentiates against, sigma (4,), valid (n, F).
"""

from __future__ import annotations

import numpy as np


class OutlierError(ValueError):
    """Bad input to outlier rejection; the message names what."""


def spd_solve_small(S: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve ``S z = r`` for many small SPD matrices S (..., m, m), r (..., m) by an unrolled
    Cholesky factorisation.

    Hand-written because numpy's batched solve calls LAPACK once per 4x4 matrix, which costs
    more than the arithmetic for the thousands of per-feature systems of one frame.
    """
    m = S.shape[-1]
    L = [[None] * m for _ in range(m)]
    for j in range(m):
        d = S[..., j, j] - sum(L[j][k] * L[j][k] for k in range(j))
        L[j][j] = np.sqrt(np.maximum(d, 1e-300))
        for i in range(j + 1, m):
            L[i][j] = (S[..., i, j] - sum(L[i][k] * L[j][k] for k in range(j))) / L[j][j]
    y = [None] * m
    for i in range(m):
        y[i] = (r[..., i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i]
    z = [None] * m
    for i in reversed(range(m)):
        z[i] = (y[i] - sum(L[k][i] * z[k] for k in range(i + 1, m))) / L[i][i]
    return np.stack(z, axis=-1)


def feature_innovations(r, H, P, sigma):
    """Per-feature ``HP = H_j P`` (n, F, 4, d) and ``z = S_j^-1 r_j`` (n, F, 4) with
    ``S_j = H_j P H_j^T + diag(sigma^2)``; shared by both tests."""
    n, F, m, d = H.shape
    HP = (H.reshape(n, F * m, d) @ P).reshape(n, F, m, d)
    S = HP @ np.swapaxes(H, -1, -2) + np.diag(sigma**2)
    return HP, spd_solve_small(S, r)


def mahalanobis_gate(r, z, valid, chi2_threshold: float):
    """(n, F) True where the feature passes ``r^T S^-1 r <= chi2_threshold`` (and is valid);
    z from :func:`feature_innovations`."""
    d2 = (r * z).sum(axis=-1)
    return valid & (d2 <= chi2_threshold)


def one_point_ransac(r, H, HP, z, sigma, valid, threshold_sigma: float):
    """(n, F) low-innovation inliers of the best 1-point hypothesis (see module docstring);
    HP, z from :func:`feature_innovations`."""
    if r.ndim != 3 or r.shape[-1] != len(sigma):
        raise OutlierError(f"residuals must be (n, F, {len(sigma)}), got {r.shape}")
    n, F, m = r.shape
    # Correction of hypothesis h alone: dx_h = P H_h^T S_h^-1 r_h, (n, F, d); then every
    # feature's residual moves by H_j dx_h.
    dx = (z[:, :, None, :] @ HP)[:, :, 0, :]
    moved = H.reshape(n, F * m, -1) @ np.swapaxes(dx, 1, 2)  # (n, (j, a), h)
    predicted = r.reshape(n, F * m, 1) - moved
    ok = np.abs(predicted) <= (threshold_sigma * np.tile(sigma, F))[None, :, None]
    inlier = ok.reshape(n, F, m, F).all(axis=2) & valid[:, :, None]  # (n, j, h)
    count = np.where(valid, inlier.sum(axis=1), -1)
    best = np.argmax(count, axis=1)
    return inlier[np.arange(n), :, best] & valid
