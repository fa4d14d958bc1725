"""The one sequence model every data source produces and the filter reads.

Frames and directions (docs/model.md, "Conventions", Eq. 1):
- ``world``: gravity-aligned, z up, fixed to the start of the sequence; gravity is
  ``Sequence.gravity_world_mps2`` (normally (0, 0, -9.81)).
- ``imu``: body frame of the IMU (KITTI OXTS: x forward, y left, z up).
- ``cam``: camera frame (x right, y down, z forward).
- ``R_a_b`` maps b-frame vectors into frame a; ``p_a_b`` is the origin of b expressed in a.

All arrays are numpy float64 unless stated; leading axes are named in each docstring.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace

import numpy as np

from avio.calibration import Calibration
from avio.errors import AvioError


class SequenceError(AvioError):
    """A sequence (or a part of it) is malformed; the message names what and where."""


def content_hash(arrays: list[np.ndarray], extra: dict | None = None) -> str:
    """Hex SHA-256 of arrays (dtype, shape, bytes) and a JSON-able dict: a data identity for records."""
    digest = hashlib.sha256(json.dumps(extra or {}, sort_keys=True, default=str).encode())
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise figures (also the filter's process noise).

    accel_noise: accelerometer white noise density, m/s^2/sqrt(Hz).
    gyro_noise: gyroscope white noise density, rad/s/sqrt(Hz).
    accel_bias_walk: accelerometer bias random walk, m/s^3/sqrt(Hz).
    gyro_bias_walk: gyroscope bias random walk, rad/s^2/sqrt(Hz).
    """

    # GTSAM's KITTI figures (kitti00/KittiEquivBiasedImu_metadata.txt), read as densities
    accel_noise: float = 0.01
    gyro_noise: float = 0.000175
    accel_bias_walk: float = 0.000167
    gyro_bias_walk: float = 2.91e-6


@dataclass(frozen=True)
class ImuSamples:
    """IMU measurements on the IMU clock.

    t_s: (m,) strictly increasing sample times, seconds.
    accel_imu_mps2: (m, 3) specific force in the IMU frame, m/s^2
        (``R_world_imu^T (a_world - g_world)`` plus bias and noise).
    gyro_imu_radps: (m, 3) angular rate of the IMU frame, in the IMU frame, rad/s.
    """

    t_s: np.ndarray
    accel_imu_mps2: np.ndarray
    gyro_imu_radps: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.t_s)
        if self.accel_imu_mps2.shape != (m, 3) or self.gyro_imu_radps.shape != (m, 3):
            raise SequenceError(
                f"IMU arrays disagree: {m} times, accel {self.accel_imu_mps2.shape}, "
                f"gyro {self.gyro_imu_radps.shape}"
            )
        if m > 1 and not np.all(np.diff(self.t_s) > 0):
            bad = int(np.argmin(np.diff(self.t_s) > 0)) + 1
            raise SequenceError(f"IMU times are not strictly increasing at sample {bad}")


@dataclass(frozen=True)
class GroundTruth:
    """Ground-truth IMU poses and velocities at the camera frames.

    p_world_imu_m: (N, 3) IMU origin in the world frame, metres.
    R_world_imu: (N, 3, 3) maps IMU-frame vectors into the world frame.
    v_world_imu_mps: (N, 3) IMU velocity in the world frame, m/s.
    """

    p_world_imu_m: np.ndarray
    R_world_imu: np.ndarray
    v_world_imu_mps: np.ndarray


@dataclass(frozen=True)
class TripletTracks:
    """Calibration-independent feature tracks over consecutive frame triplets.

    Triplet j covers frames ``(frame_index[j] - 2, frame_index[j] - 1, frame_index[j])``.
    uv_px: (n_triplets, n_feat_max, 3, 2) pixel coordinates (u right, v down) of each
        feature in the three images, oldest first; padded rows are zero.
    valid: (n_triplets, n_feat_max) bool, False for padding.
    """

    frame_index: np.ndarray
    uv_px: np.ndarray
    valid: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.frame_index)
        if self.uv_px.ndim != 4 or self.uv_px.shape[0] != n or self.uv_px.shape[2:] != (3, 2):
            raise SequenceError(f"uv_px must be (n_triplets, n_feat, 3, 2), got {self.uv_px.shape}")
        if self.valid.shape != self.uv_px.shape[:2]:
            raise SequenceError(f"valid {self.valid.shape} does not match uv_px {self.uv_px.shape}")

    @property
    def n_features(self) -> np.ndarray:
        """(n_triplets,) number of valid features per triplet."""
        return self.valid.sum(axis=1)


@dataclass(frozen=True)
class Sequence:
    """One drive: IMU, camera frame times, truth, camera measurements and calibrations.

    frame_t_s: (N,) camera frame times on the IMU clock, seconds.
    truth: ground truth at the N frames (GPS/INS for real data).
    tracks: feature tracks over frame triplets (None until the front end ran on images).
    image_paths: N grayscale image files, when the source has images.
    image_size_px: (width, height).
    reference_calibration: batch of 1, the calibration a user would start from.
    truth_calibration: batch of 1 when known (simulated camera), else None.
    gravity_world_mps2: (3,) gravity in the world frame.
    imu_noise: the noise figures the filter should assume.
    initial_gyro_bias_radps, initial_accel_bias_mps2: (3,) the filter's initial bias estimates
        (its prior mean) where the source knows them (e.g. a standstill at the start, or a
        ground-truth bias at frame 0, as the initial pose and velocity come from the truth);
        None: zero.
    meta: free-form provenance (source files, seeds, config, content hash).
    """

    name: str
    imu: ImuSamples
    frame_t_s: np.ndarray
    truth: GroundTruth
    reference_calibration: Calibration
    image_size_px: tuple[int, int] = (1241, 376)
    tracks: TripletTracks | None = None
    image_paths: tuple[str, ...] | None = None
    truth_calibration: Calibration | None = None
    gravity_world_mps2: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    initial_gyro_bias_radps: np.ndarray | None = None
    initial_accel_bias_mps2: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.frame_t_s)
        for name in ("p_world_imu_m", "R_world_imu", "v_world_imu_mps"):
            if getattr(self.truth, name).shape[0] != n:
                raise SequenceError(
                    f"sequence {self.name!r}: truth.{name} has {getattr(self.truth, name).shape[0]} "
                    f"rows for {n} frames"
                )
        if n > 1 and not np.all(np.diff(self.frame_t_s) > 0):
            bad = int(np.argmin(np.diff(self.frame_t_s) > 0)) + 1
            raise SequenceError(f"sequence {self.name!r}: frame times not increasing at frame {bad}")

    @property
    def n_frames(self) -> int:
        return len(self.frame_t_s)

    def path_length_m(self) -> float:
        """Length of the ground-truth IMU path, metres."""
        return float(np.linalg.norm(np.diff(self.truth.p_world_imu_m, axis=0), axis=1).sum())

    def with_tracks(self, tracks: TripletTracks) -> "Sequence":
        return replace(self, tracks=tracks)
