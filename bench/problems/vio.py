"""The paper's objective as registered problems: VIO position RMSE (Eq. 11–12) of a batch of
candidate calibrations, on simulated drives, KITTI 00 (real IMU) and KITTI raw drives.

Each problem has a calibration drive (the objective) and optionally a held-out drive (never
seen by the optimiser; used by ``bench.tables`` for the paper's Tables 2–3). Beside f, every
evaluation reports, uncharged, the calibration error against the truth when the truth is
known: focal and principal-point errors (px, the larger of the two axes), the geodesic
rotation error (deg), the translation error (cm) and, with a time offset, its error (ms).
"""

from __future__ import annotations

import os
from dataclasses import fields
from pathlib import Path

import numpy as np

from avio.filter import FilterConfig, FilterResult, prepare, run
from avio.geometry import geodesic_angle_deg
from avio.metrics import pose_errors, position_rmse_objective
from avio.sequence import Calibration, ImuNoise, Sequence
from bench.calibration_space import make_calibration_space
from bench.problems.base import ProblemError, register

REPO_ROOT = Path(__file__).resolve().parents[2]


def default_data_dir(data_dir: str | None = None) -> Path:
    """``data_dir``, else ``$AVIO_DATA``, else ``../shared/data`` beside the repository."""
    if data_dir:
        return Path(data_dir).expanduser()
    return Path(os.environ.get("AVIO_DATA", REPO_ROOT.parent / "shared" / "data"))


def _tuples(d: dict) -> dict:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in (d or {}).items()}


def filter_config(params: dict | None) -> FilterConfig:
    """A FilterConfig from a config dict; unknown keys are an error naming the valid ones."""
    valid = {f.name for f in fields(FilterConfig)}
    unknown = set(params or {}) - valid
    if unknown:
        raise ProblemError(f"filter: unknown setting(s) {sorted(unknown)}; valid: {', '.join(sorted(valid))}")
    return FilterConfig(**_tuples(params))


def calibration_errors(cal: Calibration, truth: Calibration) -> dict[str, np.ndarray]:
    """(n,) errors of a batch of calibrations against a truth (batch of 1)."""
    errors = {
        "focal_error_px": np.maximum(abs(cal.fx_px - truth.fx_px[0]), abs(cal.fy_px - truth.fy_px[0])),
        "principal_point_error_px": np.maximum(abs(cal.cx_px - truth.cx_px[0]), abs(cal.cy_px - truth.cy_px[0])),
        "rotation_error_deg": geodesic_angle_deg(truth.R_cam_imu[0][None], cal.R_cam_imu),
        "translation_error_cm": 100.0 * np.linalg.norm(cal.p_imu_cam_m - truth.p_imu_cam_m[0], axis=1),
    }
    errors["time_offset_error_ms"] = 1e3 * abs(cal.time_offset_s - truth.time_offset_s[0])
    return errors


