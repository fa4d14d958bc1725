"""The update's joint innovation statistics (docs/model.md, Eqs. 44-45 and 55b, which the joint
likelihoods of avio.objectives.innovation_nll_joint sum, Eqs. 55a-b) against the dense stacked innovation
covariance ``S = H P H^T + R`` formed explicitly; and the update's score at the true pose with each
feature's Jacobian at its measured or its corrected pixels (FilterConfig.jacobian_pixels, Eq. 35a)."""

from __future__ import annotations

import numpy as np
import pytest

from avio.filter._linalg import corrected_pixels
from avio.filter.interface import Calibrations, FilterState, Settings, UpdateWorkspaces
from avio.filter.measurement import measure, measure_workspace
from avio.filter.trifocal import LANES, feature_residuals
from avio.filter.update import (
    MODE_NONE,
    NOISE_FLOOR,
    USED_RESIDUALS,
    noise_workspace,
    outlier_workspace,
    update,
    update_workspace,
)
from avio.geometry import so3_exp

#: R_cam_imu of a forward-looking camera on a car (IMU x forward, camera z forward)
R_CAM_IMU = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
INTRINSICS = (700.0, 705.0, 610.0, 185.0)


def _scene(rng, F=12, noise_px=0.7):
    """IMU poses of images 1, 2, 3 (clones k-2, k-1 and the current pose), a random SPD error
    covariance P (27, 27) and F features (F, 3, 2) px seen from them with pixel noise."""
    Rs = [so3_exp(rng.normal(0, 0.02, 3)) for _ in range(3)]
    ps = [np.array([1.2 * i, 0.05 * i, 0.01 * i]) + rng.normal(0, 0.02, 3) for i in range(3)]
    X = np.c_[rng.uniform(8, 30, F), rng.uniform(-10, 10, F), rng.uniform(-3, 3, F)]  # world, ahead
    fx, fy, cx, cy = INTRINSICS
    uv = np.empty((F, 3, 2))
    for i in range(3):
        cam = (X - ps[i]) @ Rs[i] @ R_CAM_IMU.T  # R_cam_imu R_world_imu^T (X - p), camera at the IMU
        uv[:, i, 0] = fx * cam[:, 0] / cam[:, 2] + cx
        uv[:, i, 1] = fy * cam[:, 1] / cam[:, 2] + cy
    uv += rng.normal(0, noise_px, uv.shape)
    B = rng.normal(0, 0.02, (27, 27))
    P = B @ B.T + 1e-4 * np.eye(27)
    return Rs, ps, P, uv


def _measured(Rs, ps, uv, cap=0.0, noise_too=True):
    """The measurement (r4 (4, F), J4 (4, 12, F), G4 (4, 6, F)) of features uv (F, 3, 2) px from the
    poses, the Jacobians at the measured pixels (cap 0) or the corrected ones (steps up to cap px;
    G4 too unless not noise_too, Eq. 35c)."""
    F = uv.shape[0]
    r4, J4, G4 = np.empty((4, F)), np.empty((4, 12, F)), np.empty((4, 6, F))
    C, t12, t13 = np.empty((12, 27)), np.empty(3), np.empty(3)
    measure(Rs[2], ps[2], np.zeros(3), ps[0], Rs[0], ps[1], Rs[1], np.zeros(3), 0.0, *INTRINSICS, R_CAM_IMU,
            np.zeros(3), uv, r4, J4, G4, C, t12, t13, measure_workspace(), cap, noise_too)
    return r4, J4, G4


def _dense(Rs, ps, P, uv, sigma_px):
    """NIS, log det S, the residual count and the pose's share tr(S^-1 H P H^T) (Eq. 55b) of all
    features from the explicit (3F, 3F) S = H P H^T + R."""
    F = uv.shape[0]
    r4, J4, G4 = np.empty((4, F)), np.empty((4, 12, F)), np.empty((4, 6, F))
    C, t12, t13 = np.empty((12, 27)), np.empty(3), np.empty(3)
    measure(Rs[2], ps[2], np.zeros(3), ps[0], Rs[0], ps[1], Rs[1], np.zeros(3), 0.0, *INTRINSICS, R_CAM_IMU,
            np.zeros(3), uv, r4, J4, G4, C, t12, t13, measure_workspace())
    rows = list(USED_RESIDUALS)
    r = r4[rows].T.reshape(-1)  # feature-major: (f, a)
    H = np.concatenate([J4[rows, :, f] for f in range(F)]) @ C
    R = np.zeros((3 * F, 3 * F))
    for f in range(F):
        G = G4[rows, :, f]
        R[3 * f:3 * f + 3, 3 * f:3 * f + 3] = sigma_px**2 * (G @ G.T + NOISE_FLOOR**2 * np.eye(3))
    S = H @ P @ H.T + R
    return r @ np.linalg.solve(S, r), np.linalg.slogdet(S)[1], 3 * F, np.trace(np.linalg.solve(S, H @ P @ H.T))


