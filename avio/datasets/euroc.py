"""EuRoC MAV "Vicon Room 1 01" (first 30 s) with its real 200 Hz IMU, real tracks and Kalibr.

Files (../shared/data/euroc_v1_01, see its README):

- ``eqvio_processed_30s.csv``: ``imu`` rows (``t_abs``, ``gx gy gz`` rad/s, ``ax ay az`` m/s^2,
  IMU frame), ``vision_feature`` rows (``t_abs, frame_idx, landmark_id, u_norm, v_norm``:
  *undistorted normalised* coordinates) and ``meta`` rows (``key, value``; ``t0_abs`` and the
  intrinsics the features were undistorted with).
- ``V1_01_easy_groundtruth.csv``: ``#time(ns), p (m), q_world_imu (w, x, y, z), v (m/s),
  gyro bias (rad/s), accel bias (m/s^2)`` at 20 Hz over the whole flight.
- ``kalibr_imucam_chain.yaml``: cam0 ``T_imu_cam`` (maps camera points into the IMU frame),
  pinhole ``intrinsics`` (fu, fv, cu, cv), ``resolution`` (width, height).
- ``kalibr_imu_chain.yaml``: IMU noise densities (already continuous-time densities).

What the loader does, and why:

- Clock: every time is seconds from ``t0_abs`` (the first IMU sample and the first frame);
  IMU, frames and ground truth share the one EuRoC clock, so the time offset is 0.
- Frames: IMU frame = the ground truth's body frame (gyro against the ground-truth body rate
  correlates > 0.9 per axis: tests/avio/datasets/test_euroc.py). A frame takes the ground-truth
  row nearest in time (all are within 1 ms; a frame without one is an error).
- World: the Vicon world, which is gravity-aligned with z up (the mean specific force over the
  initial standstill, rotated to the world, is +9.81 m/s^2 along +z), shifted so that the IMU
  is at the origin at the window's first frame. Gravity ``(0, 0, -GRAVITY_MPS2)``.
- Calibration: ``R_cam_imu = R_imu_cam^T``, ``p_imu_cam`` = the last column of ``T_imu_cam``;
  pixels ``u = fx x + cx``, ``v = fy y + cy`` from the normalised coordinates with the Kalibr
  intrinsics (the meta rows' intrinsics must agree: they undistorted the features).
- Initial biases (``Sequence.initial_gyro_bias_radps``): the filter starts at the ground-truth
  pose and velocity of the first frame, and from zero gyro bias it diverges (the real bias is
  ~0.077 rad/s about z against a 1e-4 rad/s prior). ``gyro_bias_init="ground_truth"`` (default)
  takes the ground-truth gyro bias at the window's first frame, like the initial pose; it works
  for every window, including the dynamic 20-30 s one. ``"standstill"`` takes the mean gyro
  over the window's initial standstill (ground-truth speed below ``standstill_speed_mps`` for at
  least ``min_standstill_s``; an error for a window that starts in flight): what a user without
  motion capture would do. Over the 5 s standstill of this recording the two differ by
  1.2 mrad/s (mostly about z), and the filter at Kalibr (studies/data_checks/check_euroc.py, median of 5
  feature draws) is better from the ground truth: position RMSE 0.080 against 0.100 m over
  0-30 s, 0.078 against 0.104 m over 0-20 s, attitude RMSE 0.42 against 1.00 deg over 0-30 s;
  hence the default. The accelerometer bias defaults to zero
  (``accel_bias_init="zero"``): the ground-truth one drifts 0.03 -> 0.20 m/s^2 over the 30 s
  and did not help consistently (data README); ``"ground_truth"`` is available.
- Nominal for calibration experiments: with ``nominal_perturbation`` (an
  avio.calibration.CalibrationPerturbation or its fields) the sequence's reference calibration (the
  one a user starts from) is Kalibr plus that offset and ``truth_calibration`` is Kalibr: the
  trusted target-based calibration plays the truth, so calibration errors are against Kalibr.
  Without it the reference is Kalibr and the truth unknown (None).
- Tracks: features seen in three consecutive frames (avio.tracks), optionally at most
  ``max_features`` per triplet by bucketing; ~1.6 % of the observations are gross outliers
  (up to 760 px), kept: rejecting them is the filter's job.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from avio.calibration import Calibration, CalibrationPerturbation
from avio.datasets._io import DatasetError, check_increasing, read_numeric_table, with_content_hash
from avio.datasets.eqvio import meta_float, read_eqvio_csv
from avio.datasets.kalibr import read_camchain, read_imu_noise
from avio.datasets.paths import data_root
from avio.sequence import GroundTruth, ImuNoise, ImuSamples, Sequence, TripletTracks

DEFAULT_DATA_DIR = data_root() / "euroc_v1_01"  # at import: avio/datasets/paths.py
FEATURES_FILE = "eqvio_processed_30s.csv"
GT_FILE = "V1_01_easy_groundtruth.csv"
CAMCHAIN_FILE = "kalibr_imucam_chain.yaml"
IMU_CHAIN_FILE = "kalibr_imu_chain.yaml"
#: |g| in the Vicon room (Zurich 9.807; the EuRoC tools use 9.81), m/s^2.
GRAVITY_MPS2 = 9.81
GT_COLUMNS = 17  # time, p(3), q(4), v(3), bg(3), ba(3)


class EurocDataError(DatasetError):
    """A EuRoC file is missing or malformed, or a request does not fit the data; the message
    names the file and line (or key), or the window."""


# ---------------------------------------------------------------- file readers


@dataclass(frozen=True, eq=False)  # identity hash: memoised, and arrays are unhashable
class EurocRaw:
    """The parsed files, all times in seconds from ``t0_abs_s``.

    imu: the whole 200 Hz record. frame_t_s: (N,) frame times.
    obs_frame (m,) int, obs_landmark (m,) int, obs_xy_norm (m, 2): feature observations in
        undistorted normalised coordinates.
    gt_p_world_imu_m (N, 3), gt_R_world_imu (N, 3, 3), gt_v_world_imu_mps (N, 3),
    gt_gyro_bias_radps (N, 3), gt_accel_bias_mps2 (N, 3): ground truth at each frame (Vicon
        world, not re-origined). gt_dt_s: (N,) |ground-truth time - frame time|.
    calibration: Kalibr cam0 (batch of 1); image_size_px (width, height); imu_noise.
    """

    t0_abs_s: float
    imu: ImuSamples
    frame_t_s: np.ndarray
    obs_frame: np.ndarray
    obs_landmark: np.ndarray
    obs_xy_norm: np.ndarray
    gt_p_world_imu_m: np.ndarray
    gt_R_world_imu: np.ndarray
    gt_v_world_imu_mps: np.ndarray
    gt_gyro_bias_radps: np.ndarray
    gt_accel_bias_mps2: np.ndarray
    gt_dt_s: np.ndarray
    calibration: Calibration
    image_size_px: tuple[int, int]
    imu_noise: ImuNoise
    data_dir: Path


def _signature(data_dir: Path) -> tuple:
    """(path, size, mtime) of the files read, so a memoised parse is never stale."""
    out = []
    for name in (FEATURES_FILE, GT_FILE, CAMCHAIN_FILE, IMU_CHAIN_FILE):
        path = data_dir / name
        st = path.stat() if path.is_file() else None
        out.append((str(path.resolve()), st and st.st_size, st and st.st_mtime_ns))
    return tuple(out)


def read_euroc(data_dir: str | Path = DEFAULT_DATA_DIR, gt_tolerance_s: float = 1e-3) -> EurocRaw:
    """Parse the four files (memoised per folder and file sizes/mtimes; the arrays returned
    are read-only because they are shared). A frame without a ground-truth row within
    ``gt_tolerance_s`` is an error."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise EurocDataError(f"{data_dir}: EuRoC data folder not found")
    return _read_euroc(data_dir, _signature(data_dir), float(gt_tolerance_s))


