"""The batched sliding-window trifocal VIO: n error-state Kalman filters in lock-step (PAPER.md §2).

One call of :func:`run` runs one filter per candidate calibration over the same IMU and feature
tracks. Every array carries the calibration axis first, and the Python loop runs over frames
only, never over calibrations (DESIGN.md, "Batch first").

State (nominal): ``p_world_imu`` (m), ``R_world_imu``, ``v_world_imu`` (m/s), accelerometer and
gyro biases ``b_a`` (m/s^2), ``b_g`` (rad/s), and two clones of the camera-exposure IMU pose of
frames k-2 and k-1. Error state, 27: ``[dp, dtheta, dv, db_a, db_g, dp1, dtheta1, dp2, dtheta2]``
with local rotation errors (``R_true = R exp(dtheta)``).

- Initial state: the ground-truth pose and velocity at frame 0, biases zero; the initial
  covariance is diagonal with the ``init_sigma_*`` of :class:`FilterConfig`. The filter
  estimates from frame 0 on; frames before the first complete triplet are IMU propagation only.
- Prediction: the IMU increments of every frame interval are integrated with RK4 (IMU linearly
  interpolated at sub-steps of ``rk4_max_step_s``) once per sequence, bias-free, together with
  their bias Jacobians; each filter applies its own biases to first order (Forster et al. 2017
  preintegration). Against a per-filter RK4 with biases this differs by ~|b_g T|^2, below 1e-6 m
  per interval (tests/avio/test_imu_propagation.py) and makes the prediction ~50x cheaper.
  Covariance: closed-form transition of the interval and the discrete IMU noise
  (avio/imu_propagation.py), once per frame.
- Time offset ``td`` (per calibration): frame k was exposed at IMU time ``t_k + td``; its pose is
  taken to first order, ``(p + v td, R exp((w_m - b_g) td))``, both for the clones and for the
  current pose in the measurement (with its Jacobian w.r.t. ``dv`` and ``db_g``).
- Update per frame triplet: 4 pixel residuals per feature (avio/measurement.py) with analytic
  Jacobians; features chosen once per sequence by 4x8 bucketing of frame k's image
  (calibration-independent); outliers rejected per filter (avio/outliers.py); then the Kalman
  update in information form, reduced to the 12 relative-pose errors the measurement depends
  on (see :func:`_update`): a 12x12 solve, never the (4F)x(4F) innovation covariance.
- Standing still: when the median image motion of a triplet's features over two frames is
  below ``stationary_flow_px`` (calibration-free), the trifocal geometry has no baseline and
  says nothing; a zero-velocity pseudo-measurement (``zero_velocity_sigma_mps``) replaces the
  update. (Not in the paper; its drives do not stop, the simulated city drive does.)
- Slide: the oldest clone is dropped and the (time-shifted) current pose is cloned.
- Divergence: a filter whose state or covariance is non-finite, whose largest covariance
  diagonal exceeds ``divergence_max_variance`` (default 1e6, i.e. a 1 km standard deviation) or
  whose speed exceeds ``divergence_max_speed_mps`` (100 m/s) is flagged at that frame and frozen:
  its estimates stay at the last good frame, its state is reset each frame to that value so the
  batch arithmetic stays finite; the others carry on. A calibration with non-finite values is
  flagged at frame 0. :func:`avio.metrics.position_rmse_objective` turns a divergence into a
  finite penalty.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.stats import chi2

from avio.imu_propagation import (
    preintegrate,
    process_noise,
    propagate_preintegrated,
    so3_exp_fast,
)
from avio.measurement import (
    camera_pose_jacobian,
    relative_pose_jacobian,
    relative_poses,
    triplet_residuals,
)
from avio.outliers import feature_innovations, mahalanobis_gate, one_point_ransac
from avio.sequence import Calibration, Sequence


class FilterError(ValueError):
    """Bad input to the filter (sequence, calibrations or config); the message says what."""


@lru_cache(maxsize=None)
def _chi2_ppf(probability: float, dof: int) -> float:
    return float(chi2.ppf(probability, dof))


OUTLIER_MODES = ("ransac", "mahalanobis", "both", "none")


@dataclass(frozen=True)
class FilterConfig:
    """Filter settings (units in the names).

    outlier_rejection: "both" (default), "ransac", "mahalanobis" or "none". "both" runs the
        1-point RANSAC and then the chi-square gate on its inliers. Measured with
        ``scripts/bench_filter.py outliers`` (truth calibration, seeds 0-4, position RMSE
        mean / max): kitti00 15-796 both 3.61 / 4.09 m, mahalanobis 3.62 / 4.08, ransac
        6.99 / 8.61, none 7.72 / 9.83; simulated 540 m city drive (5 % outliers) both
        2.13 / 3.12 m, mahalanobis 2.12 / 3.20, ransac 4.08 / 12.6, none 225 / 474. RANSAC
        alone uses a fixed pixel threshold after a one-feature correction and keeps features
        the state uncertainty cannot explain (or drops ones it can); the gate alone ties with
        "both" in accuracy and is ~10 % faster; "both" is kept as the default for its slightly
        better worst case with outliers and because it is the paper's RANSAC plus a gate.
    rk4_max_step_s: longest RK4 sub-step of the once-per-sequence IMU integration, seconds.
    max_update_features: features per update (16: kitti00 15-796 and the simulated 540 m drive
        gave the same median RMSE with 12 and 16, worse with 10 and 24), chosen by bucketing
        frame k's image into ``bucket_grid`` (rows, cols) cells (avio.tracks.bucket_select,
        seeded with ``bucket_seed``; calibration-independent, so once per sequence).
    epipolar_sigma_px / transfer_sigma_px: measurement noise of the Sampson distances and of
        each transfer coordinate (the reference implementation uses 2 px^2 for the transfer).
    mahalanobis_probability: chi-square gate (4 degrees of freedom) of one feature.
    ransac_threshold_sigma: a feature is a RANSAC inlier when each residual is within this many
        measurement standard deviations after the hypothesis' correction.
    min_parallax_m: no trifocal update when the predicted camera baseline 1-2 or 2-3 is shorter.
    min_feature_flow_px: features moving less than this between consecutive images are not
        used (0: all are used; dropping them did not help).
    stationary_flow_px, zero_velocity_sigma_mps: standing-still detection and its pseudo-
        measurement (module docstring); the threshold suits pixel noise up to ~0.7 px.
    init_sigma_*: initial standard deviations (m, rad, m/s, m/s^2, rad/s); the clones start
        with the pose values. The bias ones matter: with 1e-3 rad/s on the gyro bias the
        trifocal updates "learn" a yaw-rate bias that is not there (yaw is unobservable) and
        the heading drifts 1.5-2 deg; 1e-4 rad/s (the order of the sensors' bias) and
        0.02 m/s^2 took the simulated 540 m drive from 3.4 to 2.0 m median RMSE, the 928 m
        one from 8.2 to 2.1 m and kitti00 15-796 from 4.1 to 3.4 m (5 seeds).
    imu_noise_scale: multiplies the sequence's ImuNoise densities (process noise).
    divergence_max_variance, divergence_max_speed_mps: divergence thresholds (m^2 or (m/s)^2
        or rad^2 on any diagonal entry of the covariance; m/s on the estimated speed).
    """

    rk4_max_step_s: float = 0.005
    max_update_features: int = 16
    bucket_grid: tuple[int, int] = (4, 8)
    bucket_seed: int = 0
    epipolar_sigma_px: float = 1.0
    transfer_sigma_px: float = float(np.sqrt(2.0))
    outlier_rejection: str = "both"
    mahalanobis_probability: float = 0.99
    ransac_threshold_sigma: float = 3.0
    min_parallax_m: float = 0.05
    min_feature_flow_px: float = 0.0
    stationary_flow_px: float = 1.5
    zero_velocity_sigma_mps: float = 0.1
    init_sigma_p_m: float = 0.01
    init_sigma_theta_rad: float = float(np.radians(0.1))
    init_sigma_v_mps: float = 0.05
    init_sigma_ba_mps2: float = 0.02
    init_sigma_bg_radps: float = 1e-4
    imu_noise_scale: float = 1.0
    divergence_max_variance: float = 1e6
    divergence_max_speed_mps: float = 100.0

    @property
    def chi2_threshold(self) -> float:
        """Gate on the squared Mahalanobis distance of one feature's 4 residuals."""
        return float(_chi2_ppf(self.mahalanobis_probability, 4))

    def __post_init__(self) -> None:
        if self.outlier_rejection not in OUTLIER_MODES:
            raise FilterError(f"FilterConfig.outlier_rejection must be one of {OUTLIER_MODES}, "
                              f"got {self.outlier_rejection!r}")
        if self.max_update_features < 1 or self.rk4_max_step_s <= 0:
            raise FilterError("FilterConfig: max_update_features >= 1 and rk4_max_step_s > 0 required")


@dataclass(frozen=True)
class FilterResult:
    """Estimates of n filters at the N frames (IMU pose at the frame time, world frame).

    p_world_imu_m (n, N, 3), R_world_imu (n, N, 3, 3), v_world_imu_mps (n, N, 3).
    diverged (n,) bool; diverged_at_frame (n,) int, -1 when the filter did not diverge.
    n_updates (n, N) features used in each frame's update; n_outliers (n, N) rejected ones.
    sigma (n, N, 15): the filter's own standard deviations of ``[p, theta, v, b_a, b_g]``
        (square roots of the core covariance diagonal; m, rad, m/s, m/s^2, rad/s) at each frame.
    b_a_mps2, b_g_radps (n, N, 3): bias estimates.
    """

    p_world_imu_m: np.ndarray
    R_world_imu: np.ndarray
    v_world_imu_mps: np.ndarray
    diverged: np.ndarray
    diverged_at_frame: np.ndarray
    n_updates: np.ndarray
    n_outliers: np.ndarray
    sigma: np.ndarray
    b_a_mps2: np.ndarray
    b_g_radps: np.ndarray
    meta: dict = field(default_factory=dict)


@dataclass(frozen=True)
class _Prepared:
    """Calibration-independent inputs, built once per (sequence, config)."""

    pre: object  # avio.imu_propagation.Preintegrated
    triplet_of_frame: np.ndarray  # (N,) triplet index ending at the frame, -1 if none
    uv_px: np.ndarray  # (n_trip, F, 3, 2) selected features
    valid: np.ndarray  # (n_trip, F)
    Qd: np.ndarray  # (N, 15, 15)
    stationary: np.ndarray  # (N,) bool, the images of frames k-2..k show no motion


def prepare(sequence: Sequence, config: FilterConfig) -> _Prepared:
    """Everything of the filter that does not depend on the calibration (cache it per sequence)."""
    from avio.tracks import bucket_select

    if sequence.tracks is None:
        raise FilterError(f"sequence {sequence.name!r} has no feature tracks; run the front end first")
    tr = sequence.tracks
    imu = sequence.imu
    pre = preintegrate(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, sequence.frame_t_s,
                       config.rk4_max_step_s)
    N = sequence.n_frames
    if np.any((tr.frame_index < 2) | (tr.frame_index >= N)):
        raise FilterError(f"sequence {sequence.name!r}: triplet frame_index outside [2, {N})")
    # Image motion of each feature (pixels, calibration-free): a feature that hardly moves
    # (far away or near the epipole) makes the transfer ill-conditioned; a triplet whose
    # features hardly move means the car stands still.
    flow = np.linalg.norm(np.diff(tr.uv_px, axis=2), axis=-1)  # (n_trip, F, 2)
    moving = np.where(tr.valid, flow.min(axis=-1), np.nan)
    flow13 = np.linalg.norm(tr.uv_px[:, :, 2] - tr.uv_px[:, :, 0], axis=-1)
    stationary = np.zeros(N, bool)
    has = tr.n_features >= 3
    median_flow = np.nanmedian(np.where(tr.valid[has], flow13[has], np.nan), axis=1)
    stationary[tr.frame_index[has]] = median_flow < config.stationary_flow_px
    trip, feat = np.nonzero(tr.valid & (moving >= config.min_feature_flow_px))
    uv3 = tr.uv_px[trip, feat, 2]
    chosen = bucket_select(trip, uv3, config.max_update_features, np.random.default_rng(config.bucket_seed),
                           sequence.image_size_px, config.bucket_grid)
    trip, feat = trip[chosen], feat[chosen]
    F = config.max_update_features
    slot = np.zeros(len(trip), np.int64)
    if len(trip):
        first = np.r_[True, trip[1:] != trip[:-1]]
        start = np.maximum.accumulate(np.where(first, np.arange(len(trip)), 0))
        slot = np.arange(len(trip)) - start
    uv = np.zeros((len(tr.frame_index), F, 3, 2))
    valid = np.zeros((len(tr.frame_index), F), bool)
    uv[trip, slot] = tr.uv_px[trip, feat]
    valid[trip, slot] = True
    tof = np.full(N, -1)
    tof[tr.frame_index] = np.arange(len(tr.frame_index))
    nz = sequence.imu_noise
    s = config.imu_noise_scale
    Qd = np.stack([process_noise(T, s * nz.accel_noise, s * nz.gyro_noise, s * nz.accel_bias_walk,
                                 s * nz.gyro_bias_walk) for T in pre.T_s])
    return _Prepared(pre, tof, uv, valid, Qd, stationary)


class _State:
    """Nominal states and covariances of the n filters (mutable, private to :func:`run`)."""

    def __init__(self, sequence: Sequence, n: int, config: FilterConfig):
        tr = sequence.truth
        self.R = np.repeat(tr.R_world_imu[:1], n, axis=0).astype(float)
        self.p = np.repeat(tr.p_world_imu_m[:1], n, axis=0).astype(float)
        self.v = np.repeat(tr.v_world_imu_mps[:1], n, axis=0).astype(float)
        self.ba = np.zeros((n, 3))
        self.bg = np.zeros((n, 3))
        self.cp = np.zeros((2, n, 3))  # clones (k-2, k-1): exposure-time IMU positions
        self.cR = np.repeat(np.eye(3)[None, None], 2, 0).repeat(n, 1)
        c = config
        d = np.r_[[c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3, [c.init_sigma_v_mps] * 3,
                  [c.init_sigma_ba_mps2] * 3, [c.init_sigma_bg_radps] * 3, [c.init_sigma_p_m] * 3,
                  [c.init_sigma_theta_rad] * 3, [c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3]
        self.P0 = np.diag(d**2)
        self.P = np.repeat(self.P0[None], n, axis=0)

    NAMES = ("R", "p", "v", "ba", "bg", "cp", "cR", "P")

    def snapshot(self) -> dict:
        return {k: getattr(self, k).copy() for k in self.NAMES}

    def restore(self, snap: dict, which: np.ndarray) -> None:
        """Reset the filters in ``which`` (n,) bool to a snapshot (clone axes come second)."""
        for k in self.NAMES:
            a = getattr(self, k)
            if k in ("cp", "cR"):
                a[:, which] = snap[k][:, which]
            else:
                a[which] = snap[k][which]
        self.P[which] = self.P0


def _shifted_pose(st: _State, omega, td):
    """Exposure-time IMU pose (p + v td, R exp(w td)) and its (n, 6, 15) Jacobian w.r.t. the core
    error ``[dp, dtheta, dv, db_a, db_g]``."""
    E = so3_exp_fast(omega * td[:, None])
    R = st.R
    n = len(td)
    J = np.zeros((n, 6, 15))
    J[:, 0:3, 0:3] = np.eye(3)
    J[:, 0:3, 6:9] = td[:, None, None] * np.eye(3)
    J[:, 3:6, 3:6] = np.swapaxes(E, 1, 2)
    J[:, 3:6, 12:15] = -td[:, None, None] * np.eye(3)
    return st.p + st.v * td[:, None], R @ E, J


def _slide(st: _State, p_new, R_new, J_new) -> None:
    """Drop clone k-2, move k-1 down, clone the current exposure pose (error rows J_new @ core)."""
    st.cp[0], st.cR[0] = st.cp[1], st.cR[1]
    st.cp[1], st.cR[1] = p_new, R_new
    P = st.P
    Pn = P.copy()
    Pn[:, 15:21, :] = P[:, 21:27, :]
    Pn[:, :, 15:21] = Pn[:, :, 21:27].copy()
    new_rows = J_new @ P[:, 0:15, :]  # (n, 6, 27), cross-covariances with the old state
    new_rows[:, :, 15:21] = new_rows[:, :, 21:27]
    Pn[:, 21:27, :] = new_rows
    Pn[:, :, 21:27] = np.swapaxes(new_rows, 1, 2)
    Pn[:, 21:27, 21:27] = new_rows[:, :, 0:15] @ np.swapaxes(J_new, 1, 2)
    st.P = Pn


def measurement_model(st: "_State", cal: Calibration, uv_px, omega, td):
    """Innovations r (n, F, 4) pixels, their Jacobian J (n, F, 4, 12) w.r.t. the relative-pose
    errors of the triplet and the map C (n, 12, 27) from the error state to those, so that the
    measurement Jacobian is ``H = J C`` (``dr = -H dx``); also t12, t13 (n, 3).

    Chain: state error -> exposure-time IMU poses of images 1, 2, 3 (clones, shifted current
    pose) -> camera pose errors -> relative-pose errors -> residuals (avio/measurement.py).
    """
    n = len(td)
    p3, R3, Jshift = _shifted_pose(st, omega, td)
    Rci, pic = cal.R_cam_imu, cal.p_imu_cam_m
    Rci_t = np.swapaxes(Rci, 1, 2)
    R_imu = np.stack([st.cR[0], st.cR[1], R3])
    p_imu = np.stack([st.cp[0], st.cp[1], p3])
    Rc = R_imu @ Rci_t[None]
    pc = p_imu + (R_imu @ pic[None, :, :, None])[..., 0]
    R12, t12, R13, t13 = relative_poses(Rc, pc)
    r, J = triplet_residuals(uv_px, R12, t12, R13, t13, cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px)
    G = np.zeros((n, 18, 27))
    G[:, 0:6, 15:21] = camera_pose_jacobian(R_imu[0], Rci, pic)
    G[:, 6:12, 21:27] = camera_pose_jacobian(R_imu[1], Rci, pic)
    G[:, 12:18, 0:15] = camera_pose_jacobian(R_imu[2], Rci, pic) @ Jshift
    C = relative_pose_jacobian(Rc, t12, t13) @ G
    return r, J, C, t12, t13


def _update(st: _State, cal: Calibration, uv_px, valid, omega, td, config: FilterConfig):
    """One trifocal update of all filters; returns (used, rejected) feature counts (n,).

    The measurement depends on the state only through the 12 relative-pose errors ``C dx``,
    so the gates and the update work with ``Sigma = C P C^T`` (12x12) and ``J``: the Kalman
    step is ``P+ = P - P C^T (I + A Sigma)^-1 A C P``, ``dx = P C^T (I + A Sigma)^-1 J^T R^-1 r``
    with ``A = J^T R^-1 J`` — algebraically the information form
    ``(P^-1 + H^T R^-1 H)^-1`` with ``H = J C``, at the price of a 12x12 solve.
    """
    n = len(td)
    # Degenerate geometry (a point at the epipole, a wild candidate) gives non-finite values;
    # they are masked out just below, so the warnings carry no information.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        r, J, C, t12, t13 = measurement_model(st, cal, uv_px, omega, td)
    ok = valid[None, :] & np.all(np.isfinite(r), axis=-1) & np.all(np.isfinite(J), axis=(-1, -2))
    # Without baseline the epipolar geometry and the transfer are undefined (car standing still).
    moving = (np.linalg.norm(t12, axis=1) > config.min_parallax_m) & (
        np.linalg.norm(t13 - t12, axis=1) > config.min_parallax_m)
    ok &= moving[:, None]
    r = np.where(ok[..., None], r, 0.0)
    J = np.where(ok[..., None, None], J, 0.0)
    PCt = st.P @ np.swapaxes(C, 1, 2)  # (n, 27, 12)
    Sigma = C @ PCt
    Sigma = 0.5 * (Sigma + np.swapaxes(Sigma, 1, 2))
    sigma = np.array([config.epipolar_sigma_px] * 2 + [config.transfer_sigma_px] * 2)
    inl = ok
    mode = config.outlier_rejection
    if mode != "none":
        JS, z = feature_innovations(r, J, Sigma, sigma)
    if mode in ("ransac", "both"):
        inl = one_point_ransac(r, J, JS, z, sigma, inl, config.ransac_threshold_sigma)
    if mode in ("mahalanobis", "both"):
        inl = mahalanobis_gate(r, z, inl, config.chi2_threshold)
    w = inl[..., None] / sigma  # whitening, zero for rejected features
    Jw = (J * w[..., None]).reshape(n, -1, 12)
    rw = (r * w).reshape(n, -1)
    A = np.swapaxes(Jw, 1, 2) @ Jw
    beta = (np.swapaxes(Jw, 1, 2) @ rw[..., None])[..., 0]
    X = np.linalg.solve(np.eye(12) + A @ Sigma, np.concatenate([A, beta[..., None]], axis=2))
    dx = (PCt @ X[:, :, 12:])[..., 0]
    P = st.P - PCt @ (X[:, :, :12] @ np.swapaxes(PCt, 1, 2))
    st.P = 0.5 * (P + np.swapaxes(P, 1, 2))
    _inject(st, dx)
    return inl.sum(axis=1), ok.sum(axis=1) - inl.sum(axis=1)


def _kalman_update(st: _State, Hw, rw) -> None:
    """Kalman update from whitened innovations rw (n, M) and Jacobians Hw (n, M, 27), in
    information form: ``P+ = P - P (I + G P)^-1 G P``, ``dx = P (I + G P)^-1 Hw^T rw`` with
    ``G = Hw^T Hw``."""
    Gm = np.swapaxes(Hw, 1, 2) @ Hw
    b = (np.swapaxes(Hw, 1, 2) @ rw[..., None])[..., 0]
    GP = Gm @ st.P
    X = np.linalg.solve(np.eye(27) + GP, np.concatenate([GP, b[..., None]], axis=2))
    dx = (st.P @ X[:, :, 27:])[..., 0]
    P = st.P - st.P @ X[:, :, :27]
    st.P = 0.5 * (P + np.swapaxes(P, 1, 2))
    _inject(st, dx)


def _zero_velocity_update(st: _State, sigma_mps: float) -> None:
    """Pseudo-measurement v = 0 (the images say the car stands still; the trifocal geometry
    has no baseline then and says nothing)."""
    n = st.v.shape[0]
    Hw = np.zeros((n, 3, 27))
    Hw[:, :, 6:9] = np.eye(3) / sigma_mps
    _kalman_update(st, Hw, -st.v / sigma_mps)


def _inject(st: _State, dx) -> None:
    """Add the error-state correction to the nominal state (local rotation errors)."""
    st.p = st.p + dx[:, 0:3]
    st.R = st.R @ so3_exp_fast(dx[:, 3:6])
    st.v = st.v + dx[:, 6:9]
    st.ba = st.ba + dx[:, 9:12]
    st.bg = st.bg + dx[:, 12:15]
    for i, o in enumerate((15, 21)):
        st.cp[i] = st.cp[i] + dx[:, o:o + 3]
        st.cR[i] = st.cR[i] @ so3_exp_fast(dx[:, o + 3:o + 6])


def _check_input(sequence: Sequence, cal: Calibration) -> None:
    n = len(cal)
    shapes = {"fx_px": (n,), "fy_px": (n,), "cx_px": (n,), "cy_px": (n,), "R_cam_imu": (n, 3, 3),
              "p_imu_cam_m": (n, 3), "time_offset_s": (n,)}
    for k, s in shapes.items():
        if getattr(cal, k).shape != s:
            raise FilterError(f"Calibration.{k} has shape {getattr(cal, k).shape}, expected {s}")
    if n == 0:
        raise FilterError("empty batch of calibrations")
    if sequence.n_frames < 3:
        raise FilterError(f"sequence {sequence.name!r} has {sequence.n_frames} frames, need >= 3")


def run(sequence: Sequence, calibrations: Calibration, config: FilterConfig = FilterConfig(),
        prepared: _Prepared | None = None) -> FilterResult:
    """Run one filter per calibration over ``sequence``, all in one vectorised computation.

    sequence: IMU, frame times, ground truth (for the initial state only) and tracks.
    calibrations: batch of n candidate calibrations.
    prepared: output of :func:`prepare` for this (sequence, config), to reuse across calls.
    Returns a :class:`FilterResult` with (n, N, ...) estimates at the frames.
    """
    _check_input(sequence, calibrations)
    prep = prepared if prepared is not None else prepare(sequence, config)
    cal = calibrations
    n, N = len(cal), sequence.n_frames
    td = np.asarray(cal.time_offset_s, float)
    g = np.asarray(sequence.gravity_world_mps2, float)
    pre = prep.pre
    st = _State(sequence, n, config)
    out_p = np.empty((n, N, 3))
    out_R = np.empty((n, N, 3, 3))
    out_v = np.empty((n, N, 3))
    out_sig = np.empty((n, N, 15))
    out_ba = np.empty((n, N, 3))
    out_bg = np.empty((n, N, 3))
    n_upd = np.zeros((n, N), np.int64)
    n_out = np.zeros((n, N), np.int64)
    # A calibration with non-finite values is diverged before it starts; run it on the
    # reference values so the batch arithmetic stays finite.
    frozen = ~np.all(np.isfinite(np.concatenate(
        [np.stack([cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px, cal.time_offset_s], 1),
         cal.R_cam_imu.reshape(n, 9), cal.p_imu_cam_m], axis=1)), axis=1)
    div_at = np.where(frozen, 0, -1)
    if np.any(frozen):
        ref = sequence.reference_calibration.repeat(n)
        cal = Calibration(**{k: np.where(frozen.reshape((n,) + (1,) * (getattr(cal, k).ndim - 1)),
                                         getattr(ref, k), getattr(cal, k))
                             for k in cal.__dataclass_fields__})
        td = np.asarray(cal.time_offset_s, float)
    for k in range(N):
        snap = st.snapshot()
        if k > 0:
            st.R, st.v, st.p, Phi = propagate_preintegrated(st.R, st.v, st.p, st.ba, st.bg, g, pre, k)
            P = st.P.copy()
            P[:, 0:15, :] = Phi @ st.P[:, 0:15, :]
            P[:, :, 0:15] = P[:, :, 0:15] @ np.swapaxes(Phi, 1, 2)
            P[:, 0:15, 0:15] += prep.Qd[k]
            st.P = P
        omega = pre.gyro_frame_radps[k][None, :] - st.bg
        j = prep.triplet_of_frame[k]
        if k >= 2 and prep.stationary[k] and config.zero_velocity_sigma_mps > 0:
            _zero_velocity_update(st, config.zero_velocity_sigma_mps)
        elif k >= 2 and j >= 0:
            n_upd[:, k], n_out[:, k] = _update(st, cal, prep.uv_px[j], prep.valid[j], omega, td, config)
        p_new, R_new, J_new = _shifted_pose(st, omega, td)
        _slide(st, p_new, R_new, J_new)
        bad = ~(np.all(np.isfinite(st.P), axis=(1, 2)) & np.all(np.isfinite(st.R), axis=(1, 2))
                & np.all(np.isfinite(st.p), axis=1) & np.all(np.isfinite(st.v), axis=1))
        diag = np.where(bad[:, None], 0.0, np.diagonal(st.P, axis1=1, axis2=2))
        bad |= diag.max(axis=1) > config.divergence_max_variance
        bad |= np.linalg.norm(np.where(bad[:, None], 0.0, st.v), axis=1) > config.divergence_max_speed_mps
        newly = bad & ~frozen
        div_at[newly] = k
        frozen |= bad
        if np.any(frozen):
            # Frozen filters keep the state of their last good frame (and so their estimates).
            st.restore(snap, frozen)
            n_upd[frozen, k] = 0
            n_out[frozen, k] = 0
        out_p[:, k] = st.p
        out_R[:, k] = st.R
        out_v[:, k] = st.v
        out_sig[:, k] = np.sqrt(np.abs(np.diagonal(st.P, axis1=1, axis2=2)[:, :15]))
        out_ba[:, k] = st.ba
        out_bg[:, k] = st.bg
    return FilterResult(out_p, out_R, out_v, frozen.copy(), div_at, n_upd, n_out, out_sig, out_ba, out_bg,
                        meta={"config": config})
