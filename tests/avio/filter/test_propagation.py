"""IMU propagation: RK4 against an analytic motion, preintegration against per-filter RK4,
the closed-form error transition against finite differences."""

import numpy as np
from imu_reference import make_substeps, matrix_to_quat, propagate_interval, propagate_preintegrated
from test_filter import make_circle_sequence

from avio.filter.propagation import preintegrate, quat_to_matrix
from avio.geometry import so3_exp, so3_log


def _seq():
    return make_circle_sequence(n_frames=40)


def test_rk4_preintegration_follows_the_analytic_motion():
    seq = _seq()
    imu, tr = seq.imu, seq.truth
    pre = preintegrate(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.frame_t_s, 0.005)
    R, v, p = tr.R_world_imu[:1], tr.v_world_imu_mps[:1], tr.p_world_imu_m[:1]
    z = np.zeros((1, 3))
    for k in range(1, seq.n_frames):
        R, v, p, _ = propagate_preintegrated(R, v, p, z, z, seq.gravity_world_mps2, pre, k)
    # 3.9 s of dead reckoning on exact IMU samples: only the linear interpolation between the
    # 100 Hz samples and RK4 truncation remain.
    assert np.linalg.norm(p[0] - tr.p_world_imu_m[-1]) < 1e-3
    assert np.linalg.norm(v[0] - tr.v_world_imu_mps[-1]) < 1e-3
    assert np.degrees(np.linalg.norm(so3_log(R[0].T @ tr.R_world_imu[-1]))) < 1e-3


def test_preintegration_with_biases_matches_per_filter_rk4():
    seq = _seq()
    imu, tr = seq.imu, seq.truth
    pre = preintegrate(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.frame_t_s, 0.005)
    sub = make_substeps(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.frame_t_s, 0.005)
    b_a = np.array([[0.05, -0.03, 0.02], [0.2, 0.1, -0.1]])
    b_g = np.array([[1e-3, -2e-3, 5e-4], [-5e-3, 3e-3, 2e-3]])
    k = 7
    R0 = np.repeat(tr.R_world_imu[k - 1:k], 2, 0)
    v0 = np.repeat(tr.v_world_imu_mps[k - 1:k], 2, 0)
    p0 = np.repeat(tr.p_world_imu_m[k - 1:k], 2, 0)
    g = seq.gravity_world_mps2
    R1, v1, p1, Phi1 = propagate_preintegrated(R0, v0, p0, b_a, b_g, g, pre, k)
    q2, v2, p2, Phi2 = propagate_interval(matrix_to_quat(R0), v0, p0, b_a, b_g, g, sub, k)
    # First order in the biases: the remainder is ~ |b_g T|^2 and |b_a| |b_g| T^3.
    np.testing.assert_allclose(p1, p2, atol=1e-6)
    np.testing.assert_allclose(v1, v2, atol=2e-5)
    assert np.abs(so3_log(np.swapaxes(R1, 1, 2) @ quat_to_matrix(q2))).max() < 1e-8
    # Transitions agree to the first-order bias terms (|b_g T| ~ 5e-4) in the pose/velocity
    # columns; the per-filter RK4 integrates the bias columns with a cruder quadrature.
    np.testing.assert_allclose(Phi1[:, :, :9], Phi2[:, :, :9], atol=1e-3)
    np.testing.assert_allclose(Phi1[:, :, 9:], Phi2[:, :, 9:], atol=5e-3)


def test_error_transition_matches_finite_differences():
    """Phi of the preintegrated propagation against central differences of the exact
    (per-filter RK4) nonlinear propagation, at realistic biases."""
    seq = _seq()
    imu, tr = seq.imu, seq.truth
    sub = make_substeps(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.frame_t_s, 0.005)
    pre = preintegrate(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.frame_t_s, 0.005)
    k = 5
    R0 = tr.R_world_imu[[k - 1]]
    v0, p0 = tr.v_world_imu_mps[[k - 1]], tr.p_world_imu_m[[k - 1]]
    ba, bg, g = np.array([[0.05, -0.02, 0.03]]), np.array([[2e-4, -1e-4, 3e-4]]), seq.gravity_world_mps2
    R, v, p, Phi = propagate_preintegrated(R0, v0, p0, ba, bg, g, pre, k)

    def prop(dx):
        qq = matrix_to_quat(R0 @ so3_exp(dx[3:6])[None])
        q1, v1, p1, _ = propagate_interval(qq, v0 + dx[6:9], p0 + dx[0:3], ba + dx[9:12], bg + dx[12:15], g, sub, k)
        return np.r_[p1[0] - p[0], so3_log(R[0].T @ quat_to_matrix(q1)[0]), v1[0] - v[0]]

    eps = 1e-6
    F = np.stack([(prop(eps * e) - prop(-eps * e)) / (2 * eps) for e in np.eye(15)], axis=1)
    # Phi is evaluated at the bias-free increments: the remainder is ~ |b_g| T (3e-5) in the
    # pose/velocity columns and ~ |b_a| int |S| (3e-4) in the velocity-gyro-bias block.
    np.testing.assert_allclose(Phi[0, :9, :9], F[:, :9], atol=1e-4)
    np.testing.assert_allclose(Phi[0, :9, 9:], F[:, 9:], atol=5e-4)
