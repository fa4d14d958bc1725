"""studies/objective/nees_at_truth.py: errors are normalised in the frame the filter injects them
(the IMU frame, R_est = R_true Exp(dtheta)), the report averages each time slice per drive and then
over drives with an interval that finds a planted overconfidence, and the relative pose's NEES at
the updates is the recorded pose's error over its Sigma."""

from __future__ import annotations

from types import SimpleNamespace

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
    assert lines[2].startswith("| 0–3 |") and lines[2].endswith("| 0.00 [0.00–0.00] |")
    assert lines[3].startswith("| 4–7 |") and lines[3].endswith("| 2.00 [2.00–2.00] |")
    assert lines[4].startswith("| all |") and lines[4].endswith("| 1.00 [1.00–1.00] |")


def test_the_interval_over_drives_covers_a_consistent_filter_and_excludes_a_planted_overconfidence(load_script):
    module = load_script("nees_at_truth")
    rng = np.random.default_rng(3)
    # 40 drives, each the mean of 30 squared standard normal errors: a consistent filter
    consistent = (rng.standard_normal((40, 30)) ** 2).mean(axis=1)
    mean, lo, hi = module.interval(consistent)
    assert lo < 1.0 < hi and lo < mean < hi
    # the same drives with the filter claiming half the error's standard deviation: NEES 4
    mean, lo, hi = module.interval(4.0 * consistent)
    assert lo > 2.0 and hi > lo
    # two drives give no interval: the mean at both ends
    assert module.interval(np.array([0.5, 1.5])) == (1.0, 1.0, 1.0)


def test_the_relative_pose_nees_is_the_recorded_poses_error_over_its_sigma(load_script):
    module = load_script("nees_at_truth")
    rng = np.random.default_rng(4)
    N = 6
    R = np.repeat(np.eye(3)[None], N, axis=0)  # level, camera axes = world axes (R_cam_imu = I)
    p = np.cumsum(rng.standard_normal((N, 3)), axis=0)
    dof = np.zeros((1, N), int)
    dof[0, 2:] = 9
    poses = np.zeros((1, N, 3, 4, 3))
    for k in range(2, N):
        poses[0, k, :, :3, :] = R[k - 2:k + 1]
        poses[0, k, :, 3, :] = p[k - 2:k + 1]
    delta = np.array([0.02, 0.0, -0.01])
    poses[0, :, 2, 3, :] += delta  # the predicted frame's position off by delta: dt13 and dt23 carry it
    sd = 0.01
    res = SimpleNamespace(dof=dof, update_poses=poses, pose_cov=np.repeat(sd**2 * np.eye(12)[None, None], N, axis=1))
    drive = SimpleNamespace(truth=SimpleNamespace(R_world_imu=R, p_world_imu_m=p))
    camera = SimpleNamespace(R_cam_imu=np.eye(3)[None], p_imu_cam_m=np.zeros((1, 3)))
    rel = module.relative_pose_nees(res, drive, camera)
    assert rel.shape == (18,)
    np.testing.assert_allclose(rel[:9], 0.0, atol=1e-18)  # psi12, dt12, psi13 exact
    np.testing.assert_allclose(rel[9:12], (delta / sd) ** 2, rtol=1e-9)  # dt13
    assert rel[12:15].max() < 1e-18 and rel[15] > 0.1 and rel[16] < 1e-18  # psi23 exact; dt23 off along x, z
