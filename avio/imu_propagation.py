"""Batched IMU propagation of the error-state Kalman filter (PAPER.md §2, "Prediction").

Nominal state per filter: quaternion ``q_world_imu`` (w, x, y, z; Hamilton; maps IMU vectors
into the world frame), ``v_world_imu_mps``, ``p_world_imu_m``, integrated with the classical
4th-order Runge–Kutta scheme from the bias-corrected IMU, linearly interpolated at the RK4
sub-step nodes and mid-points. Kinematics: ``p' = v``, ``q' = 1/2 q ⊗ [0, w_m - b_g]``,
``v' = R(q) (a_m - b_a) + g``.

Error state (core, 15): ``[dp, dtheta, dv, db_a, db_g]`` with the rotation error local
(``R_true = R exp(dtheta)``). Its transition over one frame interval is written in closed
form from integrals of the nominal trajectory (``Phi`` below), so the covariance is propagated
once per interval rather than once per IMU sample.

Everything calibration-independent (sub-step times, interpolated IMU) is built once per
sequence by :func:`make_substeps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class ImuPropagationError(ValueError):
    """Bad input to IMU propagation; the message names what and where."""


# R(q) as a linear map of the outer product q q^T (flattened, 16) -> R (flattened, 9),
# so that a batch of rotation matrices costs one matmul instead of a dozen small ops.
_Q2R = np.zeros((16, 9))
for _i, _j, _k, _l, _c in [
    (0, 0, 0, 0, 1), (0, 0, 1, 1, 1), (0, 0, 2, 2, -1), (0, 0, 3, 3, -1),
    (0, 1, 1, 2, 2), (0, 1, 0, 3, -2), (0, 2, 1, 3, 2), (0, 2, 0, 2, 2),
    (1, 0, 1, 2, 2), (1, 0, 0, 3, 2), (1, 1, 0, 0, 1), (1, 1, 1, 1, -1),
    (1, 1, 2, 2, 1), (1, 1, 3, 3, -1), (1, 2, 2, 3, 2), (1, 2, 0, 1, -2),
    (2, 0, 1, 3, 2), (2, 0, 0, 2, -2), (2, 1, 2, 3, 2), (2, 1, 0, 1, 2),
    (2, 2, 0, 0, 1), (2, 2, 1, 1, -1), (2, 2, 2, 2, -1), (2, 2, 3, 3, 1),
]:
    _Q2R[4 * _k + _l, 3 * _i + _j] = _c

# Omega(w) with q ⊗ [0, w] = Omega(w) q, as a linear map of w: (3,) -> (4, 4).
_OMEGA = np.zeros((3, 4, 4))
_OMEGA[0] = [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -1, 0]]
_OMEGA[1] = [[0, 0, -1, 0], [0, 0, 0, -1], [1, 0, 0, 0], [0, 1, 0, 0]]
_OMEGA[2] = [[0, 0, 0, -1], [0, 0, 1, 0], [0, -1, 0, 0], [1, 0, 0, 0]]

# skew(x) = x @ _SKEW (contracting the first axis), batched without building element by element.
_SKEW = np.zeros((3, 3, 3))
_SKEW[2, 0, 1], _SKEW[1, 0, 2], _SKEW[2, 1, 0] = -1, 1, 1
_SKEW[0, 1, 2], _SKEW[1, 2, 0], _SKEW[0, 2, 1] = -1, -1, 1


def skew_fast(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices (one tensordot, for the hot loop)."""
    return np.tensordot(v, _SKEW, axes=(-1, 0))


def omega_matrix(w: np.ndarray) -> np.ndarray:
    """(..., 3) angular rate (rad/s) -> (..., 4, 4) with ``q ⊗ [0, w] = Omega(w) q``."""
    return np.tensordot(w, _OMEGA, axes=(-1, 0))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions (w, x, y, z), any norm -> (n, 3, 3) rotation matrices."""
    n = q.shape[0]
    qq = (q[:, :, None] * q[:, None, :]).reshape(n, 16)
    return ((qq @ _Q2R) / np.einsum("ni,ni->n", q, q)[:, None]).reshape(n, 3, 3)


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
    frame_t_s = np.asarray(frame_t_s, float)
    if frame_t_s[0] < imu_t_s[0] - 1e-9 or frame_t_s[-1] > imu_t_s[-1] + 1e-9:
        raise ImuPropagationError(
            f"frames span [{frame_t_s[0]:.3f}, {frame_t_s[-1]:.3f}] s but the IMU covers only "
            f"[{imu_t_s[0]:.3f}, {imu_t_s[-1]:.3f}] s"
        )
    T = np.diff(frame_t_s)
    m_per = np.maximum(1, np.ceil(T / max_step_s - 1e-9).astype(int))
    start = np.concatenate([[0, 0], np.cumsum(m_per)])
    k_of_step = np.repeat(np.arange(len(T)), m_per)
    i_in = np.arange(len(k_of_step)) - start[1:-1][k_of_step]
    h = (T / m_per)[k_of_step]
    t0 = frame_t_s[k_of_step] + i_in * h
    nodes = t0[:, None] + h[:, None] * np.array([0.0, 0.5, 1.0])[None, :]
    interp = lambda y: np.stack([np.interp(nodes, imu_t_s, y[:, j]) for j in range(3)], axis=-1)
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
    transition of the core error state ``[dp, dtheta, dv, db_a, db_g]``:

        dtheta_T = R_T^T R_0 dtheta_0 - R_T^T S dbg,             S = int R ds
        dv_T = dv_0 - [Delta]x R_0 dtheta_0 - S dba + V_bg dbg,   Delta = v_T - v_0 - g T
        dp_T = dp_0 + T dv_0 - [Pi]x R_0 dtheta_0 - SS dba + P_bg dbg,
               Pi = p_T - p_0 - v_0 T - g T^2 / 2, SS = int S ds,
        V_bg = int [R a]x S ds, P_bg = int V_bg ds      (left-point quadrature per RK4 step).
    """
    n = q.shape[0]
    s0, s1 = sub.start[k], sub.start[k + 1]
    Ob = omega_matrix(b_g)
    q0, v0, p0 = q, v, p
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
        # Left-point quadrature of the transition integrals (covariance only).
        Pbg += h * Vbg
        SS += h * S
        Vbg += h * (skew_fast(Ra0) @ S)
        S += h * R1
        R1 = quat_to_matrix(q)
        T += h
    RT = R1
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


def process_noise(T_s: float, accel_noise: float, gyro_noise: float, accel_bias_walk: float,
                  gyro_bias_walk: float) -> np.ndarray:
    """(15, 15) discrete process noise of one interval of T_s seconds for the core error state.

    Noise densities are continuous-time (ImuNoise). White accelerometer noise integrates into
    velocity and position (the double-integrator blocks sa^2 T, T^2/2, T^3/3); it is isotropic,
    so rotating it into the world frame changes nothing. Gyro noise enters the local rotation
    error; the biases are random walks.
    """
    Q = np.zeros((15, 15))
    sa2, sg2 = accel_noise**2, gyro_noise**2
    I3 = np.eye(3)
    Q[0:3, 0:3] = sa2 * T_s**3 / 3.0 * I3
    Q[0:3, 6:9] = Q[6:9, 0:3] = sa2 * T_s**2 / 2.0 * I3
    Q[6:9, 6:9] = sa2 * T_s * I3
    Q[3:6, 3:6] = sg2 * T_s * I3
    Q[9:12, 9:12] = accel_bias_walk**2 * T_s * I3
    Q[12:15, 12:15] = gyro_bias_walk**2 * T_s * I3
    return Q
