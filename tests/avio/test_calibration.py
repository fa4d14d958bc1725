"""The ray error (avio.calibration.ray_error_deg): what the images see of a calibration error."""

from __future__ import annotations

import numpy as np

from avio.calibration import Calibration, calibration_errors, ray_error_deg
from avio.geometry import so3_exp

SIZE = (1241, 376)


def _cal(R, cx=620.0, cy=188.0, f=718.0):
    return Calibration.single(f, f, cx, cy, R, np.zeros(3))


def test_a_pure_rotation_turns_every_ray_by_its_angle():
    R = so3_exp(np.array([0.3, -1.2, 0.5]))
    rotated = so3_exp(np.array([0.01, 0.0, 0.0])) @ R
    err = ray_error_deg(_cal(rotated), _cal(R), SIZE)
    # rays turn by theta times the sine of their angle to the axis: the grid's central column is
    # within a pixel of perpendicular to the camera's x axis
    assert np.degrees(0.01) * (1 - 1e-6) < err[0] <= np.degrees(0.01) * (1 + 1e-12)
    assert ray_error_deg(_cal(R), _cal(R), SIZE)[0] == 0.0


def test_a_principal_point_shift_with_its_compensating_rotation_casts_nearly_the_same_rays():
    # 12 px of cx with the rotation about the camera's y axis that keeps the centre ray: 0.96 deg
    # of rotation error, a fraction of it in the rays (only perspective tells the two apart).
    R = so3_exp(np.array([0.3, -1.2, 0.5]))
    theta = np.arctan(12.0 / 718.0)
    best = min((ray_error_deg(_cal(so3_exp(np.array([0.0, s * theta, 0.0])) @ R, cx=632.0), _cal(R), SIZE)[0], s)
               for s in (-1.0, 1.0))
    rotation = calibration_errors(_cal(so3_exp(np.array([0.0, best[1] * theta, 0.0])) @ R, cx=632.0),
                                  _cal(R))["rotation_error_deg"][0]
    uncompensated = ray_error_deg(_cal(R, cx=632.0), _cal(R), SIZE)[0]
    assert abs(rotation - np.degrees(theta)) < 1e-9
    assert best[0] < 0.35 * rotation
    assert uncompensated > 0.9 * np.degrees(theta)
