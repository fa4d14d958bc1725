"""End-to-end properties of the batched trifocal VIO filter on a small analytic drive.

The drive is made here (a few lines, noiseless IMU from analytic derivatives, landmarks
projected with the truth calibration), so these tests do not depend on the simulator.
"""

from __future__ import annotations

import numpy as np
import pytest

from avio.calibration import Calibration
from avio.filter.batch import run
from avio.filter.config import FilterConfig, FilterError
from avio.filter.prepare import prepare
from avio.geometry import euler_zyx_deg_to_matrix, so3_exp
from avio.metrics import position_rmse_objective
from avio.reference import kitti_2011_10_03_calibration
from avio.sequence import GroundTruth, ImuSamples, Sequence, TripletTracks

G = np.array([0.0, 0.0, -9.81])


def _motion(t, radius=40.0, speed=7.0):
    """Analytic car-like motion: circle in x-y, gentle heave, roll and pitch oscillations.
    Returns p, v, a (m, 3), R_world_imu (m, 3, 3), gyro (m, 3) body rates."""
    w = speed / radius
    p = np.stack([radius * np.sin(w * t), radius * (1 - np.cos(w * t)), 0.3 * np.sin(0.8 * t)], -1)
    v = np.stack([radius * w * np.cos(w * t), radius * w * np.sin(w * t), 0.24 * np.cos(0.8 * t)], -1)
    a = np.stack([-radius * w**2 * np.sin(w * t), radius * w**2 * np.cos(w * t),
                  -0.192 * np.sin(0.8 * t)], -1)
    yaw, yawd = w * t, w + 0 * t
    pitch, pitchd = 0.03 * np.sin(1.1 * t), 0.033 * np.cos(1.1 * t)
    roll, rolld = 0.04 * np.sin(0.9 * t + 0.5), 0.036 * np.cos(0.9 * t + 0.5)
    R = euler_zyx_deg_to_matrix(np.degrees(roll), np.degrees(pitch), np.degrees(yaw))
    gyro = np.stack([rolld - yawd * np.sin(pitch),
                     pitchd * np.cos(roll) + yawd * np.cos(pitch) * np.sin(roll),
                     -pitchd * np.sin(roll) + yawd * np.cos(pitch) * np.cos(roll)], -1)
    return p, v, a, R, gyro


