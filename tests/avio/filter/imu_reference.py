"""The reference the filter's IMU propagation is tested against: RK4 of every filter with its own
biases (:func:`make_substeps` + :func:`propagate_interval`), and the batched wrapper of the
compiled per-filter step (:func:`propagate_preintegrated`). docs/model.md, Eqs. 10-18."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from avio.filter.propagation import (
    Preintegrated,
    _covered_frame_times,
    omega_matrix,
    propagate_one,
    propagate_workspace,
    quat_to_matrix,
    skew_fast,
)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices -> (n, 4) unit quaternions (w, x, y, z), w >= 0."""
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(R).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)



@dataclass(frozen=True)
class Substeps:
    """RK4 sub-steps of every frame interval, calibration-independent.

    Interval k (1 <= k < N) goes from frame k-1 to frame k; its steps are
    ``start[k] : start[k + 1]`` (``start`` has N + 1 entries; interval 0 is empty).
    h_s: (m,) step lengths, seconds.
    omega_node: (m, 3, 4, 4) ``Omega(gyro)`` at step start, mid-point, end (rows 0..2).
    accel_node: (m, 3, 3) specific force (IMU frame, m/s^2) at start, mid-point, end.
    gyro_frame_radps: (N, 3) gyro interpolated at the frame times (for the time offset).
    T_s: (N,) interval lengths (T_s[0] = 0).
    """

    start: np.ndarray
    h_s: np.ndarray
    omega_node: np.ndarray
    accel_node: np.ndarray
    gyro_frame_radps: np.ndarray
    T_s: np.ndarray



def make_substeps(imu_t_s, accel, gyro, frame_t_s, max_step_s: float) -> Substeps:
    """Split each frame interval into equal RK4 steps no longer than ``max_step_s`` and
    interpolate the IMU (linearly in time) at their nodes and mid-points.

    imu_t_s: (m,) IMU times; accel, gyro: (m, 3); frame_t_s: (N,) on the IMU clock.
    """
    frame_t_s = _covered_frame_times(imu_t_s, frame_t_s)
    T = np.diff(frame_t_s)
    m_per = np.maximum(1, np.ceil(T / max_step_s - 1e-9).astype(int))
    start = np.concatenate([[0, 0], np.cumsum(m_per)])
    k_of_step = np.repeat(np.arange(len(T)), m_per)
    i_in = np.arange(len(k_of_step)) - start[1:-1][k_of_step]
    h = (T / m_per)[k_of_step]
    t0 = frame_t_s[k_of_step] + i_in * h
    nodes = t0[:, None] + h[:, None] * np.array([0.0, 0.5, 1.0])[None, :]
    def interp(y):
        return np.stack([np.interp(nodes, imu_t_s, y[:, j]) for j in range(3)], axis=-1)
    gyro_node = interp(gyro)
    accel_node = interp(accel)
    gyro_frame = np.stack([np.interp(frame_t_s, imu_t_s, gyro[:, j]) for j in range(3)], axis=-1)
    return Substeps(
        start=start,
        h_s=h,
        omega_node=omega_matrix(gyro_node),
        accel_node=accel_node,
        gyro_frame_radps=gyro_frame,
        T_s=np.concatenate([[0.0], T]),
    )



