"""Trifocal measurement model of the filter: residuals and analytic Jacobians (docs/model.md,
Sections "Time offset" to "Noise model", Eqs. 19-34).

For a feature seen in images 1, 2, 3 (frames k-2, k-1, k) at pixels m1, m2, m3, four residuals
in pixels:

- r0: Sampson distance of the epipolar constraint 1–2 (Eqs. 25-26), ``m2^T K^-T R12^T [t12]x K^-1 m1`` divided
  by the norm of the first two entries of ``F m1`` and ``F^T m2`` (first-order geometric
  distance, pixels; the algebraic value in normalised coordinates would carry almost no weight);
- r1: the same for images 2–3;
- r2, r3: ``m3`` minus the trifocal point transfer 1→3 through image 2 (Eqs. 27-28; point–line–point
  transfer; the line through m2 perpendicular to the epipolar line ``F12 m1``):
  ``x3 ∝ -(l'·a4) B x1 + (l'·A x1) b4`` with ``P2 = [A|a4]``, ``P3 = [B|b4]`` relative to
  camera 1.

Relative poses (Eq. 21; camera frames, x right, y down, z forward): ``R1j = R_world_cam1^T R_world_camj``
maps camera-j vectors into camera 1, ``t1j = R_world_cam1^T (p_world_camj - p_world_cam1)``
is camera j's origin in camera 1.

Jacobians are taken with respect to the 12 relative-pose perturbations
``[psi12, dt12, psi13, dt13]`` with ``R1j <- R1j exp(psi1j)``, ``t1j <- t1j + dt1j`` (Eqs. 30-33);
:func:`measure` chains them to the filter's 27-dim error state (Eqs. 20-24).

The per-feature arithmetic is compiled with numba (``cache=True``, no fastmath, so results are
deterministic): the filter calls :func:`feature_residuals` for every feature of every filter
of every frame, where numpy's per-call overhead on (n, F, 3) arrays cost more than the maths.
The helpers of :func:`feature_residuals` are ``inline="always"`` (inlined by numba into it): as
calls, passing their arrays and tuples cost ~40 % of the measurement's time (issue 13: the
filter 1.08x faster, same bits, +4 s of first compile; inlining feature_residuals itself into
the kernel too gained about as much again but cost +20 s of compile, so it stays a call).
Vectors are passed as 3-tuples (values, no allocation). Shapes: n filters, F features.
"""

from __future__ import annotations

import numpy as np

from avio.errors import AvioError
from avio.filter._linalg import corrected_pixels, matmul, so3_exp
from avio.filter._simd import kernel_jit
from avio.filter.interface import MeasureWorkspace


class MeasurementError(AvioError):
    """Bad input to the measurement model; the message names what and where."""


@kernel_jit(inline="always")
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel_jit(inline="always")
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel_jit(inline="always")
def rot(R, x):
    """R (3, 3) array applied to the 3-tuple x."""
    return (R[0, 0] * x[0] + R[0, 1] * x[1] + R[0, 2] * x[2],
            R[1, 0] * x[0] + R[1, 1] * x[1] + R[1, 2] * x[2],
            R[2, 0] * x[0] + R[2, 1] * x[1] + R[2, 2] * x[2])


@kernel_jit(inline="always")
def rot_t(R, x):
    """R^T applied to the 3-tuple x."""
    return (R[0, 0] * x[0] + R[1, 0] * x[1] + R[2, 0] * x[2],
            R[0, 1] * x[0] + R[1, 1] * x[1] + R[2, 1] * x[2],
            R[0, 2] * x[0] + R[1, 2] * x[1] + R[2, 2] * x[2])


@kernel_jit(inline="always")
def _axpy(a, x, b, y):
    """a x + b y for scalars a, b and 3-tuples x, y."""
    return (a * x[0] + b * y[0], a * x[1] + b * y[1], a * x[2] + b * y[2])


