"""A simulated camera: street-like landmarks along a path and their pinhole projections.

Camera pose of a frame = IMU pose composed with the extrinsics (docs/model.md, Eq. 20):
``R_world_cam = R_world_imu R_cam_imu^T``, ``p_world_cam = p_world_imu + R_world_imu p_imu_cam``;
a world point X projects to ``u = fx x/z + cx, v = fy y/z + cy`` with
``(x, y, z) = R_world_cam^T (X - p_world_cam)`` (docs/model.md, Eq. 5). The camera of a frame
stamped t sees the world at IMU time ``t + time_offset_s``. Works with any truth (the simulator's exact
TrajectoryFn, or a GroundTruth at the frames such as KITTI's), and knows nothing of the
simulator's internals.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation, RotationSpline

from avio.calibration import Calibration
from avio.errors import AvioError
from avio.geometry import so3_exp, so3_log
from avio.sequence import GroundTruth, TripletTracks
from avio.sim.trajectory import TrajectoryFn
from avio.tracks import triplets_from_observations

IMU_HEIGHT_M = 0.93  # KITTI OXTS unit above the road (KITTI sensor setup drawing)


class CameraSimError(AvioError):
    """Bad input to the camera simulation; the message names the argument and what is wrong."""


@dataclass(frozen=True)
class Observations:
    """Noiseless projections of landmarks into frames, one row per (frame, landmark) seen.

    frame_index: (m,) int. landmark_id: (m,) int row of ``landmarks_world``.
    uv_px: (m, 2) pixels (u right, v down). depth_m: (m,) z in the camera frame, metres.
    """

    frame_index: np.ndarray
    landmark_id: np.ndarray
    uv_px: np.ndarray
    depth_m: np.ndarray


def interpolate_pose(truth: GroundTruth, frame_t_s: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IMU pose at times t_s (m,) from a truth sampled at frame_t_s (N,).

    Position: cubic Hermite through the frame positions and velocities (extrapolated past the
    ends). Rotation: scipy's C2 RotationSpline inside [frame_t_s[0], frame_t_s[-1]]; outside,
    extrapolated geodesically with the end pair's rate.
    Returns (R_world_imu (m, 3, 3), p_world_imu_m (m, 3)).
    """
    frame_t_s = np.asarray(frame_t_s, float)
    t_s = np.asarray(t_s, float)
    if len(frame_t_s) < 2:
        raise CameraSimError(f"avio.sim.camera: interpolating a truth needs >= 2 frames, got {len(frame_t_s)}")
    hermite = CubicHermiteSpline(frame_t_s, truth.p_world_imu_m, truth.v_world_imu_mps, axis=0, extrapolate=True)
    R = RotationSpline(frame_t_s, Rotation.from_matrix(truth.R_world_imu))(
        np.clip(t_s, frame_t_s[0], frame_t_s[-1])
    ).as_matrix()
    outside = (t_s < frame_t_s[0]) | (t_s > frame_t_s[-1])
    if np.any(outside):
        i = np.where(t_s[outside] < frame_t_s[0], 0, len(frame_t_s) - 2)
        alpha = (t_s[outside] - frame_t_s[i]) / (frame_t_s[i + 1] - frame_t_s[i])
        R0 = truth.R_world_imu[i]
        rel = so3_log(np.swapaxes(R0, -1, -2) @ truth.R_world_imu[i + 1])
        R[outside] = R0 @ so3_exp(alpha[:, None] * rel)
    return R, hermite(t_s)


