"""KITTI odometry sequence 00 (= raw drive 2011_10_03_drive_0027) with its real 100 Hz IMU.

Files (../shared/data/kitti00, see its README): ``KITTI_00_gt.txt`` (T_w_cam0 per frame, world =
rectified cam0 of frame 0, x right / y down / z forward), ``KITTI_00_gt_times.txt`` (frame times
from frame 0), ``KittiEquivBiasedImu.txt`` (100 Hz OXTS IMU, seconds of the day, body x forward /
y left / z up, specific force m/s^2, rates rad/s; its dt column is unused),
``VO_stereo_factors00.txt`` (real tracks of frames 0-153, rows ``frame landmark uL uR v X Y Z``).

What the loader does, and why:

- Clocks: IMU time = frame time + ``TIME_OFFSET_S`` (46535.00 s; gyro z against the GT yaw rate
  correlates 0.997 at that offset). ``Sequence.frame_t_s`` is on the IMU clock.
- IMU poses: ``T_W_imu = T_W_cam0 · T_cam0_imu`` with the *rectified* 2011_10_03 extrinsic,
  because the ground truth lives in the rectified cam0 frame.
- Gravity: the GT world W is the camera frame of frame 0, tilted against gravity by the car's
  pitch/roll there. Gravity in W is estimated once from the whole drive (frames 15..end, where
  the IMU has no gap) by the velocity-increment identity
  ``v(t1) - v(t0) = ∫ R_W_imu f_imu dt + g_W (t1 - t0)``: GT velocities at both ends, the IMU
  specific force rotated by the GT attitude (slerp-interpolated to the IMU times) and summed.
  Over 450 s with many turns the accelerometer bias averages out: the estimates from the three
  thirds of the drive agree to 0.04 deg, and |g_W| = 9.810 m/s^2 (Karlsruhe: 9.809).
  ``gravity_world_mps2`` is ``(0, 0, -|g_W|)`` so that integrating this IMU is self-consistent.
- World of a window: z up (``-g_W``), x the horizontal projection of the IMU forward axis at the
  window's first frame, origin at the IMU position there ("fixed to the start of the sequence").
- Velocities: derivative of a cubic spline through the GT IMU positions of the *whole* drive at
  the (non-uniform, ~0.1036 s) frame times, so windows have no end effects.
- Real tracks: ``VO_stereo_factors00.txt`` has no observations in the even frames 94..130 (every
  other frame is missing there), so triplets ending in frames 94..132 are empty; the longest
  gap-free stretch after the IMU gap is ``REAL_TRACK_WINDOW`` = frames 15..93.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from avio.calibration import CalibrationPerturbation
from avio.datasets._io import DatasetError, check_increasing, read_numeric_table, with_content_hash
from avio.datasets.paths import data_root
from avio.reference import IMAGE_SIZE_PX, T_cam_imu_2011_10_03, kitti_2011_10_03_calibration
from avio.sequence import GroundTruth, ImuNoise, ImuSamples, Sequence, TripletTracks
from avio.sim.camera import simulate_camera_tracks
from avio.tracks import triplets_from_observations

#: The data folder at import (avio/datasets/paths.py: $AVIO_DATA, the checkout's ../shared/data or a user folder).
DEFAULT_DATA_DIR = data_root()
TIME_OFFSET_S = 46535.00
WINDOWS = {"paper_540m": (15, 796), "paper_928m": (2404, 3553), "clean_928m": (3000, 4077)}
#: Ground-truth/IMU consistency (see :func:`check_ground_truth_rate`): the yaw rate of the ground
#: truth against the real gyro, RMS over blocks of 16 frames. On the drive the blocks' median is
#: 0.0017 rad/s and clean stretches stay below 0.019 (a sharp turn with a few ms of clock error);
#: the defects reach 0.03-0.15 rad/s: frames ~1903-1983, 2111-2143, 2271-2287, 2671-2703 and
#: 2959-2991 (the last two inside the paper-sized 928 m window 2404-3553, hence "clean_928m",
#: 3000-4077: 929 m in 112 s, the held-out default).
GT_RATE_BLOCK_FRAMES = 16
MAX_GT_RATE_MISFIT_RADPS = 0.025
REAL_TRACK_FRAMES = (15, 153)
REAL_TRACK_WINDOW = (15, 93)
#: first frame after the 1.92 s IMU gap; the gravity estimate uses frames from here on.
FIRST_GAPLESS_FRAME = 15
GT_FILE, TIMES_FILE = "KITTI_00_gt.txt", "KITTI_00_gt_times.txt"
IMU_FILE, TRACKS_FILE = "KittiEquivBiasedImu.txt", "VO_stereo_factors00.txt"
# KittiEquivBiasedImu_metadata.txt: discrete sigmas at dt = 0.01 s -> densities.
class KittiDataError(DatasetError):
    """A KITTI file is missing or malformed, or a request does not fit the data; the message
    names the file and line, or the frames."""


KITTI00_IMU_NOISE = ImuNoise(
    accel_noise=0.01 / np.sqrt(0.01),
    gyro_noise=0.000175 / np.sqrt(0.01),
    accel_bias_walk=0.000167,
    gyro_bias_walk=2.91e-6,
)


@dataclass(frozen=True, eq=False)  # identity hash: memoised, and arrays are unhashable
class Kitti00Raw:
    """The parsed files of sequence 00.

    T_W_cam0: (N, 4, 4) GT camera poses, W = rectified cam0 frame of frame 0.
    frame_t_s: (N,) frame times on the IMU clock.
    imu: the whole IMU record (gap included).
    """

    T_W_cam0: np.ndarray
    frame_t_s: np.ndarray
    imu: ImuSamples
    data_dir: Path


def _signature(data_dir: Path) -> tuple:
    """(path, size, mtime) of the files read, so a cached parse is never stale."""
    out = []
    for name in (GT_FILE, TIMES_FILE, IMU_FILE):
        path = data_dir / name
        st = path.stat() if path.is_file() else None
        out.append((str(path.resolve()), st and st.st_size, st and st.st_mtime_ns))
    return tuple(out)


def read_kitti00(data_dir: str | Path = DEFAULT_DATA_DIR / "kitti00") -> Kitti00Raw:
    """Parse GT poses, frame times and IMU of sequence 00 (memoised per folder and file
    sizes/mtimes; the arrays returned are read-only because they are shared)."""
    return _read_kitti00(Path(data_dir), _signature(Path(data_dir)))


@lru_cache(maxsize=2)
def _read_kitti00(data_dir: Path, signature: tuple) -> Kitti00Raw:
    gt = read_numeric_table(data_dir / GT_FILE, 12, error=KittiDataError)
    times = read_numeric_table(data_dir / TIMES_FILE, 1, error=KittiDataError)[:, 0]
    if len(times) != len(gt):
        raise KittiDataError(
            f"{data_dir / TIMES_FILE}: {len(times)} frame times for {len(gt)} poses in {GT_FILE}"
        )
    check_increasing(times, data_dir / TIMES_FILE, 1, error=KittiDataError)
    imu = read_numeric_table(data_dir / IMU_FILE, 8, skip_rows=1, error=KittiDataError)
    check_increasing(imu[:, 0], data_dir / IMU_FILE, 2, error=KittiDataError)
    T = np.tile(np.eye(4), (len(gt), 1, 1))
    T[:, :3, :] = gt.reshape(-1, 3, 4)
    raw = Kitti00Raw(
        T_W_cam0=T,
        frame_t_s=times + TIME_OFFSET_S,
        imu=ImuSamples(t_s=imu[:, 0], accel_imu_mps2=imu[:, 2:5], gyro_imu_radps=imu[:, 5:8]),
        data_dir=data_dir,
    )
    for array in (raw.T_W_cam0, raw.frame_t_s, raw.imu.t_s, raw.imu.accel_imu_mps2, raw.imu.gyro_imu_radps):
        array.setflags(write=False)
    return raw


def imu_poses_in_gt_world(T_W_cam0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R_W_imu (N,3,3), p_W_imu_m (N,3))`` from GT camera poses ``T_W_cam0`` (N,4,4)
    through the rectified 2011_10_03 extrinsic (``T_W_imu = T_W_cam0 · T_cam0_imu``)."""
    R_cam_imu, t_cam_imu = T_cam_imu_2011_10_03(rectified=True)
    R_W_cam, p_W_cam = T_W_cam0[:, :3, :3], T_W_cam0[:, :3, 3]
    # Project onto SO(3): the file holds rotations to 7 digits only.
    R_W_imu = Rotation.from_matrix(R_W_cam @ R_cam_imu).as_matrix()
    return R_W_imu, p_W_cam + R_W_cam @ t_cam_imu


