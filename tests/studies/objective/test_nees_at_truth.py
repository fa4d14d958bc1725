"""studies/objective/nees_at_truth.py: errors are normalised in the frame the filter injects them
(the IMU frame, R_est = R_true Exp(dtheta)), and the report averages each time slice."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def test_an_imu_frame_rotation_error_is_recovered_on_its_axis_and_normalised(load_script):
    module = load_script("nees_at_truth")
    rng = np.random.default_rng(0)
    N = 5
    R_true = Rotation.random(N, random_state=1).as_matrix()
    dtheta = np.array([0.0, 0.0, 0.02])  # yaw error about the IMU's z
    R_est = R_true @ Rotation.from_rotvec(dtheta).as_matrix()
    p_true = rng.standard_normal((N, 3))
    p_est = p_true + np.array([0.3, 0.0, 0.0])
    sigma = np.full((N, 15), 0.01)
    e2 = module.normalised_errors(p_est, R_est, p_true, R_true, sigma)
    np.testing.assert_allclose(e2, np.tile([900.0, 0, 0, 0, 0, 4.0], (N, 1)), atol=1e-9)
    # the same rotation applied on the world side is not an IMU-frame yaw error
    world = module.normalised_errors(p_true, Rotation.from_rotvec(dtheta).as_matrix() @ R_true, p_true, R_true, sigma)
    assert np.abs(world[:, 3:5]).max() > 0.1
    # the velocity, when given, normalised by its own sigmas (the error state's 7th-9th)
    sigma[:, 6:9] = 0.1
    v = rng.standard_normal((N, 3))
    e2v = module.normalised_errors(p_true, R_true, p_true, R_true, sigma, v + np.array([0.0, 0.2, 0.0]), v)
    np.testing.assert_allclose(e2v, np.tile([0, 0, 0, 0, 0, 0, 0, 4.0, 0], (N, 1)), atol=1e-9)


def test_the_report_averages_each_slice_over_drives_and_frames(load_script):
    module = load_script("nees_at_truth")
    e2 = np.zeros((3, 8, 6))
    e2[:, 4:, 5] = 2.0
    lines = module.report(e2, parts=2)
    assert lines[2].startswith("| 0–3 |") and lines[2].endswith("| 0.00 |")
    assert lines[3].startswith("| 4–7 |") and lines[3].endswith("| 2.00 |")
