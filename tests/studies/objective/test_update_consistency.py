"""studies/objective/update_consistency.py: one update from a consistent prior leaves a consistent
posterior where it is nearly linear, and the noise model taken at the measured pixels is the
default."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def test_one_update_from_a_consistent_prior_is_consistent_at_small_noise(load_script):
    module = load_script("update_consistency")
    pl = load_script("pose_linearisation")
    sim = {"imu_noise_on": False, "outlier_fraction": 0, "duration_s": 20.0}
    camera, ((_, _, res), (clean, prep, res0)) = pl.drive_updates(0, 0, 0.1, sim)
    k = int(np.nonzero(res.dof[0] > 0)[0][100])
    j = prep.triplet_of_frame[k]
    uv = prep.uv_px[j][prep.valid[j] & res0.used[0, j]]
    t = k + np.array([-2, -1, 0])
    true = pl.relative_poses(clean.truth.R_world_imu[t], clean.truth.p_world_imu_m[t], camera.R_cam_imu[0],
                             camera.p_imu_cam_m[0])
    cal = (camera.fx_px[0], camera.fy_px[0], camera.cx_px[0], camera.cy_px[0])
    rng = np.random.default_rng(0)
    nees = module.posterior_nees(uv, true, res.pose_cov[0, k], cal, 0.1, 800, rng, False)
    assert np.all((nees > 0.8) & (nees < 1.25)), nees


def test_the_noise_model_at_the_same_pixels_is_the_default(load_script):
    pl = load_script("pose_linearisation")
    rng = np.random.default_rng(1)
    R12, R13 = Rotation.from_rotvec([[0, -0.02, 0], [0, -0.04, 0]]).as_matrix()
    poses = pl.perturbed(R12, np.array([0.0, 0.0, 0.7]), R13, np.array([0.0, 0.0, 1.4]), np.zeros((2, 12)))
    uv = np.array([[[400.0, 150.0], [395.0, 152.0], [389.0, 154.0]], [[800.0, 250.0], [810.0, 255.0], [821.0, 261.0]]])
    uv = uv[None] + rng.normal(0, 0.5, (2, 2, 3, 2))
    cal = np.array([[718.856, 718.856, 607.19, 185.22]])
    outs = []
    for other in (None, uv.copy()):
        Y, JW, LD = np.empty((2, 1, 2, pl.M)), np.empty((2, 1, 2, pl.M, 12)), np.empty((2, 1, 2))
        pl._whitened(uv, *poses, cal, 0.7, np.array(pl.USED), Y, JW, LD, other)
        outs.append((Y, JW, LD))
    for a, b in zip(*outs):
        np.testing.assert_array_equal(a, b)