def estimate_gravity_gt_world(
    frame_t_s: np.ndarray, R_W_imu: np.ndarray, v_W_mps: np.ndarray, imu: ImuSamples
) -> np.ndarray:
    """(3,) gravity in the GT world, m/s^2, from ``Δv = ∫ R_W_imu f dt + g Δt`` over the frames.

    frame_t_s: (N,) on the IMU clock, inside a gap-free stretch of ``imu``; R_W_imu (N,3,3);
    v_W_mps (N,3) GT velocities. Trapezoidal integral over the IMU samples between the first
    and last frame, attitude slerp-interpolated from the frames.
    """
    inside = (imu.t_s >= frame_t_s[0]) & (imu.t_s <= frame_t_s[-1])
    t = imu.t_s[inside]
    R = Slerp(frame_t_s, Rotation.from_matrix(R_W_imu))(t).as_matrix()
    f_W = np.einsum("nij,nj->ni", R, imu.accel_imu_mps2[inside])
    integral = np.trapezoid(f_W, t, axis=0)
    span = t[-1] - t[0]
    dv = v_W_mps[-1] - v_W_mps[0]
    # The few ms between the first/last frame and the nearest IMU samples are neglected.
    return (dv - integral) / span


def gravity_aligned_rotation(g_W: np.ndarray, forward_W: np.ndarray) -> np.ndarray:
    """(3,3) ``R_world_W``: world z = -g direction (up), x = horizontal part of ``forward_W``."""
    z = -g_W / np.linalg.norm(g_W)
    x = forward_W - z * (forward_W @ z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


@dataclass(frozen=True)
class Kitti00Truth:
    """GT of the whole drive in the GT world W: R_W_imu (N,3,3), p_W_imu_m (N,3),
    v_W_imu_mps (N,3), and gravity ``g_W_mps2`` (3,)."""

    R_W_imu: np.ndarray
    p_W_imu_m: np.ndarray
    v_W_imu_mps: np.ndarray
    g_W_mps2: np.ndarray


def kitti00_truth(data_dir: str | Path = DEFAULT_DATA_DIR / "kitti00") -> Kitti00Truth:
    """GT IMU states of the whole drive in W, with the gravity estimate (see module doc);
    memoised like ``read_kitti00``."""
    return _kitti00_truth(read_kitti00(data_dir))


@lru_cache(maxsize=2)
def _kitti00_truth(raw: Kitti00Raw) -> Kitti00Truth:
    R_W_imu, p_W_imu = imu_poses_in_gt_world(raw.T_W_cam0)
    v_W = CubicSpline(raw.frame_t_s, p_W_imu, axis=0)(raw.frame_t_s, 1)
    s = slice(FIRST_GAPLESS_FRAME, None)
    g_W = estimate_gravity_gt_world(raw.frame_t_s[s], R_W_imu[s], v_W[s], raw.imu)
    truth = Kitti00Truth(R_W_imu, p_W_imu, v_W, g_W)
    for array in (R_W_imu, p_W_imu, v_W, g_W):
        array.setflags(write=False)
    return truth


def select_imu(
    imu: ImuSamples, frame_t_s: np.ndarray, first: int, margin_s: float, max_gap_s: float,
    all_frame_t_s: np.ndarray, source: str,
) -> ImuSamples:
    """IMU rows covering ``[t_first - margin_s, t_last + margin_s]`` (the samples just outside
    included); KittiDataError if that leaves the record or holds a gap over ``max_gap_s``.

    frame_t_s: (n,) window frame times; all_frame_t_s: (N,) every frame's time, to name frames.
    """
    t0, t1 = frame_t_s[0] - margin_s, frame_t_s[-1] + margin_s
    if t0 < imu.t_s[0] or t1 > imu.t_s[-1]:
        raise KittiDataError(
            f"{source}: frames {first}..{first + len(frame_t_s) - 1} need IMU over "
            f"[{t0:.3f}, {t1:.3f}] s but the IMU covers [{imu.t_s[0]:.3f}, {imu.t_s[-1]:.3f}] s"
        )
    i0 = int(np.searchsorted(imu.t_s, t0, side="right")) - 1
    i1 = int(np.searchsorted(imu.t_s, t1, side="left")) + 1
    t = imu.t_s[i0:i1]
    gaps = np.flatnonzero(np.diff(t) > max_gap_s)
    if gaps.size:
        a, b = t[gaps[0]], t[gaps[0] + 1]
        f_a = int(np.searchsorted(all_frame_t_s, a, side="right")) - 1
        f_b = int(np.searchsorted(all_frame_t_s, b, side="left"))
        raise KittiDataError(
            f"{source}: IMU gap of {b - a:.3f} s (> {max_gap_s} s) between IMU times {a:.3f} and "
            f"{b:.3f}, i.e. between frames {max(f_a, 0)} and {f_b}, inside the requested frames "
            f"{first}..{first + len(frame_t_s) - 1}"
        )
    return ImuSamples(t.copy(), imu.accel_imu_mps2[i0:i1].copy(), imu.gyro_imu_radps[i0:i1].copy())


def _window_truth(truth: Kitti00Truth, first: int, last: int) -> tuple[GroundTruth, np.ndarray]:
    """GT of frames first..last in the window's gravity-aligned world, and ``g_world`` (3,)."""
    s = slice(first, last + 1)
    R_world_W = gravity_aligned_rotation(truth.g_W_mps2, truth.R_W_imu[first][:, 0])
    p = (truth.p_W_imu_m[s] - truth.p_W_imu_m[first]) @ R_world_W.T
    gt = GroundTruth(
        p_world_imu_m=p,
        R_world_imu=R_world_W @ truth.R_W_imu[s],
        v_world_imu_mps=truth.v_W_imu_mps[s] @ R_world_W.T,
    )
    return gt, np.array([0.0, 0.0, -np.linalg.norm(truth.g_W_mps2)])


def ground_truth_rate_misfit(raw: Kitti00Raw, truth: Kitti00Truth, first: int, last: int,
                             block_frames: int = GT_RATE_BLOCK_FRAMES) -> tuple[np.ndarray, np.ndarray]:
    """``(block_first_frame (b,), rms_radps (b,))``: the RMS over blocks of ``block_frames`` frame
    intervals of ``w_gyro,z - w_gt,z``, the mean real gyro z rate over each frame interval minus
    the ground truth's body yaw rate ``Log(R_k^T R_k+1)_z / dt`` (the window's median difference,
    i.e. the gyro bias, removed), frames first..last."""
    R = truth.R_W_imu[first:last + 1]
    t = raw.frame_t_s[first:last + 1]
    rel = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:])).as_rotvec()
    w_gt = rel[:, 2] / np.diff(t)
    gyro_z = raw.imu.gyro_imu_radps[:, 2]
    csum = np.r_[0.0, np.cumsum(gyro_z)]
    i0, i1 = np.searchsorted(raw.imu.t_s, t[:-1]), np.searchsorted(raw.imu.t_s, t[1:])
    count = i1 - i0
    with np.errstate(invalid="ignore", divide="ignore"):
        w_imu = (csum[i1] - csum[i0]) / count
    e = np.where(count > 0, w_imu - w_gt, np.nan)
    e = e - np.nanmedian(e)
    starts = np.arange(0, len(e), block_frames)
    rms = np.array([np.sqrt(np.nanmean(e[k:k + block_frames] ** 2)) for k in starts])
    return starts + first, rms


