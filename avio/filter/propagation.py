"""Batched IMU propagation of the error-state Kalman filter (docs/model.md, "Prediction",
Eqs. 10-18).

Kinematics (Eq. 11): ``p' = v``, ``q' = 1/2 q ⊗ [0, w_m - b_g]``, ``v' = R(q) (a_m - b_a) + g``, integrated
with the classical 4th-order Runge–Kutta scheme, the IMU linearly interpolated at the sub-step
nodes and mid-points. Error state (core, 15): ``[dp, dtheta, dv, db_a, db_g]`` with the rotation
error local (``R_true = R exp(dtheta)``); its transition over one frame interval is written in
closed form from integrals of the nominal trajectory, so the covariance is propagated once per
interval rather than once per IMU sample.

Two implementations of the same model:

- :func:`preintegrate` + :func:`propagate_preintegrated` (what the filter uses): the RK4 runs
  once per sequence on the bias-free IMU, vectorised over all frame intervals, together with the
  integrals that give the first-order bias corrections (Eqs. 12-14; Forster et al. 2017,
  "On-manifold preintegration", with RK4 instead of Euler); each filter then applies its own biases
  (:func:`propagate_one`, compiled with numba: the filter's kernel calls it per filter and
  frame).
- :func:`make_substeps` + :func:`propagate_interval`: RK4 of every filter with its own biases,
  the reference the tests compare the first one against (differences ~|b_g T|^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from avio.errors import AvioError
from avio.filter._linalg import matmul, so3_exp


class ImuPropagationError(AvioError):
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


_SKEW9 = _SKEW.reshape(3, 9)


def skew_fast(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices (one small matmul, for the hot loop)."""
    return (v @ _SKEW9).reshape(v.shape[:-1] + (3, 3))


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


def _covered_frame_times(imu_t_s, frame_t_s) -> np.ndarray:
    """``frame_t_s`` as floats; ImuPropagationError unless the IMU covers all of them."""
    frame_t_s = np.asarray(frame_t_s, float)
    if frame_t_s[0] < imu_t_s[0] - 1e-9 or frame_t_s[-1] > imu_t_s[-1] + 1e-9:
        raise ImuPropagationError(
            f"frames span [{frame_t_s[0]:.3f}, {frame_t_s[-1]:.3f}] s but the IMU covers only "
            f"[{imu_t_s[0]:.3f}, {imu_t_s[-1]:.3f}] s"
        )
    return frame_t_s


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