def make_circle_sequence(n_frames=60, seed=0, pixel_noise_px=0.0, n_feat=30, outlier_fraction=0.0,
                         calibration: Calibration | None = None) -> Sequence:
    """A small drive with tracks projected through ``calibration`` (default: the KITTI reference)."""
    rng = np.random.default_rng(seed)
    cal = calibration if calibration is not None else kitti_2011_10_03_calibration()
    frame_t = 0.1 * np.arange(n_frames) + 0.05
    imu_t = np.arange(0.0, frame_t[-1] + 0.06, 0.01)
    _, _, a, R, gyro = _motion(imu_t)
    accel = np.einsum("mji,mj->mi", R, a - G)
    p_f, v_f, _, R_f, _ = _motion(frame_t)
    # Landmarks on a ring around the circle (radius 40 m), 20 m either side, heights -1.5..6 m.
    L = 4000
    ang = rng.uniform(0, 2 * np.pi, L)
    rad = 40.0 + rng.choice([-1, 1], L) * rng.uniform(6, 25, L)
    X = np.stack([rad * np.sin(ang), 40.0 - rad * np.cos(ang), rng.uniform(-1.5, 6, L)], -1)
    K = cal.K[0]
    R_wc = R_f @ cal.R_cam_imu[0].T
    p_wc = p_f + R_f @ cal.p_imu_cam_m[0]
    Xc = np.einsum("nji,nlj->nli", R_wc, X[None] - p_wc[:, None])  # (N, L, 3)
    uvw = Xc @ K.T
    uv = uvw[..., :2] / uvw[..., 2:]
    vis = (Xc[..., 2] > 2) & (Xc[..., 2] < 60) & (uv[..., 0] > 0) & (uv[..., 0] < 1241) \
        & (uv[..., 1] > 0) & (uv[..., 1] < 376)
    n_trip = n_frames - 2
    uv_t = np.zeros((n_trip, n_feat, 3, 2))
    valid = np.zeros((n_trip, n_feat), bool)
    for j in range(n_trip):
        ids = np.nonzero(vis[j] & vis[j + 1] & vis[j + 2])[0]
        ids = rng.permutation(ids)[:n_feat]
        uv_t[j, :len(ids)] = np.stack([uv[j, ids], uv[j + 1, ids], uv[j + 2, ids]], axis=1)
        valid[j, :len(ids)] = True
    uv_t += rng.normal(0, pixel_noise_px, uv_t.shape) * valid[..., None, None]
    if outlier_fraction:
        bad = valid & (rng.random(valid.shape) < outlier_fraction)
        uv_t[bad, 2] += rng.uniform(15, 40, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
    tracks = TripletTracks(np.arange(2, n_frames), uv_t, valid)
    return Sequence(
        name=f"circle-{seed}", imu=ImuSamples(imu_t, accel, gyro), frame_t_s=frame_t,
        truth=GroundTruth(p_f, R_f, v_f), reference_calibration=cal, tracks=tracks,
        truth_calibration=cal, gravity_world_mps2=G,
    )


def perturbed(cal: Calibration, n: int, seed: int, scale: float = 1.0) -> Calibration:
    """n calibrations around ``cal``: a few pixels, ~1 degree, a few centimetres, ms offsets."""
    rng = np.random.default_rng(seed)
    out = cal.repeat(n)
    return Calibration(
        fx_px=out.fx_px + scale * rng.normal(0, 3, n), fy_px=out.fy_px + scale * rng.normal(0, 3, n),
        cx_px=out.cx_px + scale * rng.normal(0, 3, n), cy_px=out.cy_px + scale * rng.normal(0, 3, n),
        R_cam_imu=so3_exp(scale * rng.normal(0, 0.01, (n, 3))) @ out.R_cam_imu,
        p_imu_cam_m=out.p_imu_cam_m + scale * rng.normal(0, 0.03, (n, 3)),
        time_offset_s=scale * rng.normal(0, 0.003, n),
    )


@pytest.fixture(scope="module")
def noiseless():
    return make_circle_sequence(n_frames=60)


def test_imu_only_dead_reckoning_is_exact_on_noiseless_imu(noiseless):
    seq = noiseless.with_tracks(TripletTracks(np.zeros(0, int), np.zeros((0, 1, 3, 2)), np.zeros((0, 1), bool)))
    res = run(seq, seq.truth_calibration)
    err = np.linalg.norm(res.p_world_imu_m[0] - seq.truth.p_world_imu_m, axis=-1)
    assert err.max() < 1e-3


def test_noiseless_truth_calibration_tracks_truth(noiseless):
    res = run(noiseless, noiseless.truth_calibration)
    err = np.linalg.norm(res.p_world_imu_m[0] - noiseless.truth.p_world_imu_m, axis=-1)
    assert not res.diverged[0]
    assert err.max() < 0.05
    assert res.n_updates[0, 2:].mean() > 8


def test_batch_equals_single_runs():
    seq = make_circle_sequence(n_frames=40, seed=1, pixel_noise_px=0.5, outlier_fraction=0.05)
    cals = perturbed(seq.truth_calibration, 4, seed=2)
    cfg = FilterConfig()
    prep = prepare(seq, cfg)
    batch = run(seq, cals, cfg, prep)
    for i in range(len(cals)):
        single = run(seq, cals[i], cfg, prep)
        np.testing.assert_allclose(batch.p_world_imu_m[i], single.p_world_imu_m[0], atol=1e-9, rtol=0)
        np.testing.assert_allclose(batch.R_world_imu[i], single.R_world_imu[0], atol=1e-9, rtol=0)
        np.testing.assert_allclose(batch.v_world_imu_mps[i], single.v_world_imu_mps[0], atol=1e-9, rtol=0)
        np.testing.assert_array_equal(batch.n_updates[i], single.n_updates[0])


def test_wrong_calibration_gives_larger_objective():
    seq = make_circle_sequence(n_frames=60, seed=3, pixel_noise_px=0.5)
    truth = seq.truth_calibration
    wrong = Calibration.stack([
        truth,
        Calibration.single(truth.fx_px[0] * 1.04, truth.fy_px[0] * 1.04, truth.cx_px[0] + 15,
                           truth.cy_px[0] - 12, so3_exp(np.array([0.03, -0.02, 0.03])) @ truth.R_cam_imu[0],
                           truth.p_imu_cam_m[0] + np.array([0.3, -0.2, 0.2])),
    ])
    f = position_rmse_objective(run(seq, wrong), seq.truth)
    assert f[1] > 1.5 * f[0]


def test_divergence_is_flagged_penalised_and_isolated(noiseless):
    truth = noiseless.truth_calibration
    cals = Calibration.stack([truth, truth, truth, truth])
    # fx of 1 px makes every update nonsense (without outlier rejection the state runs away);
    # a non-finite lever arm is flagged before the first frame.
    cals.fx_px[1] = 1.0
    cals.p_imu_cam_m[2] = np.nan
    cfg = FilterConfig(outlier_rejection="none", divergence_max_speed_mps=15.0)  # truth: 7 m/s
    res = run(noiseless, cals, cfg)
    single = run(noiseless, truth, cfg)
    assert res.diverged.tolist() == [False, True, True, False]
    assert res.diverged_at_frame[1] >= 2 and res.diverged_at_frame[2] == 0
    assert res.diverged_at_frame[0] == res.diverged_at_frame[3] == -1
    np.testing.assert_allclose(res.p_world_imu_m[[0, 3]], np.repeat(single.p_world_imu_m, 2, 0), atol=1e-12)
    assert np.all(np.isfinite(res.p_world_imu_m)) and np.all(np.isfinite(res.R_world_imu))
    # Frozen: the estimate stays at the last good frame.
    k = res.diverged_at_frame[1]
    np.testing.assert_array_equal(res.p_world_imu_m[1, k:], np.repeat(res.p_world_imu_m[1, k - 1:k], 60 - k, 0))
    f = position_rmse_objective(res, noiseless.truth, divergence_penalty_m=1000.0)
    assert np.all(np.isfinite(f)) and f[1] >= 1000.0 and f[2] > f[1] and f[0] < 0.1


def test_missing_tracks_is_an_error(noiseless):
    from dataclasses import replace

    with pytest.raises(FilterError, match="no feature tracks"):
        run(replace(noiseless, tracks=None), noiseless.truth_calibration)


def test_bad_outlier_mode_is_an_error():
    with pytest.raises(FilterError, match="outlier_rejection"):
        FilterConfig(outlier_rejection="magic")
    with pytest.raises(FilterError, match=r"jacobian_pixels must be one of \('measured', 'corrected', 'corrected_jacobian'\), got 'true'"):
        FilterConfig(jacobian_pixels="true")


def test_noiseless_simulated_city_drive_tracks_truth():
    from avio.sim.simulator import SimConfig, simulate

    seq = simulate(SimConfig.paper_540m(duration_s=12.0, imu_noise_on=False, pixel_noise_px=0.0,
                                        outlier_fraction=0.0), seed=0)
    res = run(seq, seq.truth_calibration)
    err = np.linalg.norm(res.p_world_imu_m[0] - seq.truth.p_world_imu_m, axis=-1)
    assert not res.diverged[0] and err.max() < 0.05


@pytest.mark.data
def test_kitti00_paper_window_with_truth_calibration(shared_data):
    """Real IMU, simulated camera, frames 15-796 (542 m): the paper's VIO got 4.89 m with the
    reference calibration; ours with the truth calibration stays below that (bench: ~4 m)."""
    from avio.datasets.kitti00 import load_kitti00

    seq = load_kitti00(shared_data / "kitti00", 15, 796, seed=1)
    cals = Calibration.stack([seq.truth_calibration, perturbed(seq.truth_calibration, 1, seed=0, scale=3.0)])
    f = position_rmse_objective(run(seq, cals), seq.truth)
    assert f[0] < 4.9
    assert f[1] > f[0]


# --- The compiled per-filter steps (avio/filter/kernels.py, update.py) against their numpy definitions. ---


def _spd(rng, d):
    A = rng.normal(size=(d, d))
    return A @ A.T + d * np.eye(d)


def test_kernel_covariance_prediction_is_f_p_ft_plus_q():
    from avio.filter.kernels import propagate_covariance

    rng = np.random.default_rng(0)
    P, Q = _spd(rng, 27), _spd(rng, 15) * 1e-3
    # Phi with the zero pattern of Eq. (16), which the kernel's sums rely on (kernels._phi_product).
    pattern = np.eye(15, dtype=bool)
    pattern[0:3, 3:6] = pattern[0:3, 9:15] = pattern[3:6, 3:6] = pattern[3:6, 12:15] = True
    pattern[6:9, 3:6] = pattern[6:9, 9:15] = True
    for i in range(3):
        pattern[i, 6 + i] = True
    Phi = np.where(pattern, np.eye(15) + 0.1 * rng.normal(size=(15, 15)), 0.0)
    Fm = np.eye(27)
    Fm[:15, :15] = Phi
    Fm[:15, 15:] = 0.0
    want = Fm @ P @ Fm.T
    want[:15, :15] += Q
    got = P.copy()
    propagate_covariance(got, Phi, Q, np.empty((15, 27)), np.empty((15, 15)))
    assert np.abs(got - want).max() < 1e-12 * np.abs(want).max()


def test_kernel_slide_moves_the_clones_and_clones_the_shifted_pose():
    from avio.filter.kernels import slide
    from avio.filter.measurement import shifted_pose

    rng = np.random.default_rng(1)
    R, p, v = so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3)
    omega, td = rng.normal(size=3), 0.01
    cp, cR = rng.normal(size=(2, 3)), so3_exp(rng.normal(size=(2, 3)))
    P = _spd(rng, 27)
    R3, p3, J, E = np.empty((3, 3)), np.empty(3), np.empty((6, 15)), np.empty((3, 3))
    shifted_pose(R, p, v, omega, td, R3, p3, J, E)
    assert np.allclose(p3, p + v * td) and np.allclose(R3, R @ so3_exp(omega * td))
    # Error-state map of the slide: new clone k-2 = old clone k-1, new clone k-1 = J core.
    T = np.zeros((27, 27))
    T[:15, :15] = np.eye(15)
    T[15:21, 21:27] = np.eye(6)
    T[21:27, :15] = J
    want = T @ P @ T.T
    cp0, cR0, P_got = cp.copy(), cR.copy(), P.copy()
    slide(R, p, v, omega, td, cp0, cR0, P_got, np.empty((3, 3)), np.empty(3), np.empty((6, 15)), np.empty((3, 3)),
          np.empty((6, 27)))
    assert np.abs(P_got - want).max() < 1e-12 * np.abs(want).max()
    assert np.array_equal(cp0[0], cp[1]) and np.array_equal(cR0[0], cR[1])
    assert np.allclose(cp0[1], p3) and np.allclose(cR0[1], R3)