@kernel_jit(inline="always")
def epipolar_sampson(R_ab, t, xa, xb, fx, fy):
    """Sampson distance (pixels) of ``xb^T R_ab^T [t]x xa = 0`` and its gradient, one feature.

    R_ab (3, 3), t (3-tuple): pose of camera b in camera a; xa, xb normalised homogeneous
    points (3-tuples); fx, fy pixels. Returns ``r``, ``g_psi``, ``g_t`` (derivatives w.r.t.
    ``R_ab <- R_ab exp(psi)``, ``t <- t + dt``), ``w = R_ab^T (t x xa)``, the epipolar line
    in normalised coordinates of b, and ``g_pix = dr / d(ua, va, ub, vb)`` (4-tuple, 1/px·px:
    the unit-norm pixel gradient of the Sampson distance, whose denominator is exactly that
    gradient's norm; first order, as the distance itself).
    docs/model.md: e, w Eq. 25 (u there is n), r Eq. 26, gradients Eqs. 30-31, g_pix Eq. 34.
    """
    # Eq. (25)
    c = cross(t, xa)
    Rxb = rot(R_ab, xb)
    e = dot(Rxb, c)
    w = rot_t(R_ab, c)
    u = cross(Rxb, t)
    ifx, ify = 1.0 / fx, 1.0 / fy
    gam = (w[0] * ifx * ifx, w[1] * ify * ify, 0.0)
    eta = (u[0] * ifx * ifx, u[1] * ify * ify, 0.0)
    # Eq. (26): the Sampson distance e / s.
    s = np.sqrt((w[0] * ifx) ** 2 + (w[1] * ify) ** 2 + (u[0] * ifx) ** 2 + (u[1] * ify) ** 2)
    i_s = 1.0 / s
    r = e * i_s
    # Eqs. (30)-(31): de/dpsi, de/dt and the terms of ds/dpsi, ds/dt.
    de_psi = cross(xb, w)
    de_t = cross(xa, Rxb)
    a1, a2 = cross(gam, w), cross(xb, rot_t(R_ab, cross(t, eta)))
    b1, b2 = cross(xa, rot(R_ab, gam)), cross(eta, Rxb)
    # g = (de - r ds) / s with ds = (a1 + a2) / s (psi) or (b1 + b2) / s (t).
    ri = r * i_s
    g_psi = ((de_psi[0] - ri * (a1[0] + a2[0])) * i_s, (de_psi[1] - ri * (a1[1] + a2[1])) * i_s,
             (de_psi[2] - ri * (a1[2] + a2[2])) * i_s)
    g_t = ((de_t[0] - ri * (b1[0] + b2[0])) * i_s, (de_t[1] - ri * (b1[1] + b2[1])) * i_s,
           (de_t[2] - ri * (b1[2] + b2[2])) * i_s)
    # Eq. (34): the unit pixel gradient.
    g_pix = (u[0] * ifx * i_s, u[1] * ify * i_s, w[0] * ifx * i_s, w[1] * ify * i_s)
    return r, g_psi, g_t, w, g_pix


@kernel_jit(inline="always")
def _transfer_grads(y, R12, l_n, w12, x1, x20, x21, a, ia):
    # d(y·lam)/d psi12 and / d t12 (lam = R12 l_n; the closed form of docs/model.md Eq. 28,
    # differentiated: Eq. 33).
    yt = rot_t(R12, y)
    z = (-yt[1] * ia + x21 * yt[2] * ia, a * yt[0] - a * x20 * yt[2], 0.0)  # L^T yt
    g1, g2 = cross(l_n, yt), cross(z, w12)
    return (g1[0] + g2[0], g1[1] + g2[1], g1[2] + g2[2]), cross(x1, rot(R12, z))