def check_ground_truth_rate(raw: Kitti00Raw, truth: Kitti00Truth, first: int, last: int,
                            max_misfit_radps: float = MAX_GT_RATE_MISFIT_RADPS, source: str = "kitti00") -> None:
    """KittiDataError naming the frames where the ground truth's yaw rate contradicts the real
    gyro by more than ``max_misfit_radps`` (block RMS, :func:`ground_truth_rate_misfit`): a
    camera simulated through such poses contradicts the IMU and the filter loses track."""
    starts, rms = ground_truth_rate_misfit(raw, truth, first, last)
    bad = np.flatnonzero(rms > max_misfit_radps)
    if bad.size:
        spans = ", ".join(f"{starts[i]}-{min(starts[i] + GT_RATE_BLOCK_FRAMES, last)} ({rms[i]:.3f} rad/s)"
                          for i in bad[:6])
        raise KittiDataError(
            f"{source}: frames {first}..{last}: the ground-truth yaw rate contradicts the real gyro "
            f"(block RMS above {max_misfit_radps} rad/s) at frames {spans}; choose a clean window, e.g. "
            f"{WINDOWS['paper_540m']} or {WINDOWS['clean_928m']}")


def _check_window(first: int, last: int, n_frames: int, source: str) -> None:
    if not (0 <= first and last < n_frames and last - first >= 2):
        raise KittiDataError(
            f"{source}: window frames {first}..{last} outside the data (frames 0..{n_frames - 1}) "
            "or shorter than one triplet"
        )