def test_kernel_zero_velocity_update_is_the_kalman_update():
    from avio.filter.kernels import zero_velocity_update

    rng = np.random.default_rng(2)
    P = _spd(rng, 27) * 1e-2
    R, p, v = np.eye(3), np.zeros(3), np.array([0.3, -0.2, 0.1])
    ba, bg, cp0, cp1 = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    cR0, cR1 = np.eye(3), np.eye(3)
    H = np.zeros((3, 27))
    H[:, 6:9] = np.eye(3)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + 0.1**2 * np.eye(3))
    dx = K @ (-v)
    P_want = P - K @ H @ P
    v_want = v + dx[6:9]
    P_got = P.copy()
    zero_velocity_update(R, p, v, ba, bg, cp0, cR0, cp1, cR1, P_got, 0.1, np.empty((3, 3)), np.empty((3, 3)))
    assert np.abs(P_got - P_want).max() < 1e-12 and np.abs(v - v_want).max() < 1e-12
    assert np.allclose(p, dx[0:3], atol=1e-15) and np.allclose(ba, dx[9:12], atol=1e-15)


def test_kernel_solve_matches_lapack():
    from avio.filter._linalg import solve

    rng = np.random.default_rng(3)
    A, B = rng.normal(size=(12, 12)), rng.normal(size=(12, 13))
    X = B.copy()
    solve(A.copy(), X)
    assert np.abs(X - np.linalg.solve(A, B)).max() < 1e-10