def test_the_updates_nis_log_det_s_and_pose_trace_are_those_of_the_dense_stacked_innovation():
    rng = np.random.default_rng(3)
    sigma = 0.7
    for _ in range(3):
        Rs, ps, P, uv = _scene(rng)
        F = uv.shape[0]
        nis_d, lds_d, m, trace_d = _dense(Rs, ps, P, uv, sigma)
        x = FilterState(R=Rs[2].copy(), p=ps[2].copy(), v=np.zeros(3), ba=np.zeros(3), bg=np.zeros(3),
                        cp0=ps[0].copy(), cR0=Rs[0].copy(), cp1=ps[1].copy(), cR1=Rs[1].copy(), P=P.copy())
        fx, fy, cx, cy = INTRINSICS
        cal = Calibrations(fx=np.array([fx]), fy=np.array([fy]), cx=np.array([cx]), cy=np.array([cy]),
                           R_cam_imu=R_CAM_IMU[None].copy(), p_imu_cam_m=np.zeros((1, 3)), td_s=np.zeros(1),
                           frozen=np.zeros(1, np.bool_))
        cfg = Settings(sigma_px=sigma, max_transfer_gain=np.inf, min_parallax_m=0.0, mode=MODE_NONE,
                       ransac_threshold_sigma=3.0, chi2_threshold=11.34, zero_velocity_sigma_mps=0.0,
                       max_variance=np.inf, max_speed_mps=np.inf, correction_cap_px=0.0,
                       correct_noise_model=False)
        ws = UpdateWorkspaces(update=update_workspace(F), measure=measure_workspace(), noise=noise_workspace(F),
                              outliers=outlier_workspace(F))
        used, rejected, nis, lds, dof, _, slots, trace = update(x, np.zeros(3), cal, 0, uv, np.ones(F, np.bool_), cfg,
                                                                ws, False, np.zeros(F, np.uint8))
        assert (used, rejected, dof, slots) == (F, 0, m, m)
        assert nis > 1.0
        np.testing.assert_allclose(nis, nis_d, rtol=1e-7)
        np.testing.assert_allclose(lds, lds_d, rtol=1e-9, atol=1e-8)
        assert 0.0 < trace < 12.0  # tr((I + A Sigma)^-1 A Sigma): at most the 12 pose errors
        np.testing.assert_allclose(trace, trace_d, rtol=1e-8)