def propagate_interval(q, v, p, b_a, b_g, g_world, sub: Substeps, k: int):
    """RK4-integrate the nominal state over interval k and build its error transition.

    q (n, 4), v (n, 3), p (n, 3): nominal state at frame k-1; b_a, b_g (n, 3) biases held
    constant over the interval. Returns ``(q, v, p, Phi)`` at frame k, Phi (n, 15, 15) the
    transition of the core error state ``[dp, dtheta, dv, db_a, db_g]`` (docs/model.md, Eq. 16,
    there with the integrals in the frame of frame k-1):

        dtheta_T = R_T^T R_0 dtheta_0 - R_T^T S dbg,             S = int R ds
        dv_T = dv_0 - [Delta]x R_0 dtheta_0 - S dba + V_bg dbg,   Delta = v_T - v_0 - g T
        dp_T = dp_0 + T dv_0 - [Pi]x R_0 dtheta_0 - SS dba + P_bg dbg,
               Pi = p_T - p_0 - v_0 T - g T^2 / 2, SS = int S ds,
        V_bg = int [R a]x S ds, P_bg = int V_bg ds      (left-point quadrature per RK4 step).
    """
    n = q.shape[0]
    s0, s1 = sub.start[k], sub.start[k + 1]
    Ob = omega_matrix(b_g)
    _q0, v0, p0 = q, v, p
    R0 = quat_to_matrix(q)
    S = np.zeros((n, 3, 3))
    SS = np.zeros((n, 3, 3))
    Vbg = np.zeros((n, 3, 3))
    Pbg = np.zeros((n, 3, 3))
    g = g_world[None, :]
    R1 = R0
    T = 0.0
    for i in range(s0, s1):
        h = sub.h_s[i]
        Om = sub.omega_node[i]
        A0, Am, A1 = 0.5 * (Om[0] - Ob), 0.5 * (Om[1] - Ob), 0.5 * (Om[2] - Ob)
        a0, am, a1 = (sub.accel_node[i][None, j] - b_a for j in range(3))
        k1q = np.einsum("nij,nj->ni", A0, q)
        Ra0 = np.einsum("nij,nj->ni", R1, a0)
        k1v = Ra0 + g
        q2 = q + 0.5 * h * k1q
        k2q = np.einsum("nij,nj->ni", Am, q2)
        k2v = np.einsum("nij,nj->ni", quat_to_matrix(q2), am) + g
        q3 = q + 0.5 * h * k2q
        k3q = np.einsum("nij,nj->ni", Am, q3)
        k3v = np.einsum("nij,nj->ni", quat_to_matrix(q3), am) + g
        q4 = q + h * k3q
        k4q = np.einsum("nij,nj->ni", A1, q4)
        k4v = np.einsum("nij,nj->ni", quat_to_matrix(q4), a1) + g
        p = p + h * v + (h * h / 6.0) * (k1v + k2v + k3v)
        v = v + (h / 6.0) * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        q = q + (h / 6.0) * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
        q = q / np.sqrt(np.einsum("ni,ni->n", q, q))[:, None]
        # Left-point quadrature of the transition integrals (covariance only; Eq. 12's S, SS, V, P_b).
        Pbg += h * Vbg
        SS += h * S
        Vbg += h * (skew_fast(Ra0) @ S)
        S += h * R1
        R1 = quat_to_matrix(q)
        T += h
    RT = R1
    # Eq. (16)
    Phi = np.broadcast_to(np.eye(15), (n, 15, 15)).copy()
    RTt = np.swapaxes(RT, 1, 2)
    Delta = v - v0 - g * T
    Pi = p - p0 - v0 * T - 0.5 * g * T * T
    Phi[:, 0:3, 3:6] = -skew_fast(Pi) @ R0
    Phi[:, 0:3, 6:9] = T * np.eye(3)
    Phi[:, 0:3, 9:12] = -SS
    Phi[:, 0:3, 12:15] = Pbg
    Phi[:, 3:6, 3:6] = RTt @ R0
    Phi[:, 3:6, 12:15] = -RTt @ S
    Phi[:, 6:9, 3:6] = -skew_fast(Delta) @ R0
    Phi[:, 6:9, 9:12] = -S
    Phi[:, 6:9, 12:15] = Vbg
    return q, v, p, Phi



@numba.njit(cache=True, error_model="numpy")
def _propagate_all(R, v, p, b_a, b_g, g_world, dR, dv, dp, S, SS, Vbg, Pbg, T):
    n = R.shape[0]
    R_new, v_new, p_new, Phi = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 15, 15))
    ws = propagate_workspace()
    for i in range(n):
        propagate_one(R[i], v[i], p[i], b_a[i], b_g[i], g_world, dR, dv, dp, S, SS, Vbg, Pbg, T, R_new[i], v_new[i],
                      p_new[i], Phi[i], ws)
    return R_new, v_new, p_new, Phi



def propagate_preintegrated(R, v, p, b_a, b_g, g_world, pre: Preintegrated, k: int):
    """Nominal state at frame k from frame k-1 and the preintegrated interval k, with the
    biases applied to first order, and the (n, 15, 15) error transition Phi (same closed form
    as :func:`propagate_interval`, with ``S = R_0 dS`` etc.); :func:`propagate_one` per filter
    (what the filter runs).

    R (n, 3, 3) ``R_world_imu``; v, p, b_a, b_g (n, 3). The bias corrections are exact to first
    order in the biases (second-order terms are ~|b_g T|^2, below 1e-8 for real IMUs).
    """
    def f(a):
        return np.ascontiguousarray(a, dtype=np.float64)
    return _propagate_all(f(R), f(v), f(p), f(b_a), f(b_g), f(g_world), pre.dR[k], pre.dv[k], pre.dp[k], pre.S[k],
                          pre.SS[k], pre.Vbg[k], pre.Pbg[k], float(pre.T_s[k]))
