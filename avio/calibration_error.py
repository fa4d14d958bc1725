"""Errors of a batch of calibrations against a known one (the truth, or a trusted reference).

Per calibration (n,): the focal and principal-point errors (px, the larger of the two axes),
the geodesic rotation error ``||Log(R_truth^T R)||`` (deg; never per-Euler-angle errors, which
mislead near gimbal lock, PAPER.md §6), the lever-arm error ``||p_imu_cam - p_truth||`` (cm) and
the time-offset error (ms).

:func:`ray_error_deg` is the error the images see: the angle between the IMU-frame rays of the
same pixels under the two calibrations. A rotation of the camera about its x or y axis by theta
moves every ray almost exactly as a principal-point shift of f theta does, so a calibration can
be 1 deg and 12 px off and still cast nearly the right rays: that combination is what a drive
determines, not its two parts (README, "Identifiability").
"""

from __future__ import annotations

import numpy as np

from avio.geometry import geodesic_angle_deg
from avio.sequence import Calibration


def calibration_errors(cal: Calibration, truth: Calibration) -> dict[str, np.ndarray]:
    """(n,) errors of a batch of calibrations against ``truth`` (batch of 1); see the module."""
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
