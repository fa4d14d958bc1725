"""What the filter needs that does not depend on the calibration, built once per sequence:
IMU preintegration, feature selection (bucketing), process noise and the standstill flags.

Equations: docs/model.md, "Prediction" (Eqs. 12-13, 17) and "Standing still" (Eqs. 47-48)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avio.filter.config import FilterConfig, FilterError
from avio.filter.propagation import preintegrate, process_noise
from avio.sequence import Sequence


@dataclass(frozen=True)
class _Prepared:
    """Calibration-independent inputs, built once per (sequence, config)."""

    pre: object  # avio.filter.propagation.Preintegrated
    triplet_of_frame: np.ndarray  # (N,) triplet index ending at the frame, -1 if none
    uv_px: np.ndarray  # (n_trip, F, 3, 2) selected features
    valid: np.ndarray  # (n_trip, F)
    Qd: np.ndarray  # (N, 15, 15)
    stationary: np.ndarray  # (N,) bool, standing still at frame k (IMU and images)
    #: outlier_decisions="reference": the (n_trip, F) features the reference's updates used, made on first use
    imposed: dict = field(default_factory=dict, compare=False, repr=False)



def prepare(sequence: Sequence, config: FilterConfig) -> _Prepared:
    """Everything of the filter that does not depend on the calibration (cache it per sequence)."""
    from avio.tracks import bucket_select, rank_in_groups

    if sequence.tracks is None:
        raise FilterError(f"sequence {sequence.name!r} has no feature tracks; run the front end first")
    tr = sequence.tracks
    imu = sequence.imu
    # Eqs. (12)-(13): the bias-free increments of every frame interval.
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
    # Eq. (48): the image test of standing still (median flow and coherence of the triplet).
    still_images = np.zeros(N, bool)
    has = tr.n_features >= 3
    median_flow = np.nanmedian(np.where(tr.valid[has], flow13[has], np.nan), axis=1)
    median_cosine = np.nanmedian(np.where(tr.valid[has], cosine[has], np.nan), axis=1)
    still_images[tr.frame_index[has]] = ((median_flow < config.stationary_flow_px)
                                         & (median_cosine < config.stationary_max_coherence))
    # Standing still: the image test and the IMU test (Eq. 47).
    stationary = still_images & imu_still(imu, sequence.frame_t_s, sequence.imu_noise, config)
    trip, feat = np.nonzero(tr.valid & (moving >= config.min_feature_flow_px))
    uv3 = tr.uv_px[trip, feat, 2]
    chosen = bucket_select(trip, uv3, config.max_update_features, np.random.default_rng(config.bucket_seed),
                           sequence.image_size_px, config.bucket_grid)
    trip, feat = trip[chosen], feat[chosen]
    F = config.max_update_features
    slot = rank_in_groups(trip)  # trip is sorted (np.nonzero)
    uv = np.zeros((len(tr.frame_index), F, 3, 2))
    valid = np.zeros((len(tr.frame_index), F), bool)
    uv[trip, slot] = tr.uv_px[trip, feat]
    valid[trip, slot] = True
    tof = np.full(N, -1)
    tof[tr.frame_index] = np.arange(len(tr.frame_index))
    nz = sequence.imu_noise
    s = config.imu_noise_scale
    # Eq. (17): the discrete process noise of every interval.
    Qd = np.stack([process_noise(T, s * nz.accel_noise, s * nz.gyro_noise, s * nz.accel_bias_walk,
                                 s * nz.gyro_bias_walk) for T in pre.T_s])
    return _Prepared(pre, tof, uv, valid, Qd, stationary)



def imu_still(imu, frame_t_s: np.ndarray, noise, config: FilterConfig) -> np.ndarray:
    """(N,) bool: at each frame time the IMU over the last ``stationary_imu_window_s`` is still:
    every gyro and accelerometer axis varies by less than ``stationary_imu_variance_ratio``
    times the white-noise variance the filter assumes (``density^2 / dt``; at rest the ratio
    is ~1, braking or turning raises it). Windows with fewer than 5 samples are not still.
    docs/model.md, Eq. 47."""
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