def camera_poses(
    truth: GroundTruth | TrajectoryFn, frame_t_s: np.ndarray, calibration: Calibration
) -> tuple[np.ndarray, np.ndarray]:
    """(R_world_cam (N, 3, 3), p_world_cam_m (N, 3)) of each frame's exposure.

    truth: a TrajectoryFn (evaluated exactly at ``frame_t_s + time_offset_s``) or a GroundTruth
    at ``frame_t_s`` (interpolated when the calibration's time offset is not zero).
    calibration: batch of 1.
    """
    if len(calibration) != 1:
        raise CameraSimError(f"avio.sim.camera: calibration must be a batch of 1, got {len(calibration)}")
    frame_t_s = np.asarray(frame_t_s, float)
    offset = float(calibration.time_offset_s[0])
    if isinstance(truth, TrajectoryFn):
        st = truth(frame_t_s + offset)
        R_world_imu, p_world_imu = st.R_world_imu, st.p_world_imu_m
    elif offset == 0.0:
        R_world_imu, p_world_imu = truth.R_world_imu, truth.p_world_imu_m
        if len(R_world_imu) != len(frame_t_s):
            raise CameraSimError(
                f"avio.sim.camera: truth has {len(R_world_imu)} poses for {len(frame_t_s)} frame times"
            )
    else:
        R_world_imu, p_world_imu = interpolate_pose(truth, frame_t_s, frame_t_s + offset)
    R_cam_imu, p_imu_cam = calibration.R_cam_imu[0], calibration.p_imu_cam_m[0]
    return R_world_imu @ R_cam_imu.T, p_world_imu + R_world_imu @ p_imu_cam


def project_landmarks(
    truth: GroundTruth | TrajectoryFn,
    frame_t_s: np.ndarray,
    calibration: Calibration,
    landmarks_world: np.ndarray,
    image_size_px: tuple[int, int],
    min_depth_m: float = 1.0,
    max_depth_m: float = np.inf,
    frames_per_chunk: int = 64,
) -> Observations:
    """Every landmark (n_lm, 3) in front of the camera (min_depth_m < z <= max_depth_m) and inside
    the image (0 <= u <= width-1, 0 <= v <= height-1) of each frame; noiseless.

    Frames are processed in chunks (a (chunk, n_lm, 3) array each) to bound memory.
    """
    landmarks_world = np.asarray(landmarks_world, float)
    if landmarks_world.ndim != 2 or landmarks_world.shape[1] != 3:
        raise CameraSimError(f"avio.sim.camera: landmarks_world must be (n_lm, 3), got {landmarks_world.shape}")
    R_world_cam, p_world_cam = camera_poses(truth, frame_t_s, calibration)
    fx, fy = calibration.fx_px[0], calibration.fy_px[0]
    cx, cy = calibration.cx_px[0], calibration.cy_px[0]
    width, height = image_size_px
    parts = []
    for start in range(0, len(R_world_cam), frames_per_chunk):  # chunks bound memory; each is vectorised
        R = R_world_cam[start : start + frames_per_chunk]
        d = landmarks_world[None, :, :] - p_world_cam[start : start + frames_per_chunk, None, :]
        x_cam = d @ R  # rows of R_world_cam^T (X - p); matmul is much faster than einsum here
        z = x_cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = fx * x_cam[..., 0] / z + cx
            v = fy * x_cam[..., 1] / z + cy
        seen = (z > min_depth_m) & (z <= max_depth_m) & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
        f, lm = np.nonzero(seen)
        parts.append((f + start, lm, np.stack([u[f, lm], v[f, lm]], axis=1), z[f, lm]))
    if not parts:
        return Observations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0))
    return Observations(*(np.concatenate(p) for p in zip(*parts)))


