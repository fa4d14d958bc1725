"""Trifocal measurement model of the filter: residuals and analytic Jacobians (PAPER.md §2).

For a feature seen in images 1, 2, 3 (frames k-2, k-1, k) at pixels m1, m2, m3, four residuals
in pixels:

- r0: Sampson distance of the epipolar constraint 1–2, ``m2^T K^-T R12^T [t12]x K^-1 m1`` divided
  by the norm of the first two entries of ``F m1`` and ``F^T m2`` (first-order geometric
  distance, pixels; the algebraic value in normalised coordinates would carry almost no weight);
- r1: the same for images 2–3;
- r2, r3: ``m3`` minus the trifocal point transfer 1→3 through image 2 (point–line–point
  transfer; the line through m2 perpendicular to the epipolar line ``F12 m1``):
  ``x3 ∝ -(l'·a4) B x1 + (l'·A x1) b4`` with ``P2 = [A|a4]``, ``P3 = [B|b4]`` relative to
  camera 1.

Relative poses (camera frames, x right, y down, z forward): ``R1j = R_world_cam1^T R_world_camj``
maps camera-j vectors into camera 1, ``t1j = R_world_cam1^T (p_world_camj - p_world_cam1)``
is camera j's origin in camera 1.

Jacobians are taken with respect to the 12 relative-pose perturbations
``[psi12, dt12, psi13, dt13]`` with ``R1j <- R1j exp(psi1j)``, ``t1j <- t1j + dt1j``, and chained
to the filter's 27-dim error state by the per-filter matrix of :func:`relative_pose_jacobian`.
Shapes: n filters (calibrations), F features.
"""

from __future__ import annotations

import numpy as np

from avio.imu_propagation import skew_fast


class MeasurementError(ValueError):
    """Bad input to the measurement model; the message names what and where."""


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # Component-wise cross product: np.cross re-checks and moves axes on every call, which
    # dominates for the (n, F, 3) arrays of the update.
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    p = a * b
    return p[..., 0] + p[..., 1] + p[..., 2]


# Batched matmul rather than einsum: einsum does not use BLAS-like kernels for these
# (n, F, 3) x (n, 3, 3) contractions and is ~15x slower here.
def _rot(R: np.ndarray, x: np.ndarray) -> np.ndarray:
    """R (n, 3, 3) applied to x (n, F, 3)."""
    return x @ np.swapaxes(R, 1, 2)


def _rot_t(R: np.ndarray, x: np.ndarray) -> np.ndarray:
    """R^T (n, 3, 3) applied to x (n, F, 3)."""
    return x @ R


def normalised_points(uv_px: np.ndarray, fx, fy, cx, cy) -> np.ndarray:
    """Pixels (F, 2) shared by the batch -> (n, F, 3) homogeneous ``K^-1 m`` of each filter."""
    n = len(fx)
    x = np.empty((n, uv_px.shape[0], 3))
    x[..., 0] = (uv_px[None, :, 0] - cx[:, None]) / fx[:, None]
    x[..., 1] = (uv_px[None, :, 1] - cy[:, None]) / fy[:, None]
    x[..., 2] = 1.0
    return x


def epipolar_sampson(R_ab, t_ab, xa, xb, fx, fy):
    """Sampson distance (pixels) of ``xb^T R_ab^T [t_ab]x xa = 0`` and its gradient.

    R_ab (n, 3, 3), t_ab (n, 3): pose of camera b in camera a; xa, xb (n, F, 3) normalised
    homogeneous points; fx, fy (n,) pixels. Returns ``r (n, F)``, ``g_psi (n, F, 3)``,
    ``g_t (n, F, 3)`` (derivatives w.r.t. ``R_ab <- R_ab exp(psi)``, ``t_ab <- t_ab + dt``) and
    ``w = R_ab^T (t_ab x xa)`` (n, F, 3), the epipolar line in normalised coordinates of b.
    """
    t = np.broadcast_to(t_ab[:, None, :], xa.shape)
    c = _cross(t, xa)
    Rxb = _rot(R_ab, xb)
    e = _dot(Rxb, c)
    w = _rot_t(R_ab, c)
    u = _cross(Rxb, t)
    ifx, ify = (1.0 / fx)[:, None], (1.0 / fy)[:, None]
    gam = np.stack([w[..., 0] * ifx * ifx, w[..., 1] * ify * ify, np.zeros_like(e)], axis=-1)
    eta = np.stack([u[..., 0] * ifx * ifx, u[..., 1] * ify * ify, np.zeros_like(e)], axis=-1)
    s = np.sqrt((w[..., 0] * ifx) ** 2 + (w[..., 1] * ify) ** 2 + (u[..., 0] * ifx) ** 2
                + (u[..., 1] * ify) ** 2)
    r = e / s
    de_psi = _cross(xb, w)
    de_t = _cross(xa, Rxb)
    ds_psi = (_cross(gam, w) + _cross(xb, _rot_t(R_ab, _cross(t, eta)))) / s[..., None]
    ds_t = (_cross(xa, _rot(R_ab, gam)) + _cross(eta, Rxb)) / s[..., None]
    g_psi = (de_psi - r[..., None] * ds_psi) / s[..., None]
    g_t = (de_t - r[..., None] * ds_t) / s[..., None]
    return r, g_psi, g_t, w


def trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy):
    """Point transfer 1→3 (pixels) and its Jacobian w.r.t. ``[psi12, dt12, psi13, dt13]``.

    x1, x2 (n, F, 3) normalised points in images 1, 2; w12 (n, F, 3) the epipolar line of x1
    in image 2 (normalised, from :func:`epipolar_sampson`). The perpendicular through m2 is
    taken in pixels (as the paper's point–line–point transfer), then mapped to normalised
    coordinates: ``l_n = K^T l_px = (a w1, -w0 / a, -a x2_0 w1 + x2_1 w0 / a)``, ``a = fx/fy``.
    Returns ``pred (n, F, 2)`` pixels and ``J (n, F, 2, 12)``.
    """
    a = (fx / fy)[:, None]
    w0, w1 = w12[..., 0], w12[..., 1]
    x20, x21 = x2[..., 0], x2[..., 1]
    l_n = np.stack([a * w1, -w0 / a, -a * x20 * w1 + x21 * w0 / a], axis=-1)
    lam = _rot(R12, l_n)  # R12 l_n: P2 = [R12^T | -R12^T t12] makes l·a4 = -(R12 l)·t12
    t12b = np.broadcast_to(t12[:, None, :], x1.shape)
    t13b = np.broadcast_to(t13[:, None, :], x1.shape)
    s1 = _dot(lam, t12b)
    s2 = _dot(lam, x1)
    Y = s1[..., None] * x1 - s2[..., None] * t13b
    X = _rot_t(R13, Y)

    def grads(y):
        # d(y·lam)/d psi12 and / d t12 for y (n, F, 3) (PAPER.md closed form, differentiated).
        yt = _rot_t(R12, y)
        z = np.stack([-yt[..., 1] / a + x21 * yt[..., 2] / a, a * yt[..., 0] - a * x20 * yt[..., 2],
                      np.zeros_like(s1)], axis=-1)  # L^T yt
        return _cross(l_n, yt) + _cross(z, w12), _cross(x1, _rot(R12, z))

    s1_psi, s1_t = grads(t12b)
    s1_t = s1_t + lam
    s2_psi, s2_t = grads(x1)
    iX2 = 1.0 / X[..., 2]
    fxb, fyb = fx[:, None], fy[:, None]
    pred = np.stack([fxb * X[..., 0] * iX2 + cx[:, None], fyb * X[..., 1] * iX2 + cy[:, None]], axis=-1)
    zero = np.zeros_like(iX2)
    Jp = np.stack([np.stack([fxb * iX2, zero, -fxb * X[..., 0] * iX2 * iX2], axis=-1),
                   np.stack([zero, fyb * iX2, -fyb * X[..., 1] * iX2 * iX2], axis=-1)], axis=-2)
    JpR = Jp @ np.swapaxes(R13, 1, 2)[:, None]  # Jp R13^T, (n, F, 2, 3)
    q1 = (JpR @ x1[..., None])[..., 0]
    q2 = (JpR @ t13b[..., None])[..., 0]
    J = np.empty(x1.shape[:2] + (2, 12))
    J[..., 0:3] = q1[..., None] * s1_psi[..., None, :] - q2[..., None] * s2_psi[..., None, :]
    J[..., 3:6] = q1[..., None] * s1_t[..., None, :] - q2[..., None] * s2_t[..., None, :]
    J[..., 6:9] = Jp @ skew_fast(X)
    J[..., 9:12] = -s2[..., None, None] * JpR
    return pred, J


def relative_poses(Rc, pc):
    """Camera poses of the triplet -> ``(R12, t12, R13, t13)``.

    Rc (3, n, 3, 3) ``R_world_cam`` and pc (3, n, 3) ``p_world_cam`` of images 1, 2, 3.
    """
    R1t = np.swapaxes(Rc[0], 1, 2)
    R12, R13 = R1t @ Rc[1], R1t @ Rc[2]
    t12 = (R1t @ (pc[1] - pc[0])[..., None])[..., 0]
    t13 = (R1t @ (pc[2] - pc[0])[..., None])[..., 0]
    return R12, t12, R13, t13


