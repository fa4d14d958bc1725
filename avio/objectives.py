"""Calibration objectives from batches of filter runs, pooled over one or more drives.

- :func:`pooled_position_rmse`: the paper's cost (Eq. 11-12), ``sqrt(mean_i ||p_true,i -
  p_VIO,i||^2)`` over every frame i of every drive (for one drive exactly
  avio.metrics.position_rmse_objective), metres.
- :func:`innovation_nll`: the negative log-likelihood of the filter's innovations, per residual.
  For frame k with a trifocal update over the inlier features (stacked residuals r_k of
  dimension m_k, innovation covariance ``S_k = H P H^T + R``):
  ``l_k = 1/2 (r_k^T S_k^-1 r_k + log det S_k + m_k log 2 pi)``; every valid feature the filter
  did not use (an outlier for this filter, a degenerate transfer, no baseline) adds the capped
  value ``1/2 (chi2_gate + log det S_f + 4 log 2 pi)`` with its own innovation covariance
  ``S_f`` (or ``R_f`` where the filter has none), a truncated-Gaussian (robust) likelihood. So
  every filter of a batch is scored over the same residual slots (4 per valid feature of every
  frame with features, calibration-free), and rejecting a feature never pays better than
  explaining it. The objective is ``sum_k l_k / sum_k slots_k`` (dimensionless; per residual, so
  drives and batches of any length compare). Standstill frames (zero-velocity update, decided
  without the calibration) carry no image information and are left out for every filter.
  Computed inside the filter kernel (avio/_kernels.py) as ``FilterResult.nll``,
  ``nll_slots``, ``nis``, ``dof``.

A diverged filter gets ``penalty * (2 - k_div / N)`` under either objective (the worst over the
drives), finite and worse the earlier it diverged.
"""

from __future__ import annotations

import numpy as np

from avio.metrics import position_rmse_objective

OBJECTIVES = ("position_rmse", "innovation_nll")


def _penalty(results, penalty: float) -> tuple[np.ndarray, np.ndarray]:
    """(n,) whether any drive diverged, and the penalty of the earliest relative divergence."""
    diverged = np.any([r.diverged for r in results], axis=0)
    frac = np.min([np.where(r.diverged, np.clip(r.diverged_at_frame, 0, None) / r.p_world_imu_m.shape[1], 1.0)
                   for r in results], axis=0)
    return diverged, penalty * (2.0 - frac)


def pooled_position_rmse(results, truths, penalty: float) -> np.ndarray:
    """(n,) position RMSE over every frame of every drive (results[d] against truths[d]), m."""
    per = [position_rmse_objective(r, t, penalty) for r, t in zip(results, truths)]
    if len(per) == 1:
        return per[0]
    frames = np.array([t.p_world_imu_m.shape[0] for t in truths], float)
    diverged, pen = _penalty(results, penalty)
    f = np.sqrt(sum(w * p**2 for w, p in zip(frames, per)) / frames.sum())
    return np.where(diverged | ~np.isfinite(f), np.where(diverged, pen, 2.0 * penalty), f)


def innovation_nll(results, penalty: float) -> tuple[np.ndarray, np.ndarray]:
    """(n,) the innovation NLL per residual pooled over the drives (module docstring), and
    (n,) the NIS per degree of freedom of the updates (~1 for a consistent filter)."""
    nll = sum(r.nll.sum(axis=1) for r in results)
    slots = sum(r.nll_slots.sum(axis=1) for r in results)
    nis = sum(r.nis.sum(axis=1) for r in results)
    dof = sum(r.dof.sum(axis=1) for r in results)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = nll / slots
        nis_per_dof = np.where(dof > 0, nis / np.maximum(dof, 1), np.nan)
    diverged, pen = _penalty(results, penalty)
    f = np.where(diverged | ~np.isfinite(f), np.where(diverged, pen, 2.0 * penalty), f)
    return f, nis_per_dof