class VioRmseProblem:
    """Position RMSE of the VIO over ``sequence`` for a batch of calibrations.

    space: "paper" (Table 1, ZYX Euler) or "local" (rotation vector and offsets around the
    reference); with_time_offset adds the camera–IMU time offset ``td`` (s).
    """

    def __init__(self, name: str, sequence: Sequence, holdout: Sequence | None = None, space: str = "paper",
                 with_time_offset: bool = False, bounds: dict | None = None, filter: dict | None = None,
                 divergence_penalty_m: float = 1000.0) -> None:
        self.name = name
        self.sequence, self.holdout = sequence, holdout
        self.calibration_space = make_calibration_space(space, sequence.reference_calibration,
                                                        with_time_offset=with_time_offset, bounds=bounds)
        self.space = self.calibration_space.space
        self.filter_config = filter_config(filter)
        self.divergence_penalty_m = float(divergence_penalty_m)
        self._prepared = {id(sequence): prepare(sequence, self.filter_config)}
        truth = sequence.truth_calibration
        self.truth = None if truth is None else self.calibration_space.encode(truth)[0]
        # the exact calibrations: a round trip through Euler angles near gimbal lock moves R by ~1e-7
        anchors = Calibration.stack([sequence.reference_calibration] + ([] if truth is None else [truth]))
        f_anchor, _ = self._score(anchors, sequence)
        self.f_reference = float(f_anchor[0])
        self.f_truth = None if self.truth is None else float(f_anchor[1])

    @property
    def identity(self) -> dict:
        return {"sequence": self.sequence.name, "n_frames": self.sequence.n_frames,
                "sequence_meta": {k: v for k, v in self.sequence.meta.items() if np.ndim(v) == 0},
                "holdout": None if self.holdout is None else self.holdout.name}

    def run_filter(self, calibrations: Calibration, sequence: Sequence | None = None) -> FilterResult:
        """All filters of the batch over ``sequence`` (default: the calibration drive)."""
        sequence = sequence or self.sequence
        if id(sequence) not in self._prepared:
            self._prepared[id(sequence)] = prepare(sequence, self.filter_config)
        return run(sequence, calibrations, self.filter_config, prepared=self._prepared[id(sequence)])

    def _score(self, cal: Calibration, sequence: Sequence) -> tuple[np.ndarray, FilterResult]:
        result = self.run_filter(cal, sequence)
        return position_rmse_objective(result, sequence.truth, self.divergence_penalty_m), result

    def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """f (n,) = position RMSE (m, Eq. 11–12; diverged filters get the documented penalty),
        and metrics (n,): trajectory errors, divergence flags, calibration errors when known."""
        X = self.space.check(X)
        cal = self.calibration_space.decode(X)
        f, result = self._score(cal, self.sequence)
        errors = pose_errors(result, self.sequence.truth)
        metrics = {"diverged": result.diverged.astype(float),
                   "velocity_rmse_mps": errors["velocity_rmse"],
                   "attitude_rmse_deg": errors["attitude_rmse"]}
        if self.sequence.truth_calibration is not None:
            errs = calibration_errors(cal, self.sequence.truth_calibration)
            if "td" not in self.space.names:
                errs.pop("time_offset_error_ms")
            metrics.update(errs)
        return f, metrics


# --- the registered problems -------------------------------------------------------------


def _synthetic_sequence(drive: str, data_seed: int, sim: dict) -> Sequence:
    from avio.simulator import SimConfig, simulate

    presets = {"paper_540m": SimConfig.paper_540m, "paper_928m": SimConfig.paper_928m}
    if drive not in presets:
        raise ProblemError(f"synthetic: unknown drive {drive!r}; valid: {', '.join(presets)}")
    sim = _tuples(sim)
    if "imu_noise" in sim:
        sim["imu_noise"] = ImuNoise(**sim["imu_noise"])
    config = presets[drive](**sim)
    config.validate()
    return simulate(config, data_seed)


@register("synthetic")
class Synthetic(VioRmseProblem):
    """A simulated KITTI-like drive with known truth (default: the paper's ~540 m city drive),
    held-out drive the ~928 m one; ``data_seed`` fixes the world, the noise and the truth."""

    def __init__(self, drive: str = "paper_540m", holdout: str | None = "paper_928m", data_seed: int = 0,
                 sim: dict | None = None, **problem) -> None:
        sim = sim or {}
        sequence = _synthetic_sequence(drive, data_seed, sim)
        held = None if not holdout else _synthetic_sequence(holdout, data_seed + 1, sim)
        super().__init__("synthetic", sequence, held, **problem)

    @staticmethod
    def preflight(drive: str = "paper_540m", holdout: str | None = "paper_928m", data_seed: int = 0,
                  sim: dict | None = None, space: str = "paper", with_time_offset: bool = False,
                  bounds: dict | None = None, filter: dict | None = None, **_) -> None:
        from avio.reference import kitti_2011_10_03_calibration
        from avio.simulator import SimConfig

        for name in (drive, holdout):
            if name and name not in ("paper_540m", "paper_928m"):
                raise ProblemError(f"unknown drive {name!r}; valid: paper_540m, paper_928m")
        try:
            SimConfig.paper_540m(**_tuples(sim)).validate()
        except TypeError as err:
            raise ProblemError(f"sim: {err}") from None
        filter_config(filter)
        make_calibration_space(space, kitti_2011_10_03_calibration(), with_time_offset, bounds=bounds)


def _kitti00_sequence(data_dir: Path, window, camera: str, data_seed: int, camera_params: dict) -> Sequence:
    from avio.kitti00 import WINDOWS, CalibrationPerturbation, load_kitti00

    if isinstance(window, str):
        if window not in WINDOWS:
            raise ProblemError(f"kitti00: unknown window {window!r}; valid: {', '.join(WINDOWS)} or [first, last]")
        first, last = WINDOWS[window]
    else:
        first, last = (int(v) for v in window)
    params = dict(camera_params)
    if "truth_perturbation" in params:
        params["truth_perturbation"] = CalibrationPerturbation(**_tuples(params["truth_perturbation"]))
    return load_kitti00(data_dir / "kitti00", first, last, camera=camera, seed=data_seed, **params)


