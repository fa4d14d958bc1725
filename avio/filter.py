"""The batched sliding-window trifocal VIO: n error-state Kalman filters in lock-step (PAPER.md §2).

One call of :func:`run` runs one filter per candidate calibration over the same IMU and feature
tracks. Every array carries the calibration axis first. The calibration-independent work (IMU
preintegration, feature selection, process noise) is numpy, once per sequence
(:func:`prepare`); the filters themselves run in one compiled numba kernel
(avio/_kernels.py: run_filters) that loops over calibrations and frames: per filter and frame
the work is a few 27x27 products and ~16 features, far too small for numpy's per-call cost
(pure numpy reached ~20 evaluations/s at batch 64, see scripts/bench_filter.py for the kernel's).
The batch is split over threads (:func:`set_threads`: contiguous ranges of calibrations, the
kernel releases the GIL) and each filter is computed by one thread with the same operations as alone, so a
batch gives the same bits as single runs whatever its size and the thread count; no fastmath,
so results are deterministic. The first call of a process with a cold numba cache compiles the
kernel and says so on stderr (:data:`COMPILE_ESTIMATE_S`).

State (nominal): ``p_world_imu`` (m), ``R_world_imu``, ``v_world_imu`` (m/s), accelerometer and
gyro biases ``b_a`` (m/s^2), ``b_g`` (rad/s), and two clones of the camera-exposure IMU pose of
frames k-2 and k-1. Error state, 27: ``[dp, dtheta, dv, db_a, db_g, dp1, dtheta1, dp2, dtheta2]``
with local rotation errors (``R_true = R exp(dtheta)``).

- Initial state: the ground-truth pose and velocity at frame 0, biases from the sequence
  (``Sequence.initial_*_bias``, zero when unknown); the initial covariance is diagonal with the
  ``init_sigma_*`` of :class:`FilterConfig`. The filter
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
  (calibration-independent). Each feature's measurement covariance is derived from the pixel
  noise: ``R_f = pixel_sigma_px^2 G G^T`` with G the residuals' derivative with respect to the six
  measured pixel coordinates (the two Sampson distances share m2 and are correlated; the
  transfer amplifies the noise of m1 and m2 by the geometry), so the filter weights each residual
  by its real uncertainty. That covariance has rank 3 (a point in three images gives three
  constraints): the update uses the 1-2 Sampson distance and the transfer, whose 3x3
  covariance is well conditioned, and not the 2-3 Sampson distance, which to first order is
  their combination (avio._kernels.USED_RESIDUALS). Transfers that amplify the noise more than
  ``max_transfer_gain`` times are degenerate and not used. Outliers rejected per filter (avio/outliers.py); then the
  Kalman update in information form, reduced to the 12 relative-pose errors the measurement
  depends on (avio._kernels.update): a 12x12 solve, never the (4F)x(4F) innovation covariance.
  Each update also yields its innovation statistics (NIS, log det S, the NLL of
  avio/objectives.py), at no extra cost in products.
- Standing still (calibration-free, once per sequence): when both the IMU is still — the
  variances of every gyro and accelerometer axis over the last ``stationary_imu_window_s``
  below ``stationary_imu_variance_ratio`` times the white-noise variance the filter assumes —
  and the median image motion of the triplet's features over two frames is below
  ``stationary_flow_px`` and incoherent (the two frame steps of a feature do not point the
  same way: pixel noise, not motion), a zero-velocity pseudo-measurement (``zero_velocity_sigma_mps``)
  replaces the update. The image test alone fired at 0.3-1.2 m/s while braking and the
  pseudo-measurement then moved the position by metres; braking shows in the accelerometer
  (variance ratio 2-8 on the default drive) long after the image motion is below the noise.
  (Not in the paper; its drives do not stop, the simulated city drive does.)
- Slide: the oldest clone is dropped and the (time-shifted) current pose is cloned.
- Divergence: a filter whose state or covariance is non-finite, whose largest covariance
  diagonal exceeds ``divergence_max_variance`` (default 1e6, i.e. a 1 km standard deviation) or
  whose speed exceeds ``divergence_max_speed_mps`` (100 m/s) is flagged at that frame and frozen:
  its estimates (and biases) stay at the last good frame, its ``sigma`` reports the initial
  standard deviations from then on and its update counts are 0; the others carry on. A
  calibration with non-finite values is flagged at frame 0 and not run. :func:`avio.metrics.position_rmse_objective` turns a divergence into a
  finite penalty.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numba
import numpy as np
from scipy.special import gammaincinv

from avio import _kernels
from avio.imu_propagation import preintegrate, process_noise
from avio.sequence import Calibration, Sequence


class FilterError(ValueError):
    """Bad input to the filter (sequence, calibrations or config); the message says what."""


_THREADS: int | None = None  # set_threads(); None: the default rule


def default_threads() -> int:
    """Threads of the filter when :func:`set_threads` was not called: numba's NUMBA_NUM_THREADS,
    i.e. the machine's cores unless the environment sets it. joblib's loky workers (the Hydra
    joblib launcher) get ``NUMBA_NUM_THREADS = cores // n_jobs`` from joblib, so two workers on
    two cores run one thread each and do not oversubscribe; at most ``os.cpu_count()``."""
    return max(1, min(int(numba.config.NUMBA_NUM_THREADS), os.cpu_count() or 1))


def set_threads(n: int | None = None) -> int:
    """Threads :func:`run` splits a batch over (contiguous ranges of calibrations, each filter on
    one thread, so results do not depend on it); None restores :func:`default_threads`. Rule
    for launchers running several filter processes on one machine:
    ``threads = max(1, cores // processes)``. At most ``os.cpu_count()``; returns the count in
    effect."""
    global _THREADS
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
        raise FilterError(f"set_threads: n must be an integer >= 1 or None, got {n!r}")
    _THREADS = None if n is None else min(int(n), os.cpu_count() or 1)
    return threads()


def threads() -> int:
    """The filter kernel's thread count now (:func:`set_threads`)."""
    return _THREADS if _THREADS is not None else default_threads()


#: Measured first-run compile time of the kernel on the 2-core development machine, seconds
#: (scripts/bench_filter.py speed prints it), quoted in the message before a cold compile.
COMPILE_ESTIMATE_S = 40
_HEARTBEAT_S = 5.0  # seconds between the "still compiling" lines (issue 13: no silent phase over 10 s)
_kernel_loaded = False


def _kernel_cached() -> bool | None:
    """Whether numba's cache holds the filter kernel for the current source (None: unknown)."""
    try:
        return bool(_kernels.run_filters._cache._cache_file._load_index())
    except AttributeError:  # numba's private cache API changed: cannot tell
        return None


@contextmanager
def _announce_compile():
    """Say so on stderr when the first kernel call of the process will compile it (a cold
    numba cache), print a heartbeat every 5 s while it does and how long it took."""
    global _kernel_loaded
    cached = False if _kernel_loaded else _kernel_cached()
    if _kernel_loaded or cached:
        _kernel_loaded = True
        yield
        return
    if cached is None:  # cannot tell: say something only if the call turns out to be long
        t0 = time.perf_counter()
        yield
        _kernel_loaded = True
        if time.perf_counter() - t0 > 5.0:
            print(f"compiled or loaded the VIO filter in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return
    where = numba.config.CACHE_DIR or os.path.join(os.path.dirname(_kernels.__file__), "__pycache__")
    print(f"compiling the VIO filter (first run only, ~{COMPILE_ESTIMATE_S} s; cached in {where})",
          file=sys.stderr, flush=True)
    done = threading.Event()
    t0 = time.perf_counter()

    def heartbeat():
        while not done.wait(_HEARTBEAT_S):
            print(f"  still compiling the VIO filter ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)

    beat = threading.Thread(target=heartbeat, name="avio-compile-heartbeat", daemon=True)
    beat.start()
    try:
        yield
    finally:
        done.set()
        beat.join()
    _kernel_loaded = True
    print(f"compiled the VIO filter in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


@lru_cache(maxsize=None)
def _chi2_ppf(probability: float, dof: int) -> float:
    # scipy.stats.chi2.ppf's own formula (the same bits), without importing scipy.stats (0.76 s
    # of every job's start)
    return float(2.0 * gammaincinv(0.5 * dof, probability))


OUTLIER_MODES = ("ransac", "mahalanobis", "both", "none")
DECISION_SOURCES = ("own", "reference", "reference_all")


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
    outlier_decisions: "own" (default): every filter's updates decide by its own
        ``outlier_rejection``; "reference": the features the updates of a filter at the
        sequence's reference calibration used (once per sequence and config, cached with
        :func:`prepare`'s inputs) are the only candidates of every filter, which then rejects
        nothing itself (features it cannot linearise still drop out). Own decisions jump with
        the calibration, and with them the objective (scripts/line_scan.py: 5e-4 nats per
        residual where 16 of ~45,000 decisions change); imposed ones do not. The likelihood
        then scores only those candidates (the valid features of avio/objectives.py).
        "reference_all": the same, and the transfer-gain and baseline checks
        (``max_transfer_gain``, ``min_parallax_m``) are the reference's too: an imposed feature
        is used whatever its gain or the predicted baseline under the filter's own calibration
        (its R_f grows with the gain, so its weight fades instead of jumping); only non-finite
        linearisations still drop features per filter. With "reference" those checks stay per
        filter and left jumps of ~4e-4 nats per residual along dx where 15-30 features crossed
        them (scripts/line_scan.py --along dx).
    rk4_max_step_s: longest RK4 sub-step of the once-per-sequence IMU integration, seconds.
    max_update_features: features per update (16: kitti00 15-796 and the simulated 540 m drive
        gave the same median RMSE with 12 and 16, worse with 10 and 24), chosen by bucketing
        frame k's image into ``bucket_grid`` (rows, cols) cells (avio.tracks.bucket_select,
        seeded with ``bucket_seed``; calibration-independent, so once per sequence).
    pixel_sigma_px: the pixel noise of the tracked points (standard deviation per coordinate);
        the residuals' covariance follows from it (module docstring). 0.7 px is the simulated
        cameras' noise; the first implementation's fixed diag(1, 1, 2, 2) px^2 gave NIS/dof 0.73
        and a position NEES of 2-24 at the truth.
    max_transfer_gain: a feature whose transferred point moves more than this many pixels per
        pixel of measurement noise (standard deviations) is a degenerate transfer and is not used;
        at the true poses inliers stay below ~10, degenerate ones reach thousands.
    mahalanobis_probability: chi-square gate of one feature (3 degrees of freedom: the residuals
        the update uses, avio._kernels.USED_RESIDUALS).
    ransac_threshold_sigma: a feature is a RANSAC inlier when each residual is within this many
        measurement standard deviations after the hypothesis' correction.
    min_parallax_m: no trifocal update when the predicted camera baseline 1-2 or 2-3 is shorter.
    min_feature_flow_px: features moving less than this between consecutive images are not
        used (0: all are used; dropping them did not help).
    stationary_flow_px, stationary_max_coherence, stationary_imu_window_s,
        stationary_imu_variance_ratio (None: the images alone decide), zero_velocity_sigma_mps:
        standing-still detection and its
        pseudo-measurement (module docstring); the flow threshold suits pixel noise up to
        ~0.7 px; the coherence (median cosine between a feature's two frame steps: about -0.5
        for pixel noise at a standstill, 1 when moving) catches slow motion below the noise.
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
    pixel_sigma_px: float = 0.7
    max_transfer_gain: float = 50.0
    outlier_rejection: str = "both"
    outlier_decisions: str = "own"
    mahalanobis_probability: float = 0.99
    ransac_threshold_sigma: float = 3.0
    min_parallax_m: float = 0.05
    min_feature_flow_px: float = 0.0
    stationary_flow_px: float = 1.5
    stationary_max_coherence: float = 0.25
    stationary_imu_window_s: float = 1.0
    stationary_imu_variance_ratio: float | None = 1.5
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
        """Gate on the squared Mahalanobis distance of one feature's used residuals (3 dof)."""
        return float(_chi2_ppf(self.mahalanobis_probability, _kernels.M))

    def __post_init__(self) -> None:
        if self.outlier_rejection not in OUTLIER_MODES:
            raise FilterError(f"FilterConfig.outlier_rejection must be one of {OUTLIER_MODES}, "
                              f"got {self.outlier_rejection!r}")
        if self.outlier_decisions not in DECISION_SOURCES:
            raise FilterError(f"FilterConfig.outlier_decisions must be one of {DECISION_SOURCES}, "
                              f"got {self.outlier_decisions!r}")
        if self.max_update_features < 1 or self.rk4_max_step_s <= 0:
            raise FilterError("FilterConfig: max_update_features >= 1 and rk4_max_step_s > 0 required")
        for name in ("pixel_sigma_px", "max_transfer_gain", "zero_velocity_sigma_mps", "stationary_imu_window_s",
                     "stationary_imu_variance_ratio", "divergence_max_variance", "divergence_max_speed_mps",
                     "imu_noise_scale"):
            value = getattr(self, name)
            if value is None and name == "stationary_imu_variance_ratio":
                continue  # standstill from the images alone
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise FilterError(f"FilterConfig.{name} = {value!r}: must be a finite number > 0")


@dataclass(frozen=True)
class FilterResult:
    """Estimates of n filters at the N frames (IMU pose at the frame time, world frame).

    p_world_imu_m (n, N, 3), R_world_imu (n, N, 3, 3), v_world_imu_mps (n, N, 3).
    diverged (n,) bool; diverged_at_frame (n,) int, -1 when the filter did not diverge.
    n_updates (n, N) features used in each frame's update; n_outliers (n, N) rejected ones.
    sigma (n, N, 15): the filter's own standard deviations of ``[p, theta, v, b_a, b_g]``
        (square roots of the core covariance diagonal; m, rad, m/s, m/s^2, rad/s) at each frame.
    b_a_mps2, b_g_radps (n, N, 3): bias estimates.
    nis, log_det_S (n, N): the normalised innovation squared and log det of the innovation
        covariance of each frame's trifocal update; dof (n, N) its residual count; nll (n, N) its
        contribution to the innovation NLL and nll_slots (n, N) the residual slots it covers
        (avio/objectives.py); zero where no trifocal update ran.
    used (n, n_triplets, F) bool: the features each triplet's update used (only when run with
        ``record_used``; False where no update ran).
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
    nis: np.ndarray | None = None
    log_det_S: np.ndarray | None = None
    dof: np.ndarray | None = None
    nll: np.ndarray | None = None
    nll_slots: np.ndarray | None = None
    used: np.ndarray | None = None
    meta: dict = field(default_factory=dict)


@dataclass(frozen=True)
class _Prepared:
    """Calibration-independent inputs, built once per (sequence, config)."""

    pre: object  # avio.imu_propagation.Preintegrated
    triplet_of_frame: np.ndarray  # (N,) triplet index ending at the frame, -1 if none
    uv_px: np.ndarray  # (n_trip, F, 3, 2) selected features
    valid: np.ndarray  # (n_trip, F)
    Qd: np.ndarray  # (N, 15, 15)
    stationary: np.ndarray  # (N,) bool, standing still at frame k (IMU and images)
    #: outlier_decisions="reference": the (n_trip, F) features the reference's updates used, made on first use
    imposed: dict = field(default_factory=dict, compare=False, repr=False)


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
    # Two frame steps of a feature: at a standstill they are pixel noise (anti-correlated
    # through the shared middle image), while moving they point the same way, however small.
    steps = np.diff(tr.uv_px, axis=2)  # (n_trip, F, 2, 2)
    cosine = np.sum(steps[:, :, 0] * steps[:, :, 1], axis=-1) / np.maximum(
        np.linalg.norm(steps[:, :, 0], axis=-1) * np.linalg.norm(steps[:, :, 1], axis=-1), 1e-12)
    still_images = np.zeros(N, bool)
    has = tr.n_features >= 3
    median_flow = np.nanmedian(np.where(tr.valid[has], flow13[has], np.nan), axis=1)
    median_cosine = np.nanmedian(np.where(tr.valid[has], cosine[has], np.nan), axis=1)
    still_images[tr.frame_index[has]] = ((median_flow < config.stationary_flow_px)
                                         & (median_cosine < config.stationary_max_coherence))
    stationary = still_images & imu_still(imu, sequence.frame_t_s, sequence.imu_noise, config)
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


def imu_still(imu, frame_t_s: np.ndarray, noise, config: FilterConfig) -> np.ndarray:
    """(N,) bool: at each frame time the IMU over the last ``stationary_imu_window_s`` is still:
    every gyro and accelerometer axis varies by less than ``stationary_imu_variance_ratio``
    times the white-noise variance the filter assumes (``density^2 / dt``; at rest the ratio
    is ~1, braking or turning raises it). Windows with fewer than 5 samples are not still."""
    dt = float(np.median(np.diff(imu.t_s)))
    s = config.imu_noise_scale
    var0 = np.r_[[(s * noise.gyro_noise) ** 2 / dt] * 3, [(s * noise.accel_noise) ** 2 / dt] * 3]
    x = np.concatenate([imu.gyro_imu_radps, imu.accel_imu_mps2], axis=1)
    x = x - x.mean(axis=0)  # conditions the running sums
    c1 = np.concatenate([np.zeros((1, 6)), np.cumsum(x, axis=0)])
    c2 = np.concatenate([np.zeros((1, 6)), np.cumsum(x * x, axis=0)])
    i1 = np.searchsorted(imu.t_s, frame_t_s, side="right")
    i0 = np.searchsorted(imu.t_s, frame_t_s - config.stationary_imu_window_s, side="left")
    count = (i1 - i0)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (c1[i1] - c1[i0]) / count
        var = (c2[i1] - c2[i0]) / count - mean**2
    if config.stationary_imu_variance_ratio is None:  # a rig whose IMU shakes at rest (rotors): images only
        return np.ones(len(frame_t_s), bool)
    return (count[:, 0] >= 5) & np.all(var < config.stationary_imu_variance_ratio * var0, axis=1)


class _State:
    """Initial nominal states and covariances of n filters: truth pose and velocity of frame 0,
    biases zero, clones at the origin (they are set by the first slides), ``P0`` diagonal."""

    def __init__(self, sequence: Sequence, n: int, config: FilterConfig):
        tr = sequence.truth
        self.R = np.repeat(tr.R_world_imu[:1], n, axis=0).astype(float)
        self.p = np.repeat(tr.p_world_imu_m[:1], n, axis=0).astype(float)
        self.v = np.repeat(tr.v_world_imu_mps[:1], n, axis=0).astype(float)
        self.ba = np.repeat(_bias(sequence.initial_accel_bias_mps2)[None], n, axis=0)
        self.bg = np.repeat(_bias(sequence.initial_gyro_bias_radps)[None], n, axis=0)
        self.cp = np.zeros((2, n, 3))  # clones (k-2, k-1): exposure-time IMU positions
        self.cR = np.repeat(np.eye(3)[None, None], 2, 0).repeat(n, 1)
        c = config
        d = np.r_[[c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3, [c.init_sigma_v_mps] * 3,
                  [c.init_sigma_ba_mps2] * 3, [c.init_sigma_bg_radps] * 3, [c.init_sigma_p_m] * 3,
                  [c.init_sigma_theta_rad] * 3, [c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3]
        self.P0 = np.diag(d**2)
        self.P = np.repeat(self.P0[None], n, axis=0)

def _bias(value) -> np.ndarray:
    return np.zeros(3) if value is None else np.asarray(value, float).reshape(3)


def measurement_model(st: "_State", cal: Calibration, uv_px, omega, td):
    """Innovations r (n, F, 4) pixels, their Jacobian J (n, F, 4, 12) w.r.t. the relative-pose
    errors of the triplet and the map C (n, 12, 27) from the error state to those, so that the
    measurement Jacobian is ``H = J C`` (``dr = -H dx``); also t12, t13 (n, 3).

    What the update runs per filter (avio._kernels.measure): state error -> exposure-time IMU
    poses of images 1, 2, 3 (clones, shifted current pose) -> camera pose errors ->
    relative-pose errors -> residuals (avio/measurement.py).
    """
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return _kernels.measure_all(st.R, st.p, st.v, st.cp, st.cR, _f64(omega), _f64(td), *_cal_arrays(cal),
                                    _f64(uv_px))


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _cal_arrays(cal: Calibration) -> tuple:
    return tuple(_f64(getattr(cal, k)) for k in ("fx_px", "fy_px", "cx_px", "cy_px", "R_cam_imu", "p_imu_cam_m"))


_MODES = {"none": _kernels.MODE_NONE, "ransac": _kernels.MODE_RANSAC, "mahalanobis": _kernels.MODE_GATE,
          "both": _kernels.MODE_BOTH}


def _inject(st: _State, dx) -> None:
    """Add the error-state correction dx (n, 27) to the nominal states (local rotation errors)."""
    _kernels.inject_all(st.R, st.p, st.v, st.ba, st.bg, st.cp, st.cR, _f64(dx))


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


def _imposed(sequence: Sequence, config: FilterConfig, prep: _Prepared) -> tuple[_Prepared, FilterConfig]:
    """outlier_decisions="reference": the inputs with only the features the reference's own
    updates used as candidates, and a config that rejects nothing itself (FilterConfig)."""
    if "valid" not in prep.imposed:
        if sequence.reference_calibration is None:
            raise FilterError(f"outlier_decisions={config.outlier_decisions!r}: sequence {sequence.name!r} has no "
                              "reference calibration")
        own = replace(config, outlier_decisions="own")
        ref = run(sequence, sequence.reference_calibration, own, prepared=prep, record_used=True)
        if ref.diverged[0]:  # its decisions would end there, and every filter's updates with them
            raise FilterError(f"outlier_decisions={config.outlier_decisions!r}: the filter at the reference "
                              f"calibration diverges on {sequence.name!r} at frame {int(ref.diverged_at_frame[0])}")
        prep.imposed["valid"] = prep.valid & ref.used[0]
    return replace(prep, valid=prep.imposed["valid"]), replace(config, outlier_rejection="none")


def run(sequence: Sequence, calibrations: Calibration, config: FilterConfig = FilterConfig(),
        prepared: _Prepared | None = None, record_used: bool = False) -> FilterResult:
    """Run one filter per calibration over ``sequence``, all in one compiled kernel call.

    sequence: IMU, frame times, ground truth (for the initial state only) and tracks.
    calibrations: batch of n candidate calibrations.
    prepared: output of :func:`prepare` for this (sequence, config), to reuse across calls.
    record_used: also return which features each update used (FilterResult.used).
    Returns a :class:`FilterResult` with (n, N, ...) estimates at the frames.
    """
    _check_input(sequence, calibrations)
    prep = prepared if prepared is not None else prepare(sequence, config)
    result_config = config
    # reference_all: the imposed features are used whatever their transfer gain and baseline
    # here (the reference judged both; R_f grows with the gain, so they fade, not jump).
    everything = config.outlier_decisions == "reference_all"
    gain_limit = np.inf if everything else float(config.max_transfer_gain)
    min_parallax_m = 0.0 if everything else config.min_parallax_m
    if config.outlier_decisions != "own":  # imposed from the reference
        prep, config = _imposed(sequence, config, prep)
    cal = calibrations
    n, N = len(cal), sequence.n_frames
    c = config
    pre = prep.pre
    st = _State(sequence, 1, c)
    out_p, out_R, out_v = np.empty((n, N, 3)), np.empty((n, N, 3, 3)), np.empty((n, N, 3))
    out_sig, out_ba, out_bg = np.empty((n, N, 15)), np.empty((n, N, 3)), np.empty((n, N, 3))
    n_upd, n_out, div_at = np.zeros((n, N), np.int64), np.zeros((n, N), np.int64), np.empty(n, np.int64)
    # A calibration with non-finite values is diverged before it starts (frame 0).
    frozen = ~np.all(np.isfinite(np.concatenate(
        [np.stack([cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px, cal.time_offset_s], 1),
         cal.R_cam_imu.reshape(n, 9), cal.p_imu_cam_m], axis=1)), axis=1)
    out_nis, out_ldS, out_nll = np.empty((n, N)), np.empty((n, N)), np.empty((n, N))
    out_dof, out_slots = np.empty((n, N), np.int64), np.empty((n, N), np.int64)
    out_used = np.zeros((n if record_used else 0, *prep.valid.shape), np.uint8)
    args = (st.R[0], st.p[0], st.v[0], st.P0, st.ba[0], st.bg[0], _f64(sequence.gravity_world_mps2), pre.dR, pre.dv,
            pre.dp, pre.S, pre.SS,
            pre.Vbg, pre.Pbg, _f64(pre.T_s), _f64(pre.gyro_frame_radps), prep.Qd, prep.triplet_of_frame, prep.uv_px,
            prep.valid, prep.stationary, *_cal_arrays(cal), _f64(cal.time_offset_s), frozen, float(c.pixel_sigma_px),
            gain_limit, min_parallax_m, _MODES[c.outlier_rejection], c.ransac_threshold_sigma,
            c.chi2_threshold, c.zero_velocity_sigma_mps, c.divergence_max_variance, c.divergence_max_speed_mps,
            out_p, out_R, out_v, out_sig, out_ba, out_bg, n_upd, n_out, div_at, out_nis, out_ldS, out_dof, out_nll,
            out_slots, out_used)
    # The kernel releases the GIL: the filters of the batch run on threads at once, each filter
    # on one thread (numba prange was tried: +41 s, +31 %, on the first compile). One task per
    # filter, taken as threads come free, since filters that diverge early stop early: on a
    # default job's batches four ranges per thread idled a thread for ~10 % of the time
    # (`python scripts/bench_filter.py schedule`); a kernel call costs ~12 us against ~12 ms.
    n_threads = min(threads(), n)
    # Degenerate geometry of a wild candidate gives non-finite intermediate values, which the
    # kernel tests for and drops; the floating-point warnings carry no information.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"), _announce_compile():
        if n_threads == 1:
            _kernels.run_filters(0, n, *args)
        else:
            with ThreadPoolExecutor(n_threads, thread_name_prefix="avio-filter") as pool:
                jobs = [pool.submit(_kernels.run_filters, i, i + 1, *args) for i in range(n)]
                for job in jobs:
                    job.result()
    return FilterResult(out_p, out_R, out_v, div_at >= 0, div_at, n_upd, n_out, out_sig, out_ba, out_bg,
                        out_nis, out_ldS, out_dof, out_nll, out_slots, used=out_used.astype(bool) if record_used else None,
                        meta={"config": result_config})