def process_noise(T_s: float, accel_noise: float, gyro_noise: float, accel_bias_walk: float,
                  gyro_bias_walk: float) -> np.ndarray:
    """(15, 15) discrete process noise of one interval of T_s seconds for the core error state.

    Noise densities are continuous-time (ImuNoise). White accelerometer noise integrates into
    velocity and position (the double-integrator blocks sa^2 T, T^2/2, T^3/3); it is isotropic,
    so rotating it into the world frame changes nothing. Gyro noise enters the local rotation
    error; the biases are random walks. docs/model.md, Eq. 17.
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


@dataclass(frozen=True)
class Preintegrated:
    """Bias-free IMU increments of every frame interval, integrated once per sequence.

    Row k describes the interval from frame k-1 to frame k (row 0 is the identity), in the IMU
    frame of frame k-1 and without gravity (Forster et al. 2017, with RK4 instead of Euler):
    dR (N, 3, 3) ``R_{k-1}^T R_k``; dv (N, 3) = int dR a ds; dp (N, 3) = int int dR a;
    S (N, 3, 3) = int dR ds; SS = int S ds; Vbg = int [dR a]x S ds; Pbg = int Vbg ds — the last
    four give both the first-order bias corrections and the error transition (see
    :func:`propagate_interval`); T_s (N,); gyro_frame_radps (N, 3) the gyro at the frame times.
    docs/model.md, Eq. 12 (S2 = SS, V = Vbg, P_b = Pbg there).
    """

    dR: np.ndarray
    dv: np.ndarray
    dp: np.ndarray
    S: np.ndarray
    SS: np.ndarray
    Vbg: np.ndarray
    Pbg: np.ndarray
    T_s: np.ndarray
    gyro_frame_radps: np.ndarray


def preintegrate(imu_t_s, accel, gyro, frame_t_s, max_step_s: float) -> Preintegrated:
    """RK4 of the bias-free increments of all frame intervals at once (vectorised over intervals).

    Each interval is split into the same number of equal steps (no longer than ``max_step_s``);
    the IMU is interpolated linearly at step nodes and mid-points. The integrals S, SS, Vbg, Pbg
    are integrated as extra states of the same RK4, so they are as accurate as the increments.
    docs/model.md, Eqs. 12-13.
    """
    frame_t_s = _covered_frame_times(imu_t_s, frame_t_s)
    T = np.diff(frame_t_s)
    # Eq. (13): the same number of equal steps in every interval.
    m = int(max(1, np.ceil(T.max() / max_step_s - 1e-9)))
    h = T / m
    M = len(T)
    def interp(t, y):
        return np.stack([np.interp(t, imu_t_s, y[:, j]) for j in range(3)], axis=-1)
    q = np.zeros((M, 4))
    q[:, 0] = 1.0
    z3, z33 = np.zeros((M, 3)), np.zeros((M, 3, 3))
    state = [q, z3, z3, z33, z33, z33, z33]  # q, dv, dp, S, SS, Vbg, Pbg

    # The right-hand sides of Eq. (12).
    def deriv(s, w, a):
        q_, dv, dp, S, SS, Vbg, Pbg = s
        R = quat_to_matrix(q_)
        Ra = np.einsum("nij,nj->ni", R, a)
        return [0.5 * np.einsum("nij,nj->ni", omega_matrix(w), q_), Ra, dv, R, S, skew_fast(Ra) @ S, Vbg]

    def axpy(s, k, c):
        return [x + c * y for x, y in zip(s, k)]

    for i in range(m):
        t0 = frame_t_s[:-1] + i * h
        w0, wm, w1 = (interp(t0 + f * h, gyro) for f in (0.0, 0.5, 1.0))
        a0, am, a1 = (interp(t0 + f * h, accel) for f in (0.0, 0.5, 1.0))
        hh = h[:, None]
        hb = [hh, hh, hh, hh[:, :, None], hh[:, :, None], hh[:, :, None], hh[:, :, None]]
        k1 = deriv(state, w0, a0)
        k2 = deriv([x + 0.5 * c * y for x, y, c in zip(state, k1, hb)], wm, am)
        k3 = deriv([x + 0.5 * c * y for x, y, c in zip(state, k2, hb)], wm, am)
        k4 = deriv([x + c * y for x, y, c in zip(state, k3, hb)], w1, a1)
        state = [x + c / 6.0 * (y1 + 2 * y2 + 2 * y3 + y4)
                 for x, c, y1, y2, y3, y4 in zip(state, hb, k1, k2, k3, k4)]
        state[0] = state[0] / np.linalg.norm(state[0], axis=1, keepdims=True)
    q, dv, dp, S, SS, Vbg, Pbg = state
    def first(x, fill):
        return np.concatenate([fill[None], x], axis=0)
    gyro_frame = interp(frame_t_s, gyro)
    return Preintegrated(
        dR=first(quat_to_matrix(q), np.eye(3)), dv=first(dv, np.zeros(3)), dp=first(dp, np.zeros(3)),
        S=first(S, np.zeros((3, 3))), SS=first(SS, np.zeros((3, 3))), Vbg=first(Vbg, np.zeros((3, 3))),
        Pbg=first(Pbg, np.zeros((3, 3))), T_s=np.concatenate([[0.0], T]), gyro_frame_radps=gyro_frame,
    )


@numba.njit(cache=True, error_model="numpy")
def propagate_workspace():
    """Scratch arrays of :func:`propagate_one`."""
    return (np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3), np.empty(3),
            np.empty(3))


@numba.njit(cache=True, error_model="numpy")
def propagate_one(R, v, p, b_a, b_g, g_world, dR, dv0, dp0, S, SS, Vbg, Pbg, T, R_new, v_new, p_new, Phi, ws):
    """One filter over one preintegrated interval (rows k of :class:`Preintegrated`: dR, dv0,
    dp0, S, SS, Vbg, Pbg, T): writes R_new (3, 3), v_new, p_new (3,) and the (15, 15) error
    transition Phi (ws: :func:`propagate_workspace`). See :func:`propagate_preintegrated`.
    docs/model.md: bias correction Eq. 14, nominal prediction Eq. 15, Phi Eq. 16."""
    E, RdR, M, dv, dp, sb, Delta, Pi = ws
    # Eq. (14): first-order bias corrections of the increments.
    for i in range(3):
        dv[i] = dv0[i] - (S[i, 0] * b_a[0] + S[i, 1] * b_a[1] + S[i, 2] * b_a[2]) \
            + (Vbg[i, 0] * b_g[0] + Vbg[i, 1] * b_g[1] + Vbg[i, 2] * b_g[2])
        dp[i] = dp0[i] - (SS[i, 0] * b_a[0] + SS[i, 1] * b_a[1] + SS[i, 2] * b_a[2]) \
            + (Pbg[i, 0] * b_g[0] + Pbg[i, 1] * b_g[1] + Pbg[i, 2] * b_g[2])
        sb[i] = S[i, 0] * b_g[0] + S[i, 1] * b_g[1] + S[i, 2] * b_g[2]
    # dtheta = -dR^T S b_g
    so3_exp(-(sb[0] * dR[0, 0] + sb[1] * dR[1, 0] + sb[2] * dR[2, 0]),
            -(sb[0] * dR[0, 1] + sb[1] * dR[1, 1] + sb[2] * dR[2, 1]),
            -(sb[0] * dR[0, 2] + sb[1] * dR[1, 2] + sb[2] * dR[2, 2]), E)
    # Eq. (15): the nominal prediction (Delta, Pi of Eq. 16 on the way).
    matmul(R, dR, RdR)
    matmul(RdR, E, R_new)
    for i in range(3):
        v_new[i] = v[i] + g_world[i] * T + (R[i, 0] * dv[0] + R[i, 1] * dv[1] + R[i, 2] * dv[2])
        p_new[i] = p[i] + v[i] * T + 0.5 * g_world[i] * T * T + (R[i, 0] * dp[0] + R[i, 1] * dp[1] + R[i, 2] * dp[2])
        Delta[i] = v_new[i] - v[i] - g_world[i] * T
        Pi[i] = p_new[i] - p[i] - v[i] * T - 0.5 * g_world[i] * T * T
    # Eq. (16): the error transition.
    Phi[:] = 0.0
    for i in range(15):
        Phi[i, i] = 1.0
    for r0, c0, X, sgn in ((0, 9, SS, -1.0), (0, 12, Pbg, 1.0), (6, 9, S, -1.0), (6, 12, Vbg, 1.0)):
        matmul(R, X, M)
        for i in range(3):
            for j in range(3):
                Phi[r0 + i, c0 + j] = sgn * M[i, j]
    for r0, w in ((0, Pi), (6, Delta)):
        # -[w]x R
        for j in range(3):
            Phi[r0 + 0, 3 + j] = -(-w[2] * R[1, j] + w[1] * R[2, j])
            Phi[r0 + 1, 3 + j] = -(w[2] * R[0, j] - w[0] * R[2, j])
            Phi[r0 + 2, 3 + j] = -(-w[1] * R[0, j] + w[0] * R[1, j])
    for i in range(3):
        Phi[i, 6 + i] = T
        for j in range(3):
            Phi[3 + i, 3 + j] = dR[j, i]
            Phi[3 + i, 12 + j] = -(dR[0, i] * S[0, j] + dR[1, i] * S[1, j] + dR[2, i] * S[2, j])


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