def _path_arclength(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Path points with repeated positions (stops) removed, and their arc length (metres)."""
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    keep = np.r_[True, step > 1e-6]
    p = p[keep]
    return p, np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]


def make_landmarks(
    truth: GroundTruth,
    rng: np.random.Generator,
    points_per_m: float = 4.0,
    near_lateral_m: tuple[float, float] = (5.0, 20.0),
    far_lateral_m: tuple[float, float] = (20.0, 60.0),
    near_height_m: tuple[float, float] = (0.0, 10.0),
    far_height_m: tuple[float, float] = (0.0, 25.0),
    far_fraction: float = 0.3,
    ground_fraction: float = 0.15,
    imu_height_m: float = IMU_HEIGHT_M,
    extend_m: float = 80.0,
    clearance_m: float = 4.0,
) -> np.ndarray:
    """(n_lm, 3) world points lining the path like a street, in arc-length order.

    Along the path (the truth positions, extended ``extend_m`` past the end along the last
    heading so the last frames see ahead), ``points_per_m`` points per metre on random sides:
    facades at ``near_lateral_m`` from the path, ``near_height_m`` above the road; a
    ``far_fraction`` of far buildings at ``far_lateral_m``, ``far_height_m``; a ``ground_fraction``
    on the road surface at ``near_lateral_m``. Heights are above the road, ``imu_height_m`` below
    the IMU; world z is up. Points closer than ``clearance_m`` (horizontally) to the driven path
    are dropped, so the car never drives through one.
    """
    p, s = _path_arclength(np.asarray(truth.p_world_imu_m, float))
    if len(p) < 2:
        raise CameraSimError("avio.sim.camera: make_landmarks needs a truth path that moves")
    heading = p[-1] - p[-2]
    extension = p[-1] + np.outer(np.arange(1.0, extend_m + 1.0), heading / np.linalg.norm(heading))
    p = np.vstack([p, extension])
    s = np.r_[s, s[-1] + np.arange(1.0, extend_m + 1.0)]
    n = int(round(points_per_m * s[-1]))
    s_lm = np.sort(rng.uniform(0.0, s[-1], n))
    base = np.stack([np.interp(s_lm, s, p[:, i]) for i in range(3)], axis=1)
    # Horizontal left direction of the path at each landmark (finite difference over +-1 m).
    ahead = np.stack([np.interp(s_lm + 1.0, s, p[:, i]) - np.interp(s_lm - 1.0, s, p[:, i]) for i in range(2)], 1)
    ahead /= np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-9)
    left = np.stack([-ahead[:, 1], ahead[:, 0]], axis=1)
    kind = rng.choice(3, size=n, p=[1.0 - far_fraction - ground_fraction, far_fraction, ground_fraction])
    lateral = np.where(kind == 1, rng.uniform(*far_lateral_m, n), rng.uniform(*near_lateral_m, n))
    height = np.where(kind == 1, rng.uniform(*far_height_m, n), rng.uniform(*near_height_m, n))
    height = np.where(kind == 2, 0.0, height)
    side = rng.choice([-1.0, 1.0], size=n)
    points = base.copy()
    points[:, :2] += (side * lateral)[:, None] * left
    points[:, 2] += height - imu_height_m
    clear = cKDTree(p[:, :2]).query(points[:, :2])[0] >= clearance_m
    return points[clear]


def corrupt_triplets(
    tracks: TripletTracks, outlier_fraction: float, rng: np.random.Generator,
    jump_px: tuple[float, float] = (20.0, 60.0),
) -> tuple[TripletTracks, np.ndarray]:
    """Turn a fraction of the valid features of every triplet into wrong matches.

    Each valid feature is an outlier with probability ``outlier_fraction``; an outlier's pixel in
    one of its three images (chosen at random) jumps by ``jump_px`` pixels in a random direction.
    Returns the corrupted tracks and the (n_triplets, n_feat) outlier mask.
    """
    if not 0.0 <= outlier_fraction <= 1.0:
        raise CameraSimError(f"avio.sim.camera: outlier_fraction must be in [0, 1], got {outlier_fraction}")
    shape = tracks.valid.shape
    outlier = tracks.valid & (rng.random(shape) < outlier_fraction)
    image = rng.integers(0, 3, shape)
    angle = rng.uniform(0.0, 2 * np.pi, shape)
    size = rng.uniform(*jump_px, shape)
    jump = np.zeros(tracks.uv_px.shape)
    t_idx, f_idx = np.nonzero(outlier)
    jump[t_idx, f_idx, image[t_idx, f_idx]] = (size[..., None] * np.stack([np.cos(angle), np.sin(angle)], -1))[
        t_idx, f_idx
    ]
    return replace(tracks, uv_px=tracks.uv_px + jump), outlier


def simulate_tracks(
    truth: GroundTruth | TrajectoryFn,
    frame_t_s: np.ndarray,
    calibration: Calibration,
    landmarks_world: np.ndarray,
    image_size_px: tuple[int, int],
    pixel_noise_px: float,
    outlier_fraction: float,
    max_features: int | None,
    rng: np.random.Generator,
    *,
    min_depth_m: float = 1.0,
    max_depth_m: float = 80.0,
    return_details: bool = False,
    noise_per_triplet: bool = False,
):
    """Triplet tracks a camera with ``calibration`` (batch of 1) would see of the landmarks.

    Projections (see project_landmarks) get Gaussian noise of ``pixel_noise_px`` (per
    observation, so a feature is consistent across the triplets sharing it; with
    ``noise_per_triplet`` instead drawn afresh for every triplet's three images, so that the
    updates' measurements are independent, as the filter assumes: a diagnostic, not a camera —
    the triplets are then chosen on the noiseless pixels); a track is a
    landmark; triplets are chosen by bucketing (``max_features`` per triplet, avio.tracks) and
    then ``outlier_fraction`` of the chosen features become wrong matches (corrupt_triplets).
    Returns TripletTracks; with ``return_details`` also a dict with the noiseless ``uv_true_px``
    (n_triplets, n_feat, 3, 2), ``landmark_id`` (n_triplets, n_feat; -1 padding), ``outlier``
    mask and the ``observations``.
    """
    if pixel_noise_px < 0:
        raise CameraSimError(f"avio.sim.camera: pixel_noise_px must be >= 0, got {pixel_noise_px}")
    frame_t_s = np.asarray(frame_t_s, float)
    obs = project_landmarks(truth, frame_t_s, calibration, landmarks_world, image_size_px, min_depth_m, max_depth_m)
    noisy = obs.uv_px if noise_per_triplet else obs.uv_px + pixel_noise_px * rng.standard_normal(obs.uv_px.shape)
    tracks, ids = triplets_from_observations(
        obs.frame_index, obs.landmark_id, noisy, len(frame_t_s), max_features, rng,
        image_size_px=image_size_px, return_track_ids=True,
    )
    if noise_per_triplet:
        fresh = pixel_noise_px * rng.standard_normal(tracks.uv_px.shape) * tracks.valid[:, :, None, None]
        tracks = replace(tracks, uv_px=tracks.uv_px + fresh)
    tracks, outlier = corrupt_triplets(tracks, outlier_fraction, rng)
    if not return_details:
        return tracks
    return tracks, {"uv_true_px": _true_uv(obs, ids, tracks), "landmark_id": ids, "outlier": outlier,
                    "observations": obs}


def _true_uv(obs: Observations, ids: np.ndarray, tracks: TripletTracks) -> np.ndarray:
    """(n_triplets, n_feat, 3, 2) noiseless pixels of the chosen features (zeros for padding)."""
    n_lm = int(obs.landmark_id.max()) + 1 if len(obs.landmark_id) else 1
    key = obs.frame_index * n_lm + obs.landmark_id
    order = np.argsort(key)
    out = np.zeros(tracks.uv_px.shape)
    t, f = np.nonzero(tracks.valid)
    for j in range(3):  # three images of the triplet
        frame = tracks.frame_index[t] - 2 + j
        pos = order[np.searchsorted(key[order], frame * n_lm + ids[t, f])]
        out[t, f, j] = obs.uv_px[pos]
    return out


def simulate_camera_tracks(truth: GroundTruth, frame_t_s: np.ndarray, truth_cal: Calibration,
                           image_size_px: tuple[int, int], pixel_noise_px: float, outlier_fraction: float,
                           max_features, rng: np.random.Generator) -> TripletTracks:
    """Triplet tracks of a simulated camera (``truth_cal``) riding along a real drive's ground
    truth: landmarks along the path (:func:`make_landmarks`), then :func:`simulate_tracks`."""
    landmarks = make_landmarks(truth, rng)
    return simulate_tracks(truth, frame_t_s, truth_cal, landmarks, image_size_px,
                           pixel_noise_px, outlier_fraction, max_features, rng)
