"""Trajectory errors of a batch of filter runs against ground truth (docs/model.md, "Objectives and
metrics", Eqs. 52, 56-57).

Definitions (per filter, over the N frames i = 0..N-1, errors e_i >= 0):

- position error ``e_i = ||p_true,i - p_est,i||`` (m), velocity error
  ``e_i = ||v_true,i - v_est,i||`` (m/s), attitude error the geodesic angle of
  ``R_true,i^T R_est,i`` (deg; Eq. 3);
- ``rmse = sqrt(mean_i e_i^2)``, ``mean = mean_i e_i``, ``std = sqrt(mean_i (e_i - mean)^2)``
  (population std over frames) — the RMSE/mean/std columns of the paper's Tables 2–3 (Eq. 56);
- the objective of the paper (its Eq. 11–12) is the position RMSE (Eq. 52);
- drift (``drift_metrics``): the KITTI odometry benchmark's relative-pose error over path
  segments, ``t_rel`` (%) and ``r_rel`` (deg/100 m) over 100–800 m, per-metre drift (also for
  drives under 100 m) and the largest one-frame position jump error (Eq. 57).

All functions are batched over the calibration axis n.
"""

from __future__ import annotations

import numpy as np

from avio.errors import AvioError
from avio.geometry import geodesic_angle_deg
from avio.sequence import GroundTruth