def test_kernel_outlier_tests_match_their_numpy_definitions():
    from avio.filter.outliers import feature_innovations, mahalanobis_gate, one_point_ransac

    rng = np.random.default_rng(4)
    F, d, m = 10, 12, 3
    H = rng.normal(size=(F, m, d))
    Sig = _spd(rng, d) * 1e-3
    Rm = np.stack([_spd(rng, m) for _ in range(F)])  # each feature its own measurement covariance
    sd = np.sqrt(np.einsum("faa->fa", Rm))
    r = 0.5 * rng.normal(size=(F, m))
    r[3] += 40.0  # an outlier
    valid = np.ones(F, bool)
    valid[7] = False
    # The kernels take features last (avio/filter/outliers.py): r (m, F), H (m, d, F), Rm (m, m, F).
    def lanes(a):
        return np.ascontiguousarray(np.moveaxis(a, 0, -1))
    B, z, logdet = np.empty((m, d, F)), np.empty((m, F)), np.empty(F)
    feature_innovations(lanes(r), lanes(H), Sig, lanes(Rm), B, z, logdet)
    S = H @ Sig @ np.swapaxes(H, 1, 2) + Rm
    assert np.abs(z.T - np.linalg.solve(S, r[..., None])[..., 0]).max() < 1e-9
    assert np.abs(logdet - np.linalg.slogdet(S)[1]).max() < 1e-9
    gate = np.empty(F, bool)
    mahalanobis_gate(lanes(r), z, valid, 11.34, gate)
    d2 = np.einsum("fa,fa->f", r, np.linalg.solve(S, r[..., None])[..., 0])
    assert np.array_equal(gate, valid & (d2 <= 11.34)) and not gate[3]
    # 1-point RANSAC by brute force: hypothesis h corrects by Sig H_h^T S_h^-1 r_h.
    inl = np.zeros((F, F), bool)
    for h in range(F):
        dxh = Sig @ H[h].T @ np.linalg.solve(S[h], r[h])
        inl[:, h] = valid & np.all(np.abs(r - H @ dxh) <= 3.0 * sd, axis=1)
    count = np.where(valid, inl.sum(0), -1)
    got = np.empty(F, bool)
    one_point_ransac(lanes(r), B, z, lanes(sd), valid, 3.0, got)
    assert np.array_equal(got, inl[:, np.argmax(count)]) and not got[3] and not got[7]


def test_the_gate_threshold_is_the_chi_square_quantile():
    # avio.filter computes it without importing scipy.stats (slow to import): same bits.
    from scipy.stats import chi2

    from avio.filter.config import _chi2_ppf

    for p in (0.5, 0.9, 0.95, 0.99, 0.999):
        for dof in (1, 2, 3, 4, 12):
            assert _chi2_ppf(p, dof) == float(chi2.ppf(p, dof))


def test_the_transfer_gain_limit_decides_which_features_are_used():
    seq = make_circle_sequence(n_frames=20, pixel_noise_px=0.5)
    base = run(seq, seq.truth_calibration, FilterConfig())
    none = run(seq, seq.truth_calibration, FilterConfig(max_transfer_gain=0.5))
    assert base.n_updates.sum() > 0 and none.n_updates.sum() == 0
    assert none.n_outliers.sum() == 0  # degenerate features are not counted as outliers