def read_real_tracks(
    path: str | Path, first: int, last: int, with_points: bool = False
) -> tuple[np.ndarray, ...]:
    """Observations of frames first..last from ``VO_stereo_factors00.txt``:
    ``(frame (m,) int, landmark (m,) int, uv_px (m, 2))`` with uv the left-image (uL, v); with
    ``with_points`` also ``xyz_cam_m (m, 3)``, KITTI's stereo-triangulated point in that frame's
    cam0 coordinates."""
    rows = read_numeric_table(path, 8, error=KittiDataError)
    frame, landmark = rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64)
    keep = (frame >= first) & (frame <= last)
    out = (frame[keep], landmark[keep], rows[keep][:, [2, 4]])
    return (*out, rows[keep][:, 5:8]) if with_points else out


def load_kitti00(
    data_dir: str | Path = DEFAULT_DATA_DIR / "kitti00",
    first: int = WINDOWS["paper_540m"][0],
    last: int = WINDOWS["paper_540m"][1],
    *,
    camera: Literal["simulated", "real_tracks"] = "simulated",
    seed: int = 0,
    truth_perturbation: CalibrationPerturbation | Mapping = CalibrationPerturbation(),
    pixel_noise_px: float = 0.5,
    outlier_fraction: float = 0.0,
    max_features: int | None = 50,
    max_imu_gap_s: float = 0.05,
    imu_margin_s: float = 0.1,
    max_gt_rate_misfit_radps: float | None = MAX_GT_RATE_MISFIT_RADPS,
) -> Sequence:
    """Frames ``first..last`` (inclusive) of KITTI sequence 00 as a Sequence.

    The IMU is real (100 Hz), rows covering ``[t_first - imu_margin_s, t_last + imu_margin_s]``
    on the IMU clock; a spacing over ``max_imu_gap_s`` inside is an error naming the frames.
    camera="simulated": landmarks projected through the GT camera poses with a known truth
    calibration (reference = rectified 2011_10_03 with P_rect_00 intrinsics, truth = reference
    + ``truth_perturbation``), ``pixel_noise_px`` Gaussian noise, ``outlier_fraction`` outliers,
    at most ``max_features`` per triplet, all drawn from ``seed``.
    camera="real_tracks": the real tracks of frames 15..153 (truth calibration None),
    ``max_features`` per triplet chosen by ``avio.tracks`` with ``seed``.
    The window's ground truth is checked against the real gyro
    (:func:`check_ground_truth_rate`; None skips the check).
    Raises KittiDataError naming the file/line or frames for any problem, before building.
    """
    source = str(Path(data_dir))
    if camera not in ("simulated", "real_tracks"):
        raise KittiDataError(f"camera must be 'simulated' or 'real_tracks', got {camera!r}")
    raw = read_kitti00(data_dir)
    _check_window(first, last, len(raw.frame_t_s), source)
    if camera == "real_tracks" and (first < REAL_TRACK_FRAMES[0] or last > REAL_TRACK_FRAMES[1]):
        raise KittiDataError(
            f"{Path(data_dir) / TRACKS_FILE}: real tracks exist for frames "
            f"{REAL_TRACK_FRAMES[0]}..{REAL_TRACK_FRAMES[1]} only, requested {first}..{last}"
        )
    frame_t = raw.frame_t_s[first:last + 1].copy()
    imu = select_imu(raw.imu, frame_t, first, imu_margin_s, max_imu_gap_s,
                     raw.frame_t_s, str(Path(data_dir) / IMU_FILE))
    if max_gt_rate_misfit_radps is not None:
        check_ground_truth_rate(raw, kitti00_truth(data_dir), first, last, max_gt_rate_misfit_radps, source)
    truth_gt, g_world = _window_truth(kitti00_truth(data_dir), first, last)
    reference = kitti_2011_10_03_calibration(rectified=True)
    if isinstance(truth_perturbation, Mapping):  # e.g. straight from a config file
        truth_perturbation = CalibrationPerturbation(**truth_perturbation)
    meta = {"source": "kitti00", "data_dir": source, "first_frame": first, "last_frame": last,
            "camera": camera, "imu_clock_minus_frame_clock_s": TIME_OFFSET_S, "seed": seed,
            "pixel_noise_px": pixel_noise_px, "outlier_fraction": outlier_fraction,
            "max_features": max_features, "imu_margin_s": imu_margin_s}
    seq = Sequence(
        name=f"kitti00_{first}_{last}_{camera}", imu=imu, frame_t_s=frame_t,
        truth=truth_gt, reference_calibration=reference, image_size_px=IMAGE_SIZE_PX,
        gravity_world_mps2=g_world, imu_noise=KITTI00_IMU_NOISE, meta=meta,
    )
    rng = np.random.default_rng(seed)
    if camera == "real_tracks":
        tracks = _real_tracks(data_dir, first, last, max_features, rng)
        empty = tracks.frame_index[tracks.n_features == 0] + first
        meta["triplets_without_tracks"] = empty.tolist()
        return with_content_hash(seq.with_tracks(tracks))
    truth_cal = truth_perturbation.apply(reference)
    meta["truth_perturbation"] = asdict(truth_perturbation)
    tracks = simulate_camera_tracks(seq.truth, seq.frame_t_s, truth_cal, seq.image_size_px, pixel_noise_px,
                                    outlier_fraction, max_features, rng)
    return with_content_hash(replace(seq, tracks=tracks, truth_calibration=truth_cal))


def _real_tracks(data_dir, first: int, last: int, max_features, rng) -> TripletTracks:
    frame, landmark, uv = read_real_tracks(Path(data_dir) / TRACKS_FILE, first, last)
    return triplets_from_observations(
        frame - first, landmark, uv, last - first + 1, max_features=max_features, rng=rng,
        image_size_px=IMAGE_SIZE_PX,
    )


