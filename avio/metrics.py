"""Trajectory errors of a batch of filter runs against ground truth (PAPER.md §4–§5).

Definitions (per filter, over the N frames i = 0..N-1, errors e_i >= 0):

- position error ``e_i = ||p_true,i - p_est,i||`` (m), velocity error
  ``e_i = ||v_true,i - v_est,i||`` (m/s), attitude error the geodesic angle of
  ``R_true,i^T R_est,i`` (deg);
- ``rmse = sqrt(mean_i e_i^2)``, ``mean = mean_i e_i``, ``std = sqrt(mean_i (e_i - mean)^2)``
  (population std over frames) — the RMSE/mean/std columns of the paper's Tables 2–3;
- the objective of the paper (Eq. 11–12) is the position RMSE.

All functions are batched over the calibration axis n.
"""

from __future__ import annotations

import numpy as np

from avio.geometry import geodesic_angle_deg
from avio.sequence import GroundTruth


class MetricsError(ValueError):
    """Estimates and truth do not fit together; the message says how."""


def _summaries(e: np.ndarray, prefix: str) -> dict:
    mean = e.mean(axis=1)
    return {
        f"{prefix}_errors": e,
        f"{prefix}_rmse": np.sqrt(np.mean(e**2, axis=1)),
        f"{prefix}_mean": mean,
        f"{prefix}_std": np.sqrt(np.mean((e - mean[:, None]) ** 2, axis=1)),
    }


def _check(result, truth: GroundTruth) -> None:
    N = truth.p_world_imu_m.shape[0]
    if result.p_world_imu_m.ndim != 3 or result.p_world_imu_m.shape[1:] != (N, 3):
        raise MetricsError(f"estimates {result.p_world_imu_m.shape} do not match truth with {N} frames")


def pose_errors(result, truth: GroundTruth) -> dict:
    """Per-frame errors ``*_errors`` (n, N) and ``*_rmse``, ``*_mean``, ``*_std`` (n,) for
    ``position`` (m), ``velocity`` (m/s) and ``attitude`` (deg); see the module docstring."""
    _check(result, truth)
    e_p = np.linalg.norm(result.p_world_imu_m - truth.p_world_imu_m[None], axis=-1)
    e_v = np.linalg.norm(result.v_world_imu_mps - truth.v_world_imu_mps[None], axis=-1)
    e_a = geodesic_angle_deg(truth.R_world_imu[None], result.R_world_imu)
    out = {}
    for e, name in ((e_p, "position"), (e_v, "velocity"), (e_a, "attitude")):
        out.update(_summaries(e, name))
    return out


def position_rmse_objective(result, truth: GroundTruth, divergence_penalty_m: float = 1000.0) -> np.ndarray:
    """(n,) the paper's cost (Eq. 11–12): ``sqrt(mean_i ||p_true,i - p_VIO,i||^2)``, metres.

    A diverged filter gets ``divergence_penalty_m * (2 - k_div / N)`` (k_div its divergence
    frame): finite, worse than any non-diverged value below the penalty, and worse the earlier
    it diverged, so optimisers can still rank failed candidates. Non-finite RMSE values (which
    a non-flagged filter should never produce) also get the penalty.
    """
    _check(result, truth)
    N = truth.p_world_imu_m.shape[0]
    e2 = np.sum((result.p_world_imu_m - truth.p_world_imu_m[None]) ** 2, axis=-1)
    f = np.sqrt(np.mean(e2, axis=1))
    penalty = divergence_penalty_m * (2.0 - np.clip(result.diverged_at_frame, 0, N) / N)
    bad = np.asarray(result.diverged, bool) | ~np.isfinite(f)
    return np.where(bad, np.where(result.diverged, penalty, 2.0 * divergence_penalty_m), f)