@kernel_jit(inline="always")
def trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy, J):
    """Point transfer 1→3 (pixels) of one feature; writes its Jacobian w.r.t.
    ``[psi12, dt12, psi13, dt13]`` into J (2, 12) and returns ``(u, v)``.

    x1, x2 normalised points in images 1, 2; w12 the epipolar line of x1 in image 2
    (normalised, from :func:`epipolar_sampson`). The perpendicular through m2 is taken in
    pixels (as the paper's point–line–point transfer), then mapped to normalised coordinates:
    ``l_n = K^T l_px = (a w1, -w0 / a, -a x2_0 w1 + x2_1 w0 / a)``, ``a = fx/fy``.
    docs/model.md: l_n Eq. 27, the transfer Eq. 28, its Jacobian Eqs. 32-33.
    """
    a = fx / fy
    ia = 1.0 / a
    w0, w1 = w12[0], w12[1]
    x20, x21 = x2[0], x2[1]
    # Eq. (27)
    l_n = (a * w1, -w0 * ia, -a * x20 * w1 + x21 * w0 * ia)
    # Eq. (28)
    lam = rot(R12, l_n)  # R12 l_n: P2 = [R12^T | -R12^T t12] makes l·a4 = -(R12 l)·t12
    s1 = dot(lam, t12)
    s2 = dot(lam, x1)
    X = rot_t(R13, _axpy(s1, x1, -s2, t13))
    # Eq. (33)
    s1_psi, s1_t = _transfer_grads(t12, R12, l_n, w12, x1, x20, x21, a, ia)
    s1_t = (s1_t[0] + lam[0], s1_t[1] + lam[1], s1_t[2] + lam[2])
    s2_psi, s2_t = _transfer_grads(x1, R12, l_n, w12, x1, x20, x21, a, ia)
    iX2 = 1.0 / X[2]
    fs = (fx, fy)
    # Eq. (32), one pixel row at a time.
    for i in range(2):
        # Row i of Jp = d(pixel_i)/dX: (f iX2 e_i - f X_i iX2^2 e_2).
        jp = (fs[i] * iX2 if i == 0 else 0.0, fs[i] * iX2 if i == 1 else 0.0, -fs[i] * X[i] * iX2 * iX2)
        jpr = rot(R13, jp)  # row i of Jp R13^T
        q1, q2 = dot(jpr, x1), dot(jpr, t13)
        jx = cross(jp, X)  # row i of Jp [X]x
        for c in range(3):
            J[i, c] = q1 * s1_psi[c] - q2 * s2_psi[c]
            J[i, 3 + c] = q1 * s1_t[c] - q2 * s2_t[c]
            J[i, 6 + c] = jx[c]
            J[i, 9 + c] = -s2 * jpr[c]
    return fx * X[0] * iX2 + cx, fy * X[1] * iX2 + cy


@kernel_jit(inline="always")
def _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, dx1, dl, fx, fy):
    """(du, dv) pixels of the transfer for a perturbation dx1 of x1 and dl of the line l_n."""
    dlam = rot(R12, dl)
    ds1 = dot(dlam, t12)
    ds2 = dot(dlam, x1) + dot(lam, dx1)
    dX = rot_t(R13, (ds1 * x1[0] + s1 * dx1[0] - ds2 * t13[0], ds1 * x1[1] + s1 * dx1[1] - ds2 * t13[1],
                     ds1 * x1[2] + s1 * dx1[2] - ds2 * t13[2]))
    iX2 = 1.0 / X[2]
    return (fx * (dX[0] * X[2] - X[0] * dX[2]) * iX2 * iX2, fy * (dX[1] * X[2] - X[1] * dX[2]) * iX2 * iX2)


@kernel_jit(inline="always")
def transfer_pixel_jacobian(R12, t12, R13, t13, x1, x2, w12, fx, fy, G):
    """d(transfer pixel (u, v)) / d(u1, v1, u2, v2) into G (2, 4): how the transferred point
    moves with the measured points of images 1 and 2 (through x1, the epipolar line w12 of x1
    and the perpendicular line through x2); the noise amplification of the transfer
    (docs/model.md, Eq. 34)."""
    a = fx / fy
    ia = 1.0 / a
    w0, w1 = w12[0], w12[1]
    l_n = (a * w1, -w0 * ia, -a * x2[0] * w1 + x2[1] * w0 * ia)
    lam = rot(R12, l_n)
    s1, s2 = dot(lam, t12), dot(lam, x1)
    X = rot_t(R13, _axpy(s1, x1, -s2, t13))
    for c in range(2):
        dx1 = (1.0 / fx if c == 0 else 0.0, 1.0 / fy if c == 1 else 0.0, 0.0)
        dw = rot_t(R12, cross(t12, dx1))
        dl = (a * dw[1], -dw[0] * ia, -a * x2[0] * dw[1] + x2[1] * dw[0] * ia)
        du, dv = _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, dx1, dl, fx, fy)
        G[0, c], G[1, c] = du, dv
    zero = (0.0, 0.0, 0.0)
    for c in range(2):
        dl = (0.0, 0.0, -a * w1 / fx if c == 0 else w0 * ia / fy)
        du, dv = _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, zero, dl, fx, fy)
        G[0, 2 + c], G[1, 2 + c] = du, dv


