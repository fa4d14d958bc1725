"""Camera–IMU calibrations: the batched model, perturbations of it, and errors against a known one.

:class:`Calibration` holds ``n`` candidate calibrations (intrinsics, extrinsics, time offset).
:class:`CalibrationPerturbation` offsets a truth from a reference (simulated cameras).

Errors per calibration (n,): the focal and principal-point errors (px, the larger of the two axes),
the geodesic rotation error ``||Log(R_truth^T R)||`` (deg; never per-Euler-angle errors, which
mislead near gimbal lock, docs/model.md, "Conventions"), the lever-arm error
``||p_imu_cam - p_truth||`` (cm) and the time-offset error (ms).

:func:`ray_error_deg` is the error the images see: the angle between the IMU-frame rays of the
same pixels under the two calibrations. A rotation of the camera about its x or y axis by theta
moves every ray almost exactly as a principal-point shift of f theta does, so a calibration can
be 1 deg and 12 px off and still cast nearly the right rays: that combination is what a drive
determines, not its two parts (studies/identifiability/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avio.errors import AvioError
from avio.geometry import geodesic_angle_deg, so3_exp


class CalibrationError(AvioError):
    """A calibration batch is malformed or used wrongly; the message says what."""


@dataclass(frozen=True)
class Calibration:
    """Camera intrinsics and camera–IMU extrinsics of ``n`` candidate calibrations.

    fx_px, fy_px, cx_px, cy_px: (n,) pinhole intrinsics in pixels (skew 0; the paper's Eq. 8,
        docs/model.md Eq. 5).
    R_cam_imu: (n, 3, 3) maps IMU-frame vectors into the camera frame (the paper's Eq. 9 writes it
        with ZYX Euler angles, docs/model.md Eq. 4; the convention: Eq. 1).
    p_imu_cam_m: (n, 3) camera origin expressed in the IMU frame, metres (the paper's Eq. 10).
    time_offset_s: (n,) camera clock offset: a frame stamped t was exposed at IMU time
        ``t + time_offset_s`` (docs/model.md, Eq. 19).
    """

    fx_px: np.ndarray
    fy_px: np.ndarray
    cx_px: np.ndarray
    cy_px: np.ndarray
    R_cam_imu: np.ndarray
    p_imu_cam_m: np.ndarray
    time_offset_s: np.ndarray

    @classmethod
    def single(
        cls,
        fx_px: float,
        fy_px: float,
        cx_px: float,
        cy_px: float,
        R_cam_imu: np.ndarray,
        p_imu_cam_m: np.ndarray,
        time_offset_s: float = 0.0,
    ) -> "Calibration":
        """One calibration as a batch of size 1."""
        return cls(
            fx_px=np.array([fx_px], float),
            fy_px=np.array([fy_px], float),
            cx_px=np.array([cx_px], float),
            cy_px=np.array([cy_px], float),
            R_cam_imu=np.asarray(R_cam_imu, float).reshape(1, 3, 3),
            p_imu_cam_m=np.asarray(p_imu_cam_m, float).reshape(1, 3),
            time_offset_s=np.array([time_offset_s], float),
        )

    @classmethod
    def stack(cls, calibrations: list["Calibration"]) -> "Calibration":
        """Concatenate batches along the calibration axis."""
        names = [f for f in cls.__dataclass_fields__]
        return cls(**{k: np.concatenate([getattr(c, k) for c in calibrations]) for k in names})

    def __len__(self) -> int:
        return len(self.fx_px)

    def __getitem__(self, index) -> "Calibration":
        """Sub-batch (an int index keeps the batch axis, with size 1)."""
        if isinstance(index, (int, np.integer)):
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        names = [f for f in self.__dataclass_fields__]
        return Calibration(**{k: getattr(self, k)[index] for k in names})

    def repeat(self, n: int) -> "Calibration":
        """A batch of size 1 repeated ``n`` times."""
        if len(self) != 1:
            raise CalibrationError(f"repeat() needs a batch of size 1, got {len(self)}")
        names = [f for f in self.__dataclass_fields__]
        return Calibration(
            **{k: np.repeat(getattr(self, k), n, axis=0) for k in names}
        )

    @property
    def K(self) -> np.ndarray:
        """(n, 3, 3) camera matrices."""
        n = len(self)
        K = np.zeros((n, 3, 3))
        K[:, 0, 0] = self.fx_px
        K[:, 1, 1] = self.fy_px
        K[:, 0, 2] = self.cx_px
        K[:, 1, 2] = self.cy_px
        K[:, 2, 2] = 1.0
        return K


@dataclass(frozen=True)
class CalibrationPerturbation:
    """Offset of a truth calibration from a reference (simulated camera only).

    d_intrinsics_px: (4,) added to (fx, fy, cx, cy), pixels.
    d_rotvec_cam_rad: (3,) rotation vector in the camera frame:
        ``R_cam_imu_truth = exp(d_rotvec) · R_cam_imu_ref``.
    d_p_imu_cam_m: (3,) added to the camera origin in the IMU frame, metres.
    time_offset_s: truth camera clock offset, seconds.
    """

    d_intrinsics_px: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    d_rotvec_cam_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    d_p_imu_cam_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    time_offset_s: float = 0.0

    def apply(self, reference: Calibration) -> Calibration:
        """The perturbed calibration, batch of 1."""
        dk = np.asarray(self.d_intrinsics_px, float)
        return Calibration.single(
            reference.fx_px[0] + dk[0], reference.fy_px[0] + dk[1],
            reference.cx_px[0] + dk[2], reference.cy_px[0] + dk[3],
            so3_exp(np.asarray(self.d_rotvec_cam_rad, float)) @ reference.R_cam_imu[0],
            reference.p_imu_cam_m[0] + np.asarray(self.d_p_imu_cam_m, float),
            reference.time_offset_s[0] + self.time_offset_s,
        )


def calibration_errors(cal: Calibration, truth: Calibration) -> dict[str, np.ndarray]:
    """(n,) errors of a batch of calibrations against ``truth`` (batch of 1); see the module
    (docs/model.md, Eq. 6)."""
    return {
        "focal_error_px": np.maximum(abs(cal.fx_px - truth.fx_px[0]), abs(cal.fy_px - truth.fy_px[0])),
        "principal_point_error_px": np.maximum(abs(cal.cx_px - truth.cx_px[0]), abs(cal.cy_px - truth.cy_px[0])),
        "rotation_error_deg": geodesic_angle_deg(truth.R_cam_imu[0][None], cal.R_cam_imu),
        "translation_error_cm": 100.0 * np.linalg.norm(cal.p_imu_cam_m - truth.p_imu_cam_m[0], axis=1),
        "time_offset_error_ms": 1e3 * abs(cal.time_offset_s - truth.time_offset_s[0]),
    }


def ray_error_deg(cal: Calibration, truth: Calibration, image_size_px, grid: int = 3) -> np.ndarray:
    """(n,) largest angle (deg) between ``R_imu_cam K^-1 [u, v, 1]`` under ``cal`` and under
    ``truth`` (batch of 1) over a grid x grid set of pixels spanning 10-90 % of the image
    (image_size_px: (width, height))."""
    w, h = image_size_px
    u, v = np.meshgrid(np.linspace(0.1, 0.9, grid) * w, np.linspace(0.1, 0.9, grid) * h)
    u, v = u.ravel(), v.ravel()

    def rays(c: Calibration) -> np.ndarray:  # (n, P, 3) unit rays in the IMU frame
        d = np.stack([(u - c.cx_px[:, None]) / c.fx_px[:, None], (v - c.cy_px[:, None]) / c.fy_px[:, None],
                      np.ones((len(c), u.size))], axis=-1)
        d = np.einsum("nji,npj->npi", c.R_cam_imu, d)  # R_cam_imu^T: camera -> IMU frame
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    a, b = rays(cal), rays(truth)
    # atan2 of |a x b| and a . b: accurate for tiny angles, where arccos of the dot is not
    angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
    return np.degrees(angle).max(axis=1)