def _check_kitti00_files(data_dir: Path) -> None:
    from avio.kitti00 import read_kitti00

    read_kitti00(data_dir / "kitti00")  # parses and validates every file (cached per process)


@register("kitti00")
class Kitti00(VioRmseProblem):
    """KITTI sequence 00 with its real 100 Hz IMU and ground truth, and a camera simulated through
    the ground-truth poses with a known truth calibration. The ground truth is in the rectified
    cam0 frame, so the reference is the rectified calibration; 0.65 deg of rectification moves its
    ZYX roll from 119.5 to 173 deg (gimbal lock), outside Table 1, hence the default local space. ``window``: a named window
    ("paper_540m" = frames 15–796, "paper_928m" = 2404–3553) or [first, last]."""

    def __init__(self, data_dir: str | None = None, window="paper_540m", holdout="paper_928m",
                 data_seed: int = 0, camera: dict | None = None, **problem) -> None:
        root = default_data_dir(data_dir)
        sequence = _kitti00_sequence(root, window, "simulated", data_seed, camera or {})
        held = None if not holdout else _kitti00_sequence(root, holdout, "simulated", data_seed + 1, camera or {})
        super().__init__("kitti00", sequence, held, **{"space": "local", **problem})

    @staticmethod
    def preflight(data_dir: str | None = None, space: str = "local", with_time_offset: bool = False,
                  bounds: dict | None = None, filter: dict | None = None, **_) -> None:
        from avio.reference import kitti_2011_10_03_calibration

        _check_kitti00_files(default_data_dir(data_dir))
        filter_config(filter)
        make_calibration_space(space, kitti_2011_10_03_calibration(rectified=True), with_time_offset,
                               bounds=bounds)


@register("kitti00_tracks")
class Kitti00Tracks(VioRmseProblem):
    """All real data: KITTI 00 frames 15–153 with the real IMU, ground truth and the real feature
    tracks of ``VO_stereo_factors00.txt``. The truth calibration is unknown; the reference is
    the rectified KITTI calibration."""

    def __init__(self, data_dir: str | None = None, window=(15, 153), data_seed: int = 0,
                 camera: dict | None = None, **problem) -> None:
        sequence = _kitti00_sequence(default_data_dir(data_dir), list(window), "real_tracks", data_seed,
                                     camera or {})
        super().__init__("kitti00_tracks", sequence, None, **{"space": "local", **problem})

    preflight = Kitti00.preflight


@register("kitti_raw")
class KittiRaw(VioRmseProblem):
    """A synced KITTI raw drive (``path=.../2011_10_03_drive_0027_sync``): OXTS truth and IMU,
    the calib files' reference calibration, grayscale image_00 tracked once by the KLT front end
    and cached under ``cache_dir``. The truth calibration is unknown."""

    def __init__(self, path: str, calib_dir: str | None = None, frontend: dict | None = None,
                 cache_dir: str = ".cache/frontend", **problem) -> None:
        from avio.cache import sequence_with_tracks
        from avio.frontend import FrontendConfig
        from avio.kitti_raw import load_kitti_raw

        sequence = load_kitti_raw(path, calib_dir)
        sequence = sequence_with_tracks(sequence, FrontendConfig(**_tuples(frontend)), cache_dir)
        super().__init__("kitti_raw", sequence, None, **{"space": "local", **problem})

    @staticmethod
    def preflight(path: str | None = None, calib_dir: str | None = None, space: str = "local",
                  with_time_offset: bool = False, bounds: dict | None = None, filter: dict | None = None,
                  **_) -> None:
        from avio.kitti_raw import reference_calibration

        if not path:
            raise ProblemError("kitti_raw needs problem.params.path=.../<date>_drive_<nnnn>_sync")
        drive = Path(path)
        if not (drive / "oxts" / "data").is_dir():
            raise ProblemError(f"{drive}: not a KITTI raw drive folder (no oxts/data)")
        reference, _ = reference_calibration(Path(calib_dir) if calib_dir else drive.parent)
        filter_config(filter)
        make_calibration_space(space, reference, with_time_offset, bounds=bounds)


__all__ = ["Kitti00", "Kitti00Tracks", "KittiRaw", "Synthetic", "VioRmseProblem", "calibration_errors",
           "default_data_dir", "filter_config"]