@kernel_jit
def feature_residuals(uv, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, r, J, G, pair23=True):
    """Innovations ``r = z - h`` (4,) pixels, Jacobian ``J = dh/d[psi12, dt12, psi13, dt13]``
    (4, 12) of one feature (written into r, J), so that ``dr = -J d``, the Kalman convention,
    and ``G = dr / d(u1, v1, u2, v2, u3, v3)`` (4, 6), the residuals' sensitivity to the pixel
    measurements: with independent pixel noise of sigma px the residuals' covariance is
    ``sigma^2 G G^T`` (the two Sampson distances share m2 and the transfer reads all three
    images, so it is not diagonal).

    uv (3, 2) pixels in images 1, 2, 3; R12, R13, R23 (3, 3) and t12, t13, t23 (3-tuples) the
    relative poses (``R23 = R12^T R13``, ``t23 = R12^T (t13 - t12)``). The epipolar
    measurements are ``z = 0`` with ``h`` the Sampson distance; the transfer is ``z = m3``.
    Pair 2–3 is chained to camera 1: ``psi23 = psi13 - R23^T psi12``,
    ``dt23 = [t23]x psi12 + R12^T (dt13 - dt12)``. ``pair23=False`` skips r1 (row 1 of r, J
    and G are zero): the filter's update does not use it (avio/filter/update.py, USED_RESIDUALS);
    skipping it made the whole filter 8 % cheaper (benchmarks/README.md: the Sampson A/B).
    docs/model.md: r Eq. 29, J Eqs. 30-33, G Eq. 34.
    """
    ifx, ify = 1.0 / fx, 1.0 / fy
    x1 = ((uv[0, 0] - cx) * ifx, (uv[0, 1] - cy) * ify, 1.0)
    x2 = ((uv[1, 0] - cx) * ifx, (uv[1, 1] - cy) * ify, 1.0)
    x3 = ((uv[2, 0] - cx) * ifx, (uv[2, 1] - cy) * ify, 1.0)
    # Eq. (29), row 0: the 1-2 Sampson distance; G row 0: Eq. (34).
    h0, gp0, gt0, w12, gx0 = epipolar_sampson(R12, t12, x1, x2, fx, fy)
    r[0] = -h0
    for c in range(6):
        for a in range(4):
            G[a, c] = 0.0
    for c in range(4):
        G[0, c] = -gx0[c]
    # Eq. (34): the transfer rows of G, [-dm3/d(m1, m2), I].
    transfer_pixel_jacobian(R12, t12, R13, t13, x1, x2, w12, fx, fy, G[2:4, 0:4])
    for a in range(2):
        for c in range(4):
            G[2 + a, c] = -G[2 + a, c]
        G[2 + a, 4 + a] = 1.0
    for c in range(3):
        J[0, c], J[0, 3 + c] = gp0[c], gt0[c]
        J[0, 6 + c], J[0, 9 + c] = 0.0, 0.0
    if pair23:
        h1, gp1, gt1, _, gx1 = epipolar_sampson(R23, t23, x2, x3, fx, fy)
        r[1] = -h1
        for c in range(4):
            G[1, 2 + c] = -gx1[c]
        Rg = rot(R23, gp1)
        gx = cross(gt1, t23)
        R12g = rot(R12, gt1)
        for c in range(3):
            J[1, c] = -Rg[c] + gx[c]
            J[1, 3 + c] = -R12g[c]
            J[1, 6 + c] = gp1[c]
            J[1, 9 + c] = R12g[c]
    else:
        r[1] = 0.0
        for c in range(12):
            J[1, c] = 0.0
    # Eq. (29), rows 2-3: m3 minus the transfer (Eq. 28); J rows 2-3: Eq. (32).
    u, v = trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy, J[2:4])
    r[2], r[3] = uv[2, 0] - u, uv[2, 1] - v


