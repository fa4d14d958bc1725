"""Kalibr's calibration files (as EuRoC ships them): the camera of an ``imucam_chain`` yaml and the
noise figures of an ``imu_chain`` yaml. Each reader raises ``error`` (a DatasetError by default;
the EuRoC loader passes EurocDataError) naming the file, and the line or the key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from avio.calibration import Calibration
from avio.datasets._io import DatasetError
from avio.sequence import ImuNoise


def read_kalibr_yaml(path: str | Path, error: type[Exception] = DatasetError) -> dict:
    """A Kalibr/OpenCV yaml file as a dict (its ``%YAML:1.0`` directive, which PyYAML rejects,
    is dropped)."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: file not found")
    text = path.read_text()
    if text.startswith("%YAML:"):
        text = "#" + text  # a comment keeps the line numbers of the errors right
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        raise error(f"{path}{where}: not valid YAML ({getattr(err, 'problem', err)})") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def _numbers(data: dict, keys: tuple[str, ...], shape: tuple[int, ...], path: Path,
             error: type[Exception]) -> np.ndarray:
    """The finite numbers of shape ``shape`` at ``keys`` (nested) of ``data``."""
    value = data
    for i, key in enumerate(keys):
        if not isinstance(value, dict) or key not in value:
            raise error(f"{path}: missing key {'.'.join(keys[:i + 1])}")
        value = value[key]
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{path}: {'.'.join(keys)} is not numeric: {value!r}") from None
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise error(
            f"{path}: {'.'.join(keys)} must be {shape} finite numbers, got {array.shape}: {value!r}"
        )
    return array


def read_camchain(path: str | Path, camera: str = "cam0",
                  error: type[Exception] = DatasetError) -> tuple[Calibration, tuple[int, int]]:
    """``(calibration (batch of 1, time offset 0), image size (width, height) px)`` of
    ``camera`` in a Kalibr ``imucam_chain`` yaml: ``R_cam_imu = R_imu_cam^T``, ``p_imu_cam`` =
    the translation of ``T_imu_cam`` (which maps camera-frame points into the IMU frame)."""
    path = Path(path)
    data = read_kalibr_yaml(path, error)
    T = _numbers(data, (camera, "T_imu_cam"), (4, 4), path, error)
    fx, fy, cx, cy = _numbers(data, (camera, "intrinsics"), (4,), path, error)
    width, height = _numbers(data, (camera, "resolution"), (2,), path, error)
    R_imu_cam = T[:3, :3]
    if abs(np.linalg.det(R_imu_cam) - 1.0) > 1e-5 or not np.allclose(T[3], [0, 0, 0, 1]):
        raise error(f"{path}: {camera}.T_imu_cam is not a rigid transform "
                    f"(det {np.linalg.det(R_imu_cam):.6f}, last row {T[3]})")
    # The file gives 12 digits; project onto SO(3) so that R^T R = I to machine precision.
    R_cam_imu = Rotation.from_matrix(R_imu_cam.T).as_matrix()
    return Calibration.single(fx, fy, cx, cy, R_cam_imu, T[:3, 3]), (int(width), int(height))


def read_imu_noise(path: str | Path, imu: str = "imu0", error: type[Exception] = DatasetError) -> ImuNoise:
    """The Kalibr noise figures of ``imu`` (continuous-time densities, used as they are)."""
    path = Path(path)
    data = read_kalibr_yaml(path, error)
    keys = {"accel_noise": "accelerometer_noise_density", "gyro_noise": "gyroscope_noise_density",
            "accel_bias_walk": "accelerometer_random_walk", "gyro_bias_walk": "gyroscope_random_walk"}
    values = {}
    for field_name, key in keys.items():
        value = float(_numbers(data, (imu, key), (), path, error))
        if value <= 0:
            raise error(f"{path}: {imu}.{key} must be > 0, got {value}")
        values[field_name] = value
    return ImuNoise(**values)