def test_corrected_pixels_satisfy_the_used_residuals_to_first_order():
    rng = np.random.default_rng(5)
    Rs, ps, _, clean = _scene(rng, F=16, noise_px=0.0)
    uv = clean + rng.normal(0, 1.0, clean.shape)
    r4, _, G4 = _measured(Rs, ps, uv)
    rows = list(USED_RESIDUALS)
    uc = np.empty((16, 3, 2))
    assert all(corrected_pixels(uv[f], r4[:, f], G4[:, :, f], np.inf, uc[f]) for f in range(16))
    rc = _measured(Rs, ps, uc)[0]
    # second order left: a hundredth of the measured residuals
    assert np.abs(rc[rows]).max() < 0.02 * np.abs(r4[rows]).max()
    # noise-free pixels at the true poses are left where they are
    r0, _, G0 = _measured(Rs, ps, clean)
    u0 = np.empty((3, 2))
    assert corrected_pixels(clean[0], r0[:, 0], G0[:, :, 0], np.inf, u0) and np.abs(u0 - clean[0]).max() < 1e-9
    # a non-finite residual is refused, not corrected
    assert not corrected_pixels(uv[0], np.full(4, np.nan), G4[:, :, 0], np.inf, u0)
    # Eq. (35b): a step longer than the cap is shortened along itself to the cap
    step = uv[1] - uc[1]
    half = 0.5 * np.linalg.norm(step)
    assert corrected_pixels(uv[1], r4[:, 1], G4[:, :, 1], half, u0)
    np.testing.assert_allclose(uv[1] - u0, 0.5 * step, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("noise_too", [True, False])
def test_the_corrected_features_jacobians_are_those_of_each_feature_alone_at_its_corrected_pixels(noise_too):
    """measure re-linearises the corrected features LANES at a time (trifocal.features_block); each
    feature's J (and Gp with noise_too) must be the bits of the one-feature arithmetic at its own
    corrected pixels, whichever lane it took; r stays the measured pixels' innovation."""
    rng = np.random.default_rng(11)
    F = 2 * LANES + 3  # two full blocks of corrections and a partial one
    Rs, ps, _, uv = _scene(rng, F=F, noise_px=1.0)
    uv[5, 2] += (40.0, -25.0)  # an outlier: a long step, cut to the cap
    cap = 4.0
    r0, J0, G0 = _measured(Rs, ps, uv)
    r4, J4, G4, C = np.empty((4, F)), np.empty((4, 12, F)), np.empty((4, 6, F)), np.empty((12, 27))
    t12, t13, ws = np.empty(3), np.empty(3), measure_workspace()
    measure(Rs[2], ps[2], np.zeros(3), ps[0], Rs[0], ps[1], Rs[1], np.zeros(3), 0.0, *INTRINSICS, R_CAM_IMU,
            np.zeros(3), uv, r4, J4, G4, C, t12, t13, ws, cap, noise_too)
    assert r4.tobytes() == r0.tobytes()
    a12, a13 = tuple(t12), tuple(t13)
    d, R = t13 - t12, ws.R12
    a23 = tuple(R[0, j] * d[0] + R[1, j] * d[1] + R[2, j] * d[2] for j in range(3))  # trifocal.rot_t's order
    r1, J1, G1 = np.empty(4), np.empty((4, 12)), np.empty((4, 6))
    uc = np.empty((3, 2))
    for f in range(F):
        assert corrected_pixels(uv[f], r0[:, f], G0[:, :, f], cap, uc)
        feature_residuals(uc, ws.R12, a12, ws.R13, a13, ws.R23, a23, *INTRINSICS, r1, J1, G1, False)
        assert J4[:, :, f].tobytes() == J1.tobytes(), f"feature {f}: J"
        want = G1 if noise_too else G0[:, :, f]
        assert G4[:, :, f].tobytes() == want.tobytes(), f"feature {f}: Gp"


def _mean_score(Rs, ps, clean, corrected, rng, draws=1000, sigma=1.0, noise_too=True):
    """Over pixel-noise draws at the true poses: the update's mean score beta (Eq. 40), its
    chi-square against its sampling covariance (12 dof) and its size in the mean information."""
    rows = list(USED_RESIDUALS)
    betas, infos = [], []
    for _ in range(draws):
        r4, J4, G4 = _measured(Rs, ps, clean + rng.normal(0, sigma, clean.shape), 4.0 * sigma if corrected else 0.0,
                               noise_too)
        beta, A = np.zeros(12), np.zeros((12, 12))
        for f in range(clean.shape[0]):
            G, J = G4[rows, :, f], J4[rows, :, f]
            Ri = np.linalg.inv(sigma ** 2 * (G @ G.T + NOISE_FLOOR ** 2 * np.eye(3)))
            beta += J.T @ Ri @ r4[rows, f]
            A += J.T @ Ri @ J
        betas.append(beta)
        infos.append(A)
    b, V = np.mean(betas, axis=0), np.cov(np.array(betas).T) / draws
    Ap = np.linalg.pinv(np.mean(infos, axis=0), rcond=1e-10, hermitian=True)
    return b @ np.linalg.solve(V, b), b @ Ap @ b - np.trace(Ap @ V)


def test_the_score_at_the_true_pose_loses_its_bias_with_the_jacobian_at_the_corrected_pixels():
    Rs, ps, _, clean = _scene(np.random.default_rng(1), F=16, noise_px=0.0)
    chi2_m, z_m = _mean_score(Rs, ps, clean, False, np.random.default_rng(2))
    chi2_c, z_c = _mean_score(Rs, ps, clean, True, np.random.default_rng(2))
    # chi2 with 12 dof: 32.9 at 0.999. Measured: errors in variables, J shares the residuals' pixel
    # noise (217 here); corrected: no bias the 1000 draws can see (10 here)
    assert chi2_m > 100 and z_m > 0.1
    assert chi2_c < 32.9 and abs(z_c) < 0.1 * z_m


def test_the_jacobian_alone_at_the_corrected_pixels_keeps_the_measured_noise_model():
    # jacobian_pixels="corrected_jacobian" (Eq. 35c): J_f as "corrected", G_f (so R_f) as "measured"
    rng = np.random.default_rng(3)
    Rs, ps, _, uv = _scene(rng, F=16, noise_px=1.0)
    r_m, J_m, G_m = _measured(Rs, ps, uv)
    r_c, J_c, G_c = _measured(Rs, ps, uv, 4.0)
    r_j, J_j, G_j = _measured(Rs, ps, uv, 4.0, noise_too=False)
    assert np.array_equal(r_j, r_m) and np.array_equal(G_j, G_m) and np.array_equal(J_j, J_c)
    assert not np.array_equal(J_j, J_m) and not np.array_equal(G_j, G_c)


def test_the_score_at_the_true_pose_loses_its_bias_with_the_jacobian_alone_at_the_corrected_pixels():
    Rs, ps, _, clean = _scene(np.random.default_rng(1), F=16, noise_px=0.0)
    _, z_m = _mean_score(Rs, ps, clean, False, np.random.default_rng(2))
    chi2_j, z_j = _mean_score(Rs, ps, clean, True, np.random.default_rng(2), noise_too=False)
    # R_f at the measured pixels shares their noise too, but the bias is J's (Eq. 35c)
    assert chi2_j < 32.9 and abs(z_j) < 0.1 * z_m