@kernel_jit
def shifted_pose(R, p, v, omega, td, R3, p3, J, E):
    """Exposure-time IMU pose of one filter, ``(p + v td, R exp(w td))``, into p3 (3,), R3 (3, 3),
    and its (6, 15) Jacobian J w.r.t. the core error ``[dp, dtheta, dv, db_a, db_g]``
    (E (3, 3): scratch). docs/model.md, Eq. 19."""
    so3_exp(omega[0] * td, omega[1] * td, omega[2] * td, E)
    matmul(R, E, R3)
    J[:] = 0.0
    for i in range(3):
        p3[i] = p[i] + v[i] * td
        J[i, i] = 1.0
        J[i, 6 + i] = td
        J[3 + i, 12 + i] = -td
        for j in range(3):
            J[3 + i, 3 + j] = E[j, i]



@kernel_jit
def measure_workspace():
    """Scratch arrays of :func:`measure` (allocated once per batch, not per filter;
    avio.filter.interface.MeasureWorkspace)."""
    return MeasureWorkspace(R3=np.empty((3, 3)), p3=np.empty(3), Jsh=np.empty((6, 15)), Rc=np.empty((3, 3, 3)),
                            pc=np.empty((3, 3)), G=np.zeros((18, 27)), M=np.empty((6, 6)), R12=np.empty((3, 3)),
                            R13=np.empty((3, 3)), R23=np.empty((3, 3)), D=np.zeros((12, 18)), E=np.empty((3, 3)),
                            uc=np.empty((3, 2)), rc=np.empty(4))



