"""``problem=kitti00`` and ``problem=kitti00_tracks``: KITTI sequence 00 with its real 100 Hz IMU
and GPS/INS ground truth (avio/datasets/kitti00.py).

- ``kitti00``: the camera is simulated through the ground-truth poses with a known truth
  calibration (the rectified KITTI calibration plus ``truth_perturbation``): real IMU and
  trajectory, known answer. Every calibration window and the held-out window see the same
  camera with independent pixel noise and outliers (loader seed ``(data_seed, i)``, held-out
  ``(data_seed, 1000)``). Windows are checked against the real gyro when loaded (a ground-truth
  defect is an error naming the frames); the default held-out window ``clean_928m`` (frames
  3000-4077, 929 m) avoids the defects inside the paper-sized 2404-3553. A calibration window that
  shares a frame with the held-out one is refused before any data is read: its camera noise is its
  own, but its IMU, trajectory and truth are the same real data (so ``paper_928m`` needs another
  held-out window than ``clean_928m``).
- ``kitti00_tracks``: all real: frames 15-153 with the real feature tracks; no truth
  calibration (no calibration errors are reported).

The ground truth lives in the rectified cam0 frame, so the reference is the rectified
calibration; 0.65 deg of rectification moves its ZYX roll from 119.5 to 173 deg (gimbal lock),
outside Table 1, hence the local space.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from avio.calibration import Calibration
from avio.errors import AvioError
from bench.problems.base import ProblemError, register
from bench.problems.vio import Drives, VioParams, VioProblem, default_data_dir, require_data

HOLDOUT_SEED = 1000


def _frames(window, what: str) -> tuple[int, int]:
    from avio.datasets.kitti00 import WINDOWS

    if isinstance(window, str):
        if window not in WINDOWS:
            raise ProblemError(f"{what}: unknown window {window!r}; valid: {', '.join(WINDOWS)} or [first, last]")
        return WINDOWS[window]
    try:
        first, last = (int(v) for v in window)
    except (TypeError, ValueError):
        raise ProblemError(f"{what} = {window!r}: a window name or [first, last] frames") from None
    return first, last


def _read(data_dir: str | None):
    from avio.datasets.kitti00 import GT_FILE, IMU_FILE, TIMES_FILE, read_kitti00

    folder = require_data(data_dir, "kitti00", (GT_FILE, TIMES_FILE, IMU_FILE), "KITTI 00")
    try:
        return read_kitti00(folder)  # parses and validates every file (memoised)
    except (AvioError, OSError) as err:  # KittiDataError, or another avio error of its data
        raise ProblemError(str(err)) from None


def _rectified_reference() -> Calibration:
    from avio.reference import kitti_2011_10_03_calibration

    return kitti_2011_10_03_calibration(rectified=True)


def _load(data_dir, window, what: str, **kwargs):
    from avio.datasets.kitti00 import load_kitti00

    first, last = _frames(window, what)
    try:
        return load_kitti00(default_data_dir(data_dir) / "kitti00", first, last, **kwargs)
    except AvioError as err:  # KittiDataError, or the simulated camera's and tracks' errors
        raise ProblemError(f"{what}: {err}") from None


def _window_text(window, frames: tuple[int, int]) -> str:
    span = f"frames {frames[0]}-{frames[1]}"
    return f"{window} ({span})" if isinstance(window, str) else span


def _check_holdout_apart(windows: dict, holdout) -> None:
    """ProblemError naming both windows when a calibration window shares a frame with the held-out one:
    its simulated camera has its own noise, but the IMU, the trajectory and the ground truth are the
    same real data, so the held-out score would test the calibration on what it was fitted to.
    Checked from the frame numbers alone, before any data is read."""
    first_h, last_h = _frames(holdout, "holdout")
    for what, window in windows.items():
        first, last = _frames(window, what)
        if first <= last_h and first_h <= last:
            raise ProblemError(f"{what} = {_window_text(window, (first, last))} overlaps the held-out window "
                               f"holdout = {_window_text(holdout, (first_h, last_h))}: the held-out score must come "
                               "from frames the optimiser never sees; choose windows apart, or set holdout: null")


def _check_windows(data_dir, windows: dict) -> None:
    """Each window inside the data, its IMU gap-free and its ground truth consistent (cheap:
    the files are parsed once per process)."""
    from avio.datasets.kitti00 import _check_window, check_ground_truth_rate, kitti00_truth, select_imu

    raw = _read(data_dir)
    for what, window in windows.items():
        first, last = _frames(window, what)
        try:
            _check_window(first, last, len(raw.frame_t_s), str(raw.data_dir))
            select_imu(raw.imu, raw.frame_t_s[first:last + 1], first, 0.1, 0.05, raw.frame_t_s, str(raw.data_dir))
            check_ground_truth_rate(raw, kitti00_truth(raw.data_dir), first, last, source=str(raw.data_dir))
        except AvioError as err:  # KittiDataError
            raise ProblemError(f"{what}: {err}") from None


@dataclass(frozen=True)
class Kitti00Params(VioParams):
    """data_dir: null = $AVIO_DATA, else ../shared/data in a checkout, else the user data folder (the
    folder holding kitti00/; ``python -m bench.data``); drives: calibration windows (names of
    avio.datasets.kitti00.WINDOWS or [first, last]); holdout: the held-out window or None; data_seed: the
    simulated camera's noise and outliers (>= 0); pixel_noise_px, outlier_fraction, max_features:
    the simulated camera; truth_perturbation: truth = rectified KITTI + this
    (avio.calibration.CalibrationPerturbation fields)."""

    data_dir: str | None = None
    drives: tuple = ("paper_540m",)
    holdout: str | tuple | None = "clean_928m"
    data_seed: int = 0
    pixel_noise_px: float = 0.7
    outlier_fraction: float = 0.05
    max_features: int = 30
    truth_perturbation: dict = field(default_factory=lambda: {
        "d_intrinsics_px": (1.2, -0.9, 1.6, -1.1),
        "d_rotvec_cam_rad": (0.0035, -0.0050, 0.0030),  # ~0.39 deg
        "d_p_imu_cam_m": (0.020, -0.015, 0.025),  # ~3.5 cm
        "time_offset_s": 0.0})

    def validate(self) -> None:
        from avio.calibration import CalibrationPerturbation

        if self.data_seed < 0:
            raise ProblemError(f"data_seed = {self.data_seed}: must be >= 0")
        if not self.drives:
            raise ProblemError("drives: at least one calibration window")
        for i, w in enumerate(self.drives):
            _frames(w, f"drives[{i}]")
        if self.holdout is not None:
            _check_holdout_apart({f"drives[{i}]": w for i, w in enumerate(self.drives)}, self.holdout)
        if not self.pixel_noise_px >= 0 or not 0 <= self.outlier_fraction <= 1 or self.max_features < 1:
            raise ProblemError("pixel_noise_px >= 0, outlier_fraction in [0, 1] and max_features >= 1 required")
        try:
            CalibrationPerturbation(**self.truth_perturbation)
        except TypeError as err:
            raise ProblemError(f"truth_perturbation: {err}") from None
        super().validate()

    def nominal_for_checks(self) -> Calibration:
        return _rectified_reference()

    def check_data(self) -> None:
        windows = {f"drives[{i}]": w for i, w in enumerate(self.drives)}
        if self.holdout is not None:
            windows["holdout"] = self.holdout
        _check_windows(self.data_dir, windows)

    def _camera(self, seed) -> dict:
        from avio.calibration import CalibrationPerturbation

        return dict(camera="simulated", seed=seed, pixel_noise_px=self.pixel_noise_px,
                    outlier_fraction=self.outlier_fraction, max_features=self.max_features,
                    truth_perturbation=CalibrationPerturbation(**self.truth_perturbation))

    def build(self) -> Drives:
        drives = tuple(_load(self.data_dir, w, f"drives[{i}]", **self._camera(self.data_seed if i == 0 else
                                                                             [self.data_seed, i]))
                       for i, w in enumerate(self.drives))
        held = None if self.holdout is None else _load(self.data_dir, self.holdout, "holdout",
                                                       **self._camera([self.data_seed, HOLDOUT_SEED]))
        return Drives(drives, held)


@register("kitti00")
class Kitti00(VioProblem):
    """KITTI 00, real IMU and ground truth, simulated camera with a known truth (module docstring)."""

    Params = Kitti00Params
    name = "kitti00"


@dataclass(frozen=True)
class Kitti00TracksParams(VioParams):
    """data_dir: as kitti00; window: [first, last] inside the real tracks' frames 15-153;
    data_seed: seeds which tracks are kept per triplet (>= 0); max_features: tracks per triplet."""

    data_dir: str | None = None
    window: tuple[int, int] = (15, 153)
    data_seed: int = 0
    max_features: int = 30

    def validate(self) -> None:
        from avio.datasets.kitti00 import REAL_TRACK_FRAMES

        if self.data_seed < 0:
            raise ProblemError(f"data_seed = {self.data_seed}: must be >= 0")
        first, last = self.window
        if first < REAL_TRACK_FRAMES[0] or last > REAL_TRACK_FRAMES[1] or last - first < 2:
            raise ProblemError(f"window = {list(self.window)}: the real tracks cover frames "
                               f"{REAL_TRACK_FRAMES[0]}..{REAL_TRACK_FRAMES[1]} (at least 3 frames)")
        if self.max_features < 1:
            raise ProblemError(f"max_features = {self.max_features}: must be >= 1")
        super().validate()

    def nominal_for_checks(self) -> Calibration:
        return _rectified_reference()

    def check_data(self) -> None:
        from avio.datasets.kitti00 import TRACKS_FILE

        tracks = require_data(self.data_dir, "kitti00", (TRACKS_FILE,), "KITTI 00 real tracks") / TRACKS_FILE
        _check_windows(self.data_dir, {"window": self.window})
        if tracks.stat().st_size == 0:
            raise ProblemError(f"{tracks}: the real feature tracks file is empty")

    def build(self) -> Drives:
        seq = _load(self.data_dir, self.window, "window", camera="real_tracks", seed=self.data_seed,
                    max_features=self.max_features)
        return Drives((seq,), None)


@register("kitti00_tracks")
class Kitti00Tracks(VioProblem):
    """All real data: KITTI 00 frames 15-153 with the real tracks (module docstring)."""

    Params = Kitti00TracksParams
    name = "kitti00_tracks"
