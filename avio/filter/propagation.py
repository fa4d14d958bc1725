"""Batched IMU propagation of the error-state Kalman filter (docs/model.md, "Prediction",
Eqs. 10-18).

Kinematics (Eq. 11): ``p' = v``, ``q' = 1/2 q ⊗ [0, w_m - b_g]``, ``v' = R(q) (a_m - b_a) + g``, integrated
with the classical 4th-order Runge–Kutta scheme, the IMU linearly interpolated at the sub-step
nodes and mid-points. Error state (core, 15): ``[dp, dtheta, dv, db_a, db_g]`` with the rotation
error local (``R_true = R exp(dtheta)``); its transition over one frame interval is written in
closed form from integrals of the nominal trajectory, so the covariance is propagated once per
interval rather than once per IMU sample.

What the filter uses: :func:`preintegrate` runs the RK4 once per sequence on the bias-free IMU,
vectorised over all frame intervals, together with the integrals that give the first-order bias
corrections (Eqs. 12-14; Forster et al. 2017, "On-manifold preintegration", with RK4 instead of
Euler); each filter then applies its own biases (:func:`propagate_one`, compiled with numba: the
filter's kernel calls it per filter and frame). The tests keep a second implementation of the
same model, RK4 of every filter with its own biases (tests/avio/filter/imu_reference.py), and
compare the two (differences ~|b_g T|^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avio.errors import AvioError
from avio.filter._linalg import matmul, so3_exp
from avio.filter._simd import kernel_jit
from avio.filter.interface import PropagateWorkspace


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


def _covered_frame_times(imu_t_s, frame_t_s) -> np.ndarray:
    """``frame_t_s`` as floats; ImuPropagationError unless the IMU covers all of them."""
    frame_t_s = np.asarray(frame_t_s, float)
    if frame_t_s[0] < imu_t_s[0] - 1e-9 or frame_t_s[-1] > imu_t_s[-1] + 1e-9:
        raise ImuPropagationError(
            f"frames span [{frame_t_s[0]:.3f}, {frame_t_s[-1]:.3f}] s but the IMU covers only "
            f"[{imu_t_s[0]:.3f}, {imu_t_s[-1]:.3f}] s"
        )
    return frame_t_s


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
    docs/model.md, Eq. 16); T_s (N,); gyro_frame_radps (N, 3) the gyro at the frame times.
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


@kernel_jit(allocates=True)
def propagate_workspace():
    """Scratch arrays of :func:`propagate_one` (avio.filter.interface.PropagateWorkspace)."""
    return PropagateWorkspace(E=np.empty((3, 3)), RdR=np.empty((3, 3)), M=np.empty((3, 3)), dv=np.empty(3),
                              dp=np.empty(3), sb=np.empty(3), Delta=np.empty(3), Pi=np.empty(3))


@kernel_jit
def propagate_one(R, v, p, b_a, b_g, g_world, dR, dv0, dp0, S, SS, Vbg, Pbg, T, R_new, v_new, p_new, Phi, ws):
    """One filter over one preintegrated interval (rows k of :class:`Preintegrated`: dR, dv0,
    dp0, S, SS, Vbg, Pbg, T): writes R_new (3, 3), v_new, p_new (3,) and the (15, 15) error
    transition Phi (ws: :func:`propagate_workspace`). Batched in tests/avio/filter/imu_reference.py.
    docs/model.md: bias correction Eq. 14, nominal prediction Eq. 15, Phi Eq. 16."""
    E, RdR, M, dv, dp, sb, Delta, Pi = ws.E, ws.RdR, ws.M, ws.dv, ws.dp, ws.sb, ws.Delta, ws.Pi
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


