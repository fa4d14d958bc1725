"""Errors of a batch of calibrations against a known one (the truth, or a trusted reference).

Per calibration (n,): the focal and principal-point errors (px, the larger of the two axes),
the geodesic rotation error ``||Log(R_truth^T R)||`` (deg; never per-Euler-angle errors, which
mislead near gimbal lock, PAPER.md §6), the lever-arm error ``||p_imu_cam - p_truth||`` (cm) and
the time-offset error (ms).
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