class MetricsError(AvioError):
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
    ``position`` (m), ``velocity`` (m/s) and ``attitude`` (deg); see the module docstring
    (docs/model.md, Eq. 56)."""
    _check(result, truth)
    e_p = np.linalg.norm(result.p_world_imu_m - truth.p_world_imu_m[None], axis=-1)
    e_v = np.linalg.norm(result.v_world_imu_mps - truth.v_world_imu_mps[None], axis=-1)
    e_a = geodesic_angle_deg(truth.R_world_imu[None], result.R_world_imu)
    out = {}
    for e, name in ((e_p, "position"), (e_v, "velocity"), (e_a, "attitude")):
        out.update(_summaries(e, name))
    return out


def position_rmse_objective(result, truth: GroundTruth, divergence_penalty_m: float = 1000.0) -> np.ndarray:
    """(n,) the paper's cost (its Eq. 11–12; docs/model.md, Eq. 52): ``sqrt(mean_i ||p_true,i -
    p_VIO,i||^2)``, metres.

    A diverged filter gets ``divergence_penalty_m * (2 - k_div / N)`` (k_div its divergence
    frame): finite, worse than any non-diverged value below the penalty, and worse the earlier
    it diverged, so optimisers can still rank failed candidates. Non-finite RMSE values (which
    a non-flagged filter should never produce) also get the penalty.
    """
    _check(result, truth)
    N = truth.p_world_imu_m.shape[0]
    # Eq. (52): the RMSE, or the divergence penalty.
    e2 = np.sum((result.p_world_imu_m - truth.p_world_imu_m[None]) ** 2, axis=-1)
    f = np.sqrt(np.mean(e2, axis=1))
    penalty = divergence_penalty_m * (2.0 - np.clip(result.diverged_at_frame, 0, N) / N)
    bad = np.asarray(result.diverged, bool) | ~np.isfinite(f)
    return np.where(bad, np.where(result.diverged, penalty, 2.0 * divergence_penalty_m), f)


# --- drift over path segments (KITTI odometry devkit, Geiger et al. 2012) -----------------

KITTI_SEGMENTS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
SHORT_SEGMENT_STEP_M = 10.0
SEGMENT_START_STEP = 10  # frames between segment starts, as in the KITTI devkit


def segment_lengths_m(path_length_m: float) -> tuple[np.ndarray, bool]:
    """The segment lengths (m) drift is averaged over on a drive of ``path_length_m``, and
    whether they are KITTI's: KITTI's 100, 200, ..., 800 m that are shorter than the path;
    when none is (a drive of 100 m or less), every multiple of 10 m shorter than the path; on a
    drive of 10 m or less (a room-sized flight), every multiple of 1 m shorter than it (none
    for a path of 1 m or less)."""
    kitti = np.array([L for L in KITTI_SEGMENTS_M if L < path_length_m])
    if kitti.size:
        return kitti, True
    step = SHORT_SEGMENT_STEP_M if path_length_m > SHORT_SEGMENT_STEP_M else 1.0
    short = step * np.arange(1, int(np.ceil(path_length_m / step)) + 1)
    return short[short < path_length_m], False


def _segments(p_true: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first, last, length) frame indices of every segment: starts every SEGMENT_START_STEP
    frames, ``last`` the first frame whose ground-truth distance from ``first`` along the path
    exceeds the length (the devkit's ``lastFrameFromSegmentLength``); segments running past
    the end of the drive are dropped."""
    dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p_true, axis=0), axis=1))]
    first = np.arange(0, len(dist), SEGMENT_START_STEP)
    F, L = np.meshgrid(first, lengths, indexing="ij")
    last = np.searchsorted(dist, dist[F] + L, side="right")
    keep = last < len(dist)
    return F[keep], last[keep], L[keep]


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Geodesic angle of ``R_a^T R_b`` (deg), (...) (docs/model.md, Eq. 3): ``atan2(|axis part|, cos part)`` of the
    product, accurate near 0 (where the devkit's ``acos`` of the trace is not) and ~20x faster
    than a scipy Rotation round trip on the many segments of a batch."""
    M = np.einsum("...ji,...jk->...ik", R_a, R_b)
    cos = 0.5 * (np.einsum("...ii->...", M) - 1.0)
    axis = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)
    return np.degrees(np.arctan2(0.5 * np.linalg.norm(axis, axis=-1), cos))


def drift_metrics(p_est: np.ndarray, R_est: np.ndarray, truth: GroundTruth) -> dict[str, np.ndarray]:
    """Drift of n estimated IMU trajectories against the ground truth, each (n,).

    p_est: (n, N, 3) ``p_world_imu_m`` (m); R_est: (n, N, 3, 3) ``R_world_imu``; truth: N frames.

    Over every segment (first, last) of the path (``segment_lengths_m``, starts every 10
    frames), the relative-pose error of the KITTI devkit: with ``D = T_first^-1 T_last`` for the
    estimate and the truth, ``E = D_est^-1 D_true``; translation error ``|t(E)|`` (m) and
    rotation error ``angle(R(E))`` (deg), each divided by the segment length L (docs/model.md, Eq. 57).

    - ``t_rel_pct``: mean over the KITTI segments (100–800 m) of ``100 |t(E)| / L`` (%);
      NaN on a drive shorter than 100 m;
    - ``r_rel_deg_per_100m``: mean over the same segments of ``100 angle(E) / L`` (deg/100 m);
    - ``drift_m_per_m``: mean of ``|t(E)| / L`` (m/m) over the segments used — the KITTI ones,
      or on shorter drives the 10 m (or, up to 10 m, 1 m) steps below the path length; NaN when
      no segment fits (a path of 1 m or less);
    - ``max_jump_m``: the largest one-frame position jump error,
      ``max_i |(p_est,i+1 - p_est,i) - (p_true,i+1 - p_true,i)|`` (m).

    A filter whose estimate holds non-finite values gets NaN everywhere.
    """
    p_est = np.asarray(p_est, float)
    R_est = np.asarray(R_est, float)
    N = truth.p_world_imu_m.shape[0]
    if p_est.ndim != 3 or p_est.shape[1:] != (N, 3) or R_est.shape != p_est.shape[:2] + (3, 3):
        raise MetricsError(f"estimates p {p_est.shape} and R {R_est.shape} do not match truth with {N} frames "
                           "(need (n, N, 3) and (n, N, 3, 3))")
    n = p_est.shape[0]
    finite = np.isfinite(p_est).all(axis=(1, 2)) & np.isfinite(R_est).all(axis=(1, 2, 3))
    p_ok = np.where(finite[:, None, None], p_est, truth.p_world_imu_m[None])
    R_ok = np.where(finite[:, None, None, None], R_est, truth.R_world_imu[None])

    jump = np.diff(p_ok, axis=1) - np.diff(truth.p_world_imu_m, axis=0)[None]
    max_jump = np.linalg.norm(jump, axis=-1).max(axis=1) if N > 1 else np.zeros(n)

    lengths, is_kitti = segment_lengths_m(float(np.linalg.norm(np.diff(truth.p_world_imu_m, axis=0),
                                                               axis=1).sum()) if N > 1 else 0.0)
    first, last, L = _segments(truth.p_world_imu_m, lengths)
    nan = np.full(n, np.nan)
    if first.size == 0:
        t_rel = r_rel = drift = nan
    else:
        def delta(p, R):  # D = T_first^-1 T_last: (.., S, 3) translation, (.., S, 3, 3) rotation
            R_first_T = np.swapaxes(R[..., first, :, :], -1, -2)
            return (R_first_T @ (p[..., last, :] - p[..., first, :])[..., None])[..., 0], \
                R_first_T @ R[..., last, :, :]

        t_true, R_true = delta(truth.p_world_imu_m, truth.R_world_imu)
        t_e, R_e = delta(p_ok, R_ok)
        # |t(D_est^-1 D_true)| = |R_est^T (t_true - t_est)| = |t_true - t_est|
        t_err = np.linalg.norm(t_true[None] - t_e, axis=-1) / L  # (n, S) m/m
        r_err = _angle_deg(R_e, R_true[None]) / L                # (n, S) deg/m
        drift = t_err.mean(axis=1)
        t_rel, r_rel = (100 * t_err.mean(axis=1), 100 * r_err.mean(axis=1)) if is_kitti else (nan, nan)
    out = {"t_rel_pct": t_rel, "r_rel_deg_per_100m": r_rel, "drift_m_per_m": drift, "max_jump_m": max_jump}
    return {k: np.where(finite, v, np.nan) for k, v in out.items()}