@lru_cache(maxsize=2)
def _read_euroc(data_dir: Path, signature: tuple, gt_tolerance_s: float) -> EurocRaw:
    calibration, image_size = read_camchain(data_dir / CAMCHAIN_FILE, error=EurocDataError)
    imu_noise = read_imu_noise(data_dir / IMU_CHAIN_FILE, error=EurocDataError)
    path = data_dir / FEATURES_FILE
    columns, meta = read_eqvio_csv(path, EurocDataError)
    t0 = meta_float(meta, "t0_abs", path, EurocDataError)
    meta_K = [meta_float(meta, f"camera_{k}", path, EurocDataError) for k in ("fx", "fy", "cx", "cy")]
    yaml_K = [calibration.fx_px[0], calibration.fy_px[0], calibration.cx_px[0], calibration.cy_px[0]]
    if not np.allclose(meta_K, yaml_K, rtol=0, atol=1e-6):
        raise EurocDataError(f"{path}: the features were undistorted with intrinsics {meta_K} "
                             f"but {data_dir / CAMCHAIN_FILE} gives {yaml_K}")
    imu_cols = columns["imu"]
    imu_t = imu_cols["t_abs"] - t0
    check_increasing(imu_t, path, imu_cols["line"], "imu", EurocDataError)
    imu = ImuSamples(t_s=imu_t,
                     accel_imu_mps2=np.stack([imu_cols[c] for c in ("ax", "ay", "az")], 1),
                     gyro_imu_radps=np.stack([imu_cols[c] for c in ("gx", "gy", "gz")], 1))
    vis = columns["vision_feature"]
    frame = vis["frame_idx"].astype(np.int64)
    landmark = vis["landmark_id"].astype(np.int64)
    frame_t = _frame_times(frame, vis["t_abs"] - t0, vis["line"], path)
    xy = np.stack([vis["u_norm"], vis["v_norm"]], 1)

    gt_path = data_dir / GT_FILE
    gt = read_numeric_table(gt_path, GT_COLUMNS, skip_rows=1, delimiter=",", error=EurocDataError)
    gt_t = gt[:, 0] * 1e-9 - t0  # float ns: ~0.3 us rounding, far below the 1 ms tolerance
    check_increasing(gt_t, gt_path, 2, "ground-truth", EurocDataError)
    row, dt = _nearest(gt_t, frame_t)
    late = np.flatnonzero(dt > gt_tolerance_s)
    if late.size:
        k = int(late[0])
        raise EurocDataError(f"{gt_path}: no ground-truth row within {gt_tolerance_s * 1e3:g} ms of "
                             f"frame {k} (t = {frame_t[k]:.4f} s; nearest {dt[k] * 1e3:.3f} ms away)")
    g = gt[row]
    q = g[:, 4:8]
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        k = int(np.argmax(np.abs(norm - 1.0)))
        raise EurocDataError(f"{gt_path}:{row[k] + 2}: quaternion norm {norm[k]:.6f}, expected 1")
    raw = EurocRaw(
        t0_abs_s=t0, imu=imu, frame_t_s=frame_t, obs_frame=frame, obs_landmark=landmark,
        obs_xy_norm=xy, gt_p_world_imu_m=g[:, 1:4],
        gt_R_world_imu=Rotation.from_quat(q, scalar_first=True).as_matrix(),  # file order w, x, y, z
        gt_v_world_imu_mps=g[:, 8:11], gt_gyro_bias_radps=g[:, 11:14], gt_accel_bias_mps2=g[:, 14:17],
        gt_dt_s=dt, calibration=calibration, image_size_px=image_size, imu_noise=imu_noise,
        data_dir=data_dir,
    )
    for array in (imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, frame_t, frame, landmark, xy,
                  raw.gt_p_world_imu_m, raw.gt_R_world_imu, raw.gt_v_world_imu_mps,
                  raw.gt_gyro_bias_radps, raw.gt_accel_bias_mps2, dt):
        array.setflags(write=False)
    return raw


