"""studies/objective/pose_linearisation.py: the relative-pose errors round-trip, the Woodbury form is the
dense Gaussian, the lag-0 ratio finds a planted scale, and the re-scored update reproduces the
kernel's own update NLL from its record."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def test_a_drawn_pose_error_is_recovered(load_script):
    module = load_script("pose_linearisation")
    rng = np.random.default_rng(0)
    R12, R13 = Rotation.random(2, random_state=1).as_matrix()
    t12, t13 = np.array([0.1, 0.0, 0.7]), np.array([0.2, -0.05, 1.4])
    delta = 1e-2 * rng.standard_normal((5, 12))
    A, a, B, b, R23, t23 = module.perturbed(R12, t12, R13, t13, delta)
    got = module.pose_error((A, a, B, b), (R12[None], t12[None], R13[None], t13[None]))
    np.testing.assert_allclose(got, delta, atol=1e-12)
    np.testing.assert_allclose(R23, np.swapaxes(A, 1, 2) @ B, atol=1e-15)
    # the IMU-pose route: three cameras in a row give the relative poses of their differences
    R_wi = Rotation.random(3, random_state=2).as_matrix()
    p_wi = rng.standard_normal((3, 3))
    R_ci, p_ic = Rotation.random(random_state=3).as_matrix(), np.array([0.3, -0.1, 0.05])
    S12, s12, S13, s13 = module.relative_poses(R_wi, p_wi, R_ci, p_ic)
    R_wc, p_wc = R_wi @ R_ci.T, p_wi + R_wi @ p_ic
    np.testing.assert_allclose(S13, R_wc[0].T @ R_wc[2], atol=1e-14)
    np.testing.assert_allclose(s12, R_wc[0].T @ (p_wc[1] - p_wc[0]), atol=1e-14)


def test_woodbury_is_the_dense_gaussian(load_script):
    module = load_script("pose_linearisation")
    rng = np.random.default_rng(3)
    F, M = 4, module.M
    L = np.tril(rng.standard_normal((F, M, M)), -1) + np.eye(M) * rng.uniform(0.5, 2, (F, M, 1))
    r, J = rng.standard_normal((F, M)), rng.standard_normal((F, M, 12))
    A = rng.standard_normal((12, 12))
    Sigma = A @ A.T / 12 + 0.1 * np.eye(12)
    Y = np.linalg.solve(L, r[..., None])[..., 0]
    JW = np.linalg.solve(L, J)
    LD = 2 * np.log(np.abs(np.diagonal(L, axis1=1, axis2=2))).sum(axis=1)
    got = module.joint_nll(Y[None, None], JW[None, None], LD[None, None], Sigma)[0, 0]
    R = np.zeros((F * M, F * M))
    for f in range(F):
        R[f * M:(f + 1) * M, f * M:(f + 1) * M] = L[f] @ L[f].T
    S = R + J.reshape(F * M, 12) @ Sigma @ J.reshape(F * M, 12).T
    want = 0.5 * (r.ravel() @ np.linalg.solve(S, r.ravel()) + np.linalg.slogdet(S)[1])
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_the_lag0_ratio_finds_a_planted_scale(load_script):
    module = load_script("pose_linearisation")
    rng = np.random.default_rng(5)
    frames = np.arange(2, 202)
    drives = []
    for _ in range(400):
        g = rng.standard_normal((len(frames), 3)) * np.sqrt([1.0, 2.0, 4.0])
        drives.append({"frames": frames, "total_g": g, "total_h": np.ones((len(frames), 3)),
                       "partial_g": g / np.sqrt([1.0, 2.0, 4.0]), "partial_h": np.ones((len(frames), 3))})
    m = module.lag0_ratios(drives, 202)
    assert m["typical"] == 400
    np.testing.assert_allclose(m["total"], [1.0, 2.0, 4.0], rtol=0.03)
    np.testing.assert_allclose(m["partial"], 1.0, rtol=0.03)
    assert np.all(np.abs(m["partial_t"]) < 4)
    # the split of the total's lag 0 adds up: variances and covariance to the ratio, curvatures to 1
    np.testing.assert_allclose(m["split"][:3].sum(axis=0), m["total"], rtol=1e-10)
    np.testing.assert_allclose(m["split"][3:].sum(axis=0), 1.0, rtol=1e-10)


def test_the_rescored_update_is_the_kernels_own(load_script):
    module = load_script("pose_linearisation")
    out = module.drive_scores(0, 0, 0.7, {"imu_noise_on": False, "outlier_fraction": 0, "duration_s": 20.0})
    assert len(out["frames"]) > 100
    # the kernel's NLL of every update at the truth, re-computed from its record (poses, Sigma, features)
    assert out["check"] < 1e-8
    for key in ("total", "partial"):
        assert out[key + "_g"].shape == (len(out["frames"]), 3) and np.all(np.isfinite(out[key + "_h"]))
    # the calibration's reach through the estimate: the two scores differ
    assert np.abs(out["total_g"] - out["partial_g"]).max() > 1e-3


def test_the_one_frame_prediction_error_is_consistent_when_the_relative_poses_are(load_script):
    module = load_script("pose_linearisation")
    rng = np.random.default_rng(2)
    R12, R13 = Rotation.from_rotvec([[0.01, -0.03, 0.0], [0.02, -0.06, 0.01]]).as_matrix()
    t12, t13 = np.array([0.05, -0.01, 0.69]), np.array([0.11, -0.02, 1.38])
    A = rng.standard_normal((12, 12))
    Sigma = (A @ A.T / 12 + np.eye(12)) * 1e-6
    delta = rng.multivariate_normal(np.zeros(12), Sigma, size=4000)
    est = module.perturbed(R12, t12, R13, t13, delta)[:4]
    true = tuple(np.broadcast_to(x, y.shape) for x, y in zip((R12, t12, R13, t13), est))
    e2 = module.prediction_error(est, true, np.broadcast_to(Sigma, (4000, 12, 12)))
    np.testing.assert_allclose(e2.mean(axis=0), 1.0, atol=0.12)