def triplet_residuals(uv_px, R12, t12, R13, t13, fx, fy, cx, cy):
    """Innovations ``r = z - h`` (n, F, 4) pixels and Jacobians ``J = dh/d[psi12, dt12, psi13, dt13]``
    (n, F, 4, 12), so that ``dr = -J d``, the Kalman convention.

    The epipolar measurements are ``z = 0`` with ``h`` the Sampson distance; the transfer is
    ``z = m3`` with ``h`` the transferred point. uv_px (F, 3, 2) pixels of the features in
    images 1, 2, 3, shared by the batch.
    """
    if uv_px.ndim != 3 or uv_px.shape[1:] != (3, 2):
        raise MeasurementError(f"triplet_residuals: uv_px must be (F, 3, 2) pixels, got {uv_px.shape}")
    x1 = normalised_points(uv_px[:, 0], fx, fy, cx, cy)
    x2 = normalised_points(uv_px[:, 1], fx, fy, cx, cy)
    x3 = normalised_points(uv_px[:, 2], fx, fy, cx, cy)
    n, F = x1.shape[:2]
    r = np.empty((n, F, 4))
    J = np.zeros((n, F, 4, 12))
    # Pair 2–3 expressed through the relative poses to camera 1:
    # R23 = R12^T R13, t23 = R12^T (t13 - t12); psi23 = psi13 - R23^T psi12,
    # dt23 = [t23]x psi12 + R12^T (dt13 - dt12).
    R23 = np.swapaxes(R12, 1, 2) @ R13
    t23 = (np.swapaxes(R12, 1, 2) @ (t13 - t12)[..., None])[..., 0]
    # Both pairs in one call (stacked on the batch axis): half the numpy calls.
    h, gp, gt, w = epipolar_sampson(np.concatenate([R12, R23]), np.concatenate([t12, t23]),
                                    np.concatenate([x1, x2]), np.concatenate([x2, x3]),
                                    np.concatenate([fx, fx]), np.concatenate([fy, fy]))
    r[..., 0], r[..., 1] = -h[:n], -h[n:]
    J[..., 0, 0:3], J[..., 0, 3:6], w12 = gp[:n], gt[:n], w[:n]
    g_psi, g_t = gp[n:], gt[n:]
    J[..., 1, 0:3] = -_rot(R23, g_psi) + _cross(g_t, np.broadcast_to(t23[:, None, :], g_t.shape))
    R12g = _rot(R12, g_t)
    J[..., 1, 3:6] = -R12g
    J[..., 1, 6:9] = g_psi
    J[..., 1, 9:12] = R12g
    pred, Jt = trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy)
    r[..., 2:4] = uv_px[None, :, 2, :] - pred
    J[..., 2:4, :] = Jt
    return r, J


def camera_pose_jacobian(R_world_imu, R_cam_imu, p_imu_cam):
    """(n, 6, 6) map from an IMU pose error ``[dp, dtheta]`` to the camera pose error
    ``[dp_cam, phi]`` (``R_world_cam <- R_world_cam exp(phi)``):
    ``phi = R_cam_imu dtheta``, ``dp_cam = dp - R_world_imu [p_imu_cam]x dtheta``."""
    n = R_cam_imu.shape[0]
    M = np.zeros((n, 6, 6))
    M[:, 0:3, 0:3] = np.eye(3)
    M[:, 0:3, 3:6] = -R_world_imu @ skew_fast(p_imu_cam)
    M[:, 3:6, 3:6] = R_cam_imu
    return M


def relative_pose_jacobian(Rc, t12, t13):
    """(n, 12, 18) map from the camera pose errors ``[dp_cam_i, phi_i]`` (i = 1, 2, 3, as
    produced by :func:`camera_pose_jacobian`, composed by the caller) to
    ``[psi12, dt12, psi13, dt13]``:
    ``psi1j = phi_j - R1j^T phi_1``, ``dt1j = [t1j]x phi_1 + R_world_cam1^T (dp_cam_j - dp_cam_1)``.

    Rc (3, n, 3, 3) camera rotations ``R_world_cam`` of images 1, 2, 3.
    """
    n = Rc.shape[1]
    D = np.zeros((n, 12, 18))
    R1t = np.swapaxes(Rc[0], 1, 2)
    for j, (row, t1j) in enumerate(((0, t12), (6, t13)), start=1):
        R1jt = np.swapaxes(R1t @ Rc[j], 1, 2)
        D[:, row:row + 3, 6 * j + 3:6 * j + 6] = np.eye(3)
        D[:, row:row + 3, 3:6] = -R1jt
        D[:, row + 3:row + 6, 3:6] = skew_fast(t1j)
        D[:, row + 3:row + 6, 6 * j:6 * j + 3] = R1t
        D[:, row + 3:row + 6, 0:3] = -R1t
    return D