@kernel_jit
def measure(R, p, v, cp0, cR0, cp1, cR1, omega, td, fx, fy, cx, cy, Rci, pic, uv, r, J, Gp, C, t12, t13, ws, pair23,
            cap=0.0):
    """Innovations r (4, F) pixels, their Jacobians J (4, 12, F) w.r.t. the relative-pose errors
    ``[psi12, dt12, psi13, dt13]``, their pixel sensitivities Gp (4, 6, F) (the measurement
    noise model, avio.filter.measurement.feature_residuals, which writes one feature's column: features
    last, as the update uses them) and the map C (12, 27) from the error
    state to those (so ``H = J C``, ``dr = -H dx``) of one filter, written into the arrays;
    also t12, t13 (3,).

    Chain: state error -> exposure-time IMU poses of images 1, 2, 3 (clones, shifted current
    pose) -> camera pose errors ``[dp_cam, phi]`` (``phi = R_cam_imu dtheta``,
    ``dp_cam = dp - R_world_imu [p_imu_cam]x dtheta``) -> relative-pose errors
    (``psi1j = phi_j - R1j^T phi_1``, ``dt1j = [t1j]x phi_1 + R_world_cam1^T (dp_cam_j - dp_cam_1)``)
    -> residuals (:func:`feature_residuals`). ``pair23=False`` leaves residual 1 (the
    Sampson distance 2-3, which the update does not use) zero. With ``cap > 0`` (px) each feature's
    J and Gp are taken again at its corrected pixels (:func:`corrected_pixels`, Eq. 35a, the step
    at most ``cap`` long; r stays the measured pixels' innovation).
    docs/model.md: shifted pose Eq. 19, camera poses Eq. 20, relative poses Eq. 21, camera pose
    errors Eq. 22, relative-pose errors Eq. 23, C Eq. 24.
    """
    R3, p3, Jsh, Rc, pc, G, M, R12, R13 = ws.R3, ws.p3, ws.Jsh, ws.Rc, ws.pc, ws.G, ws.M, ws.R12, ws.R13
    R23, D, E, uc, rc = ws.R23, ws.D, ws.E, ws.uc, ws.rc
    # Eq. (19): the exposure-time pose of image 3.
    shifted_pose(R, p, v, omega, td, R3, p3, Jsh, E)
    # G (18, 27): camera pose errors of images 1, 2, 3 <- state error; D (12, 18): camera pose
    # errors -> relative-pose errors. Both keep their zero pattern between calls (the
    # workspace starts at zero), only the blocks below are rewritten.
    for a in range(3):
        Ri = cR0 if a == 0 else (cR1 if a == 1 else R3)
        pi = cp0 if a == 0 else (cp1 if a == 1 else p3)
        for i in range(3):
            for j in range(3):
                Rc[a, i, j] = Ri[i, 0] * Rci[j, 0] + Ri[i, 1] * Rci[j, 1] + Ri[i, 2] * Rci[j, 2]
            pc[a, i] = pi[i] + Ri[i, 0] * pic[0] + Ri[i, 1] * pic[1] + Ri[i, 2] * pic[2]
        # Eq. (20): camera pose of image a+1 (Rc = R_world_imu R_cam_imu^T, pc = p + R p_imu_cam).
        # Eq. (22): M = [[I, -R_imu [pic]x], [0, R_cam_imu]]
        M[:] = 0.0
        for i in range(3):
            M[i, i] = 1.0
            col = (Ri[i, 1] * pic[2] - Ri[i, 2] * pic[1], Ri[i, 2] * pic[0] - Ri[i, 0] * pic[2],
                   Ri[i, 0] * pic[1] - Ri[i, 1] * pic[0])  # row i of R_imu [pic]x
            for j in range(3):
                M[i, 3 + j] = -col[j]
                M[3 + i, 3 + j] = Rci[i, j]
        if a == 2:
            matmul(M, Jsh, G[12:18, 0:15])
        else:
            for i in range(6):
                for j in range(6):
                    G[6 * a + i, 15 + 6 * a + j] = M[i, j]
    # Eq. (21): relative poses.
    for i in range(3):
        for j in range(3):
            R12[i, j] = Rc[0, 0, i] * Rc[1, 0, j] + Rc[0, 1, i] * Rc[1, 1, j] + Rc[0, 2, i] * Rc[1, 2, j]
            R13[i, j] = Rc[0, 0, i] * Rc[2, 0, j] + Rc[0, 1, i] * Rc[2, 1, j] + Rc[0, 2, i] * Rc[2, 2, j]
    for i in range(3):
        for j in range(3):
            R23[i, j] = R12[0, i] * R13[0, j] + R12[1, i] * R13[1, j] + R12[2, i] * R13[2, j]
    R1 = Rc[0]
    a12 = rot_t(R1, (pc[1, 0] - pc[0, 0], pc[1, 1] - pc[0, 1], pc[1, 2] - pc[0, 2]))
    a13 = rot_t(R1, (pc[2, 0] - pc[0, 0], pc[2, 1] - pc[0, 1], pc[2, 2] - pc[0, 2]))
    a23 = rot_t(R12, (a13[0] - a12[0], a13[1] - a12[1], a13[2] - a12[2]))
    for i in range(3):
        t12[i], t13[i] = a12[i], a13[i]
    for f in range(uv.shape[0]):
        feature_residuals(uv[f], R12, a12, R13, a13, R23, a23, fx, fy, cx, cy, r[:, f], J[:, :, f], Gp[:, :, f],
                          pair23)
        if cap > 0.0 and corrected_pixels(uv[f], r[:, f], Gp[:, :, f], cap, uc):
            feature_residuals(uc, R12, a12, R13, a13, R23, a23, fx, fy, cx, cy, rc, J[:, :, f], Gp[:, :, f], pair23)
    # Eq. (23): D (12, 18), camera pose errors -> relative-pose errors.
    for jj in range(2):
        row, Rj, t = 6 * jj, (R12 if jj == 0 else R13), (a12 if jj == 0 else a13)
        col = 6 * (jj + 1)
        for i in range(3):
            D[row + i, col + 3 + i] = 1.0
            for k in range(3):
                D[row + i, 3 + k] = -Rj[k, i]  # -R1j^T
                D[row + 3 + i, col + k] = R1[k, i]  # R_world_cam1^T
                D[row + 3 + i, k] = -R1[k, i]
        D[row + 3, 4], D[row + 3, 5] = -t[2], t[1]  # [t1j]x
        D[row + 4, 3], D[row + 4, 5] = t[2], -t[0]
        D[row + 5, 3], D[row + 5, 4] = -t[1], t[0]
    # Eq. (24): C = D G, each row of G only over its block's columns (images 1, 2: clones; 3: core).
    for i in range(12):
        for j in range(27):
            C[i, j] = 0.0
        for k in range(18):
            f = D[i, k]
            if f != 0.0:
                lo, hi = (15, 21) if k < 6 else ((21, 27) if k < 12 else (0, 15))
                for j in range(lo, hi):
                    C[i, j] += f * G[k, j]
