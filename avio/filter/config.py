"""The filter's settings (:class:`FilterConfig`), its outputs (:class:`FilterResult`) and its error.

The model the settings parameterise is docs/model.md; units are in the field names."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.special import gammaincinv

from avio.errors import AvioError
from avio.filter.update import M


class FilterError(AvioError):
    """Bad input to the filter (sequence, calibrations or config); the message says what."""



@lru_cache(maxsize=None)
def _chi2_ppf(probability: float, dof: int) -> float:
    # scipy.stats.chi2.ppf's own formula (the same bits), without importing scipy.stats (0.76 s
    # of every job's start)
    return float(2.0 * gammaincinv(0.5 * dof, probability))



OUTLIER_MODES = ("ransac", "mahalanobis", "both", "none")



DECISION_SOURCES = ("own", "reference", "reference_all")
#: where the update takes each feature's Jacobian and noise model (FilterConfig.jacobian_pixels)
JACOBIAN_PIXELS = ("measured", "corrected", "corrected_jacobian")
#: the corrected pixels' longest step, in pixel sigmas (docs/model.md, Eq. 35b): the radius that
#: holds 99.9 % of a correct feature's step (chi-square, 3 dof: sqrt(16.27) = 4.03)
CORRECTION_CAP_SIGMAS = 4.0



@dataclass(frozen=True)
class FilterConfig:
    """Filter settings (units in the names; the equations cited are those of docs/model.md).

    outlier_rejection: "both" (default), "ransac", "mahalanobis" or "none". "both" runs the
        1-point RANSAC and then the chi-square gate on its inliers. Measured with
        ``benchmarks/bench_filter.py outliers`` (truth calibration, seeds 0-4, position RMSE
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
        the calibration, and with them the objective (studies/identifiability/line_scan.py: 5e-4 nats per
        residual where 16 of ~45,000 decisions change); imposed ones do not. The likelihood
        then scores only those candidates (the valid features of avio/objectives.py).
        "reference_all": the same, and the transfer-gain and baseline checks
        (``max_transfer_gain``, ``min_parallax_m``) are the reference's too: an imposed feature
        is used whatever its gain or the predicted baseline under the filter's own calibration
        (its R_f grows with the gain, so its weight fades instead of jumping); only non-finite
        linearisations still drop features per filter. With "reference" those checks stay per
        filter and left jumps of ~4e-4 nats per residual along dx where 15-30 features crossed
        them (studies/identifiability/line_scan.py --along dx).
    rk4_max_step_s: longest RK4 sub-step of the once-per-sequence IMU integration, seconds.
    max_update_features: features per update (16: kitti00 15-796 and the simulated 540 m drive
        gave the same median RMSE with 12 and 16, worse with 10 and 24), chosen by bucketing
        frame k's image into ``bucket_grid`` (rows, cols) cells (avio.tracks.bucket_select,
        seeded with ``bucket_seed``; calibration-independent, so once per sequence).
    pixel_sigma_px: the pixel noise of the tracked points (standard deviation per coordinate);
        the residuals' covariance follows from it (docs/model.md, Eq. 35). 0.7 px is the simulated
        cameras' noise; the first implementation's fixed diag(1, 1, 2, 2) px^2 gave NIS/dof 0.73
        and a position NEES of 2-24 at the truth.
    jacobian_pixels: where each feature's Jacobian J_f and sensitivities G_f (so its R_f) are
        taken: "measured", at the tracked pixels; "corrected", at the first-order estimate of the
        true pixels given the predicted pose (docs/model.md, Eq. 35a). At the measured pixels J_f
        carries the pixel noise that r_f carries, which biases the update's score (errors in
        variables) the same way update after update: with exact IMU data at 1.0 px the clones'
        lateral NEES is 2.50 against ~1 corrected (studies/objective/README.md). The correction's
        step is capped at CORRECTION_CAP_SIGMAS pixel sigmas (Eq. 35b); on a few drives in 50 the
        likelihood is still rough where R_f at the corrected pixels is nearly singular
        (studies/identifiability/README.md), so "measured" stays the default. "corrected_jacobian":
        J_f alone at the corrected pixels, G_f and R_f at the measured ones (Eq. 35c): the score's
        bias goes with J_f, and the likelihood stays as smooth as with the measured pixels.
    max_transfer_gain: a feature whose transferred point moves more than this many pixels per
        pixel of measurement noise (standard deviations) is a degenerate transfer and is not used;
        at the true poses inliers stay below ~10, degenerate ones reach thousands (Eq. 36).
    mahalanobis_probability: chi-square gate of one feature (3 degrees of freedom: the residuals
        the update uses, avio.filter.update.USED_RESIDUALS; docs/model.md, Eq. 39).
    ransac_threshold_sigma: a feature is a RANSAC inlier when each residual is within this many
        measurement standard deviations after the hypothesis' correction (Eq. 38).
    min_parallax_m: no trifocal update when the predicted camera baseline 1-2 or 2-3 is shorter
        (Eq. 36).
    min_feature_flow_px: features moving less than this between consecutive images are not
        used (0: all are used; dropping them did not help).
    stationary_flow_px, stationary_max_coherence, stationary_imu_window_s,
        stationary_imu_variance_ratio (None: the images alone decide), zero_velocity_sigma_mps:
        standing-still detection and its
        pseudo-measurement (docs/model.md, Eqs. 47-49); the flow threshold suits pixel noise up to
        ~0.7 px; the coherence (median cosine between a feature's two frame steps: about -0.5
        for pixel noise at a standstill, 1 when moving) catches slow motion below the noise.
    init_sigma_*: initial standard deviations (m, rad, m/s, m/s^2, rad/s; Eq. 9); the clones start
        with the pose values. The bias ones matter: with 1e-3 rad/s on the gyro bias the
        trifocal updates "learn" a yaw-rate bias that is not there (yaw is unobservable) and
        the heading drifts 1.5-2 deg; 1e-4 rad/s (the order of the sensors' bias) and
        0.02 m/s^2 took the simulated 540 m drive from 3.4 to 2.0 m median RMSE, the 928 m
        one from 8.2 to 2.1 m and kitti00 15-796 from 4.1 to 3.4 m (5 seeds).
    imu_noise_scale: multiplies the sequence's ImuNoise densities (process noise, Eq. 17).
    divergence_max_variance, divergence_max_speed_mps: divergence thresholds (m^2 or (m/s)^2
        or rad^2 on any diagonal entry of the covariance; m/s on the estimated speed; Eq. 51).
    """

    rk4_max_step_s: float = 0.005
    max_update_features: int = 16
    bucket_grid: tuple[int, int] = (4, 8)
    bucket_seed: int = 0
    pixel_sigma_px: float = 0.7
    jacobian_pixels: str = "measured"
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
        """Gate on the squared Mahalanobis distance of one feature's used residuals (3 dof; Eq. 39)."""
        return float(_chi2_ppf(self.mahalanobis_probability, M))

    def __post_init__(self) -> None:
        if self.outlier_rejection not in OUTLIER_MODES:
            raise FilterError(f"FilterConfig.outlier_rejection must be one of {OUTLIER_MODES}, "
                              f"got {self.outlier_rejection!r}")
        if self.outlier_decisions not in DECISION_SOURCES:
            raise FilterError(f"FilterConfig.outlier_decisions must be one of {DECISION_SOURCES}, "
                              f"got {self.outlier_decisions!r}")
        if self.jacobian_pixels not in JACOBIAN_PIXELS:
            raise FilterError(f"FilterConfig.jacobian_pixels must be one of {JACOBIAN_PIXELS}, "
                              f"got {self.jacobian_pixels!r}")
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
    pose_cov (n, N, 12, 12): the covariance ``Sigma = C P C^T`` of the 12 relative-pose errors
        ``[psi12, dt12, psi13, dt13]`` (rad, m; docs/model.md, Eq. 37) of frame k's trifocal update,
        and update_poses (n, N, 3, 4, 3) the IMU poses it linearised about: frames k-2 and k-1
        (the clones, at their exposure times) and k (predicted, at the frame time: Eq. 19's time
        shift is applied after), rows 0-2 R_world_imu and row 3
        p_world_imu (m); only with ``record_used``, zero where no trifocal update ran.
    pose_trace (n, N): the pose's share of each update's S, ``tr(J^T S^-1 J Sigma) = dof - tr(S^-1 R)``
        (docs/model.md, Eq. 55b; the adjusted likelihood's term), zero where no trifocal update ran.
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
    pose_cov: np.ndarray | None = None
    update_poses: np.ndarray | None = None
    pose_trace: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