def _frame_times(frame: np.ndarray, t: np.ndarray, lines: np.ndarray, path: Path) -> np.ndarray:
    """(N,) time of frames 0..N-1 from the observations' (frame, time); every frame must have
    observations and one time."""
    if frame.min() < 0:
        i = int(np.argmin(frame))
        raise EurocDataError(f"{path}:{lines[i]}: negative frame_idx {frame[i]}")
    n = int(frame.max()) + 1
    counts = np.bincount(frame, minlength=n)
    if np.any(counts == 0):
        raise EurocDataError(f"{path}: frame {int(np.argmin(counts))} has no vision_feature rows "
                             f"(frames 0..{n - 1} expected; its time is unknown)")
    frame_t = np.zeros(n)
    frame_t[frame] = t
    off = np.flatnonzero(np.abs(frame_t[frame] - t) > 1e-6)
    if off.size:
        i = int(off[0])
        raise EurocDataError(f"{path}:{lines[i]}: frame {frame[i]} has two times "
                             f"({t[i]!r} and {frame_t[frame[i]]!r})")
    bad = np.flatnonzero(np.diff(frame_t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise EurocDataError(f"{path}: frame {k} time {frame_t[k]!r} does not follow frame "
                             f"{k - 1} ({frame_t[k - 1]!r})")
    return frame_t


def _nearest(t_ref: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index into sorted ``t_ref`` nearest each ``t`` (n,), |distance| (n,) s)."""
    right = np.clip(np.searchsorted(t_ref, t), 0, len(t_ref) - 1)
    left = np.clip(right - 1, 0, len(t_ref) - 1)
    pick = np.where(np.abs(t_ref[left] - t) < np.abs(t_ref[right] - t), left, right)
    return pick, np.abs(t_ref[pick] - t)


# ---------------------------------------------------------------- the sequence


def standstill_end(speed_mps: np.ndarray, threshold_mps: float) -> int:
    """Number of leading frames whose ground-truth speed (N,) m/s is below ``threshold_mps``."""
    moving = np.flatnonzero(speed_mps >= threshold_mps)
    return int(moving[0]) if moving.size else len(speed_mps)


def _window(raw: EurocRaw, t_first_s: float, t_last_s: float, tolerance_s: float, source: str):
    """(first, last) frame of the window [t_first_s, t_last_s] (frame times within
    ``tolerance_s`` of an end count as inside)."""
    t = raw.frame_t_s
    if not (np.isfinite(t_first_s) and np.isfinite(t_last_s)) or not (
        t[0] - tolerance_s <= t_first_s < t_last_s <= t[-1] + tolerance_s
    ):
        raise EurocDataError(f"{source}: window [{t_first_s}, {t_last_s}] s is outside the data "
                             f"(frames span [{t[0]:.3f}, {t[-1]:.3f}] s from t0) or empty")
    first = int(np.searchsorted(t, t_first_s - tolerance_s, side="left"))
    last = int(np.searchsorted(t, t_last_s + tolerance_s, side="right")) - 1
    if last - first < 2:
        raise EurocDataError(f"{source}: window [{t_first_s}, {t_last_s}] s holds frames "
                             f"{first}..{last}, fewer than one triplet (3 frames)")
    return first, last


def _select_imu(imu: ImuSamples, t_a: float, t_b: float, max_gap_s: float, source: str) -> ImuSamples:
    """IMU samples covering [t_a, t_b] s (the samples just outside included); an error if the
    record does not cover it or has a gap over ``max_gap_s`` inside."""
    if imu.t_s[0] > t_a + 1e-9 or imu.t_s[-1] < t_b - 1e-9:
        raise EurocDataError(f"{source}: frames need IMU over [{t_a:.4f}, {t_b:.4f}] s but the IMU "
                             f"covers [{imu.t_s[0]:.4f}, {imu.t_s[-1]:.4f}] s")
    i0 = max(int(np.searchsorted(imu.t_s, t_a + 1e-9, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(imu.t_s, t_b - 1e-9, side="left")) + 1, len(imu.t_s))
    t = imu.t_s[i0:i1]
    gaps = np.flatnonzero(np.diff(t) > max_gap_s)
    if gaps.size:
        a, b = t[gaps[0]], t[gaps[0] + 1]
        raise EurocDataError(f"{source}: IMU gap of {b - a:.4f} s (> {max_gap_s} s) between "
                             f"{a:.4f} and {b:.4f} s, inside the window [{t_a:.4f}, {t_b:.4f}] s")
    return ImuSamples(t.copy(), imu.accel_imu_mps2[i0:i1].copy(), imu.gyro_imu_radps[i0:i1].copy())


def load_euroc(
    data_dir: str | Path = DEFAULT_DATA_DIR,
    t_first_s: float = 0.0,
    t_last_s: float = 30.0,
    *,
    max_features: int | None = None,
    seed: int = 0,
    nominal_perturbation: CalibrationPerturbation | Mapping | None = None,
    gyro_bias_init: Literal["ground_truth", "standstill", "zero"] = "ground_truth",
    accel_bias_init: Literal["ground_truth", "zero"] = "zero",
    standstill_speed_mps: float = 0.02,
    min_standstill_s: float = 1.0,
    max_imu_gap_s: float = 0.02,
    frame_tolerance_s: float = 1e-3,
) -> Sequence:
    """The frames of ``[t_first_s, t_last_s]`` (seconds from t0) of V1_01 as a Sequence.

    Real 200 Hz IMU covering the frames (an error if it does not, or has a gap over
    ``max_imu_gap_s``); ground truth at each frame in the window's world (module doc); real
    tracks in pixels over consecutive triplets, at most ``max_features`` per triplet (None: all)
    chosen by bucketing with ``seed``; reference calibration = Kalibr cam0 and truth calibration
    None, or with ``nominal_perturbation`` reference = Kalibr + it and truth = Kalibr; image
    size and IMU noise from the Kalibr files; initial biases by ``gyro_bias_init`` /
    ``accel_bias_init`` (module doc). ``meta["content_hash"]`` identifies
    everything a filter run reads. Raises EurocDataError naming the file and line, the key or the
    window, before building.
    """
    source = str(Path(data_dir))
    nominal_perturbation = _checked_options(nominal_perturbation, gyro_bias_init, accel_bias_init, max_features)
    raw = read_euroc(data_dir)
    first, last = _window(raw, float(t_first_s), float(t_last_s), frame_tolerance_s, source)
    s = slice(first, last + 1)
    frame_t = raw.frame_t_s[s].copy()
    imu = _select_imu(raw.imu, frame_t[0], frame_t[-1], max_imu_gap_s, str(Path(data_dir) / FEATURES_FILE))
    truth = GroundTruth(
        p_world_imu_m=raw.gt_p_world_imu_m[s] - raw.gt_p_world_imu_m[first],
        R_world_imu=raw.gt_R_world_imu[s].copy(),
        v_world_imu_mps=raw.gt_v_world_imu_mps[s].copy(),
    )
    meta = {"source": "euroc_v1_01", "data_dir": source, "t_first_s": float(t_first_s),
            "t_last_s": float(t_last_s), "first_frame": first, "last_frame": last,
            "t0_abs_s": raw.t0_abs_s, "max_features": max_features, "seed": seed,
            "gyro_bias_init": gyro_bias_init, "accel_bias_init": accel_bias_init}
    b_g = _initial_gyro_bias(raw, imu, first, last, gyro_bias_init, standstill_speed_mps,
                             min_standstill_s, meta, source)
    b_a = raw.gt_accel_bias_mps2[first].copy() if accel_bias_init == "ground_truth" else None

    tracks = _window_tracks(raw, first, last, max_features, seed, Path(data_dir) / FEATURES_FILE)
    cal = raw.calibration
    reference, truth_cal = cal[0], None
    if nominal_perturbation is not None:
        reference, truth_cal = nominal_perturbation.apply(cal), cal[0]
        meta["nominal_perturbation"] = asdict(nominal_perturbation)
    seq = Sequence(
        name=f"euroc_v1_01_{t_first_s:g}_{t_last_s:g}", imu=imu, frame_t_s=frame_t, truth=truth,
        reference_calibration=reference, truth_calibration=truth_cal, image_size_px=raw.image_size_px, tracks=tracks,
        gravity_world_mps2=np.array([0.0, 0.0, -GRAVITY_MPS2]), imu_noise=raw.imu_noise,
        initial_gyro_bias_radps=b_g, initial_accel_bias_mps2=b_a, meta=meta,
    )
    return _with_hash(seq)


def _checked_options(nominal_perturbation, gyro_bias_init: str, accel_bias_init: str,
                     max_features: int | None) -> CalibrationPerturbation | None:
    """``load_euroc``'s options checked (EurocDataError), and the nominal perturbation as the class."""
    if isinstance(nominal_perturbation, Mapping):  # e.g. straight from a config file
        try:
            nominal_perturbation = CalibrationPerturbation(**nominal_perturbation)
        except TypeError as err:
            raise EurocDataError(f"nominal_perturbation: {err}") from None
    if gyro_bias_init not in ("ground_truth", "standstill", "zero"):
        raise EurocDataError(f"gyro_bias_init must be 'ground_truth', 'standstill' or 'zero', "
                             f"got {gyro_bias_init!r}")
    if accel_bias_init not in ("ground_truth", "zero"):
        raise EurocDataError(f"accel_bias_init must be 'ground_truth' or 'zero', got {accel_bias_init!r}")
    if max_features is not None and max_features < 1:
        raise EurocDataError(f"max_features must be >= 1 or None, got {max_features}")
    return nominal_perturbation


def _window_tracks(raw: EurocRaw, first: int, last: int, max_features: int | None, seed: int,
                   features_path: Path) -> TripletTracks:
    """The tracks over the triplets of frames first..last, in pixels (Kalibr intrinsics)."""
    from avio.tracks import TracksError, triplets_from_observations

    keep = (raw.obs_frame >= first) & (raw.obs_frame <= last)
    cal = raw.calibration
    uv = raw.obs_xy_norm[keep] * [cal.fx_px[0], cal.fy_px[0]] + [cal.cx_px[0], cal.cy_px[0]]
    try:
        return triplets_from_observations(
            raw.obs_frame[keep] - first, raw.obs_landmark[keep], uv, last - first + 1,
            max_features=max_features, rng=np.random.default_rng(seed), image_size_px=raw.image_size_px,
        )
    except TracksError as err:
        raise EurocDataError(f"{features_path}: {err}") from err


def _initial_gyro_bias(raw: EurocRaw, imu: ImuSamples, first: int, last: int, mode: str,
                       speed_mps: float, min_s: float, meta: dict, source: str) -> np.ndarray | None:
    """(3,) rad/s initial gyro bias by ``mode`` (module doc), or None for "zero"."""
    if mode == "zero":
        return None
    if mode == "ground_truth":
        return raw.gt_gyro_bias_radps[first].copy()
    speed = np.linalg.norm(raw.gt_v_world_imu_mps[first:last + 1], axis=1)
    n_still = standstill_end(speed, speed_mps)
    t_a, t_b = raw.frame_t_s[first], raw.frame_t_s[first + max(n_still - 1, 0)]
    if n_still == 0 or t_b - t_a < min_s:
        raise EurocDataError(
            f"{source}: gyro_bias_init='standstill' needs the window to start at rest, but the "
            f"ground-truth speed stays below {speed_mps} m/s for only {max(t_b - t_a, 0):.2f} s "
            f"(< {min_s} s) from t = {t_a:.2f} s"
        )
    inside = (imu.t_s >= t_a) & (imu.t_s <= t_b)
    meta["standstill_s"] = [float(t_a), float(t_b)]
    return imu.gyro_imu_radps[inside].mean(axis=0)


def _with_hash(seq: Sequence) -> Sequence:
    """The content hash also covers what EuRoC sets per drive: the calibrations, gravity, the
    initial biases, the IMU noise and the image size."""
    zero = np.zeros(3)
    calibrations = [seq.reference_calibration] + ([] if seq.truth_calibration is None else [seq.truth_calibration])
    arrays = [*(getattr(c, k) for c in calibrations for k in Calibration.__dataclass_fields__),
              seq.gravity_world_mps2,
              zero if seq.initial_gyro_bias_radps is None else seq.initial_gyro_bias_radps,
              zero if seq.initial_accel_bias_mps2 is None else seq.initial_accel_bias_mps2]
    noise = [seq.imu_noise.accel_noise, seq.imu_noise.gyro_noise, seq.imu_noise.accel_bias_walk,
             seq.imu_noise.gyro_bias_walk]
    return with_content_hash(seq, arrays, {"imu_noise": noise, "image_size_px": list(seq.image_size_px)})
