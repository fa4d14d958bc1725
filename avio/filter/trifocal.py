"""The trifocal residuals of one feature and their derivatives (docs/model.md, Eqs. 25-34), run on
LANES features at once.

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

Jacobians are taken with respect to the 12 relative-pose perturbations
``[psi12, dt12, psi13, dt13]`` with ``R1j <- R1j exp(psi1j)``, ``t1j <- t1j + dt1j`` (Eqs. 30-33);
avio/filter/measurement.py chains them to the filter's 27-dim error state (Eqs. 20-24).

Compiled with numba (``cache=True``, no fastmath, so results are deterministic). The filter runs
the arithmetic on LANES features at once (:func:`features_block`): one loop over the features
whose body is :func:`_feature_into` with every helper ``inline="always"`` and no loop left
inside, writing scratch whose rows lie a compile-time stride apart, so LLVM vectorises it across
the features (issue 30: 3.05 -> 2.0 µs per call of measure with 16 features, the filter 1.036x,
same bits; benchmarks/README.md). :func:`feature_residuals` is the same arithmetic for one
feature (tests, studies). Vectors are passed as 3-tuples (values, no allocation).
"""

from __future__ import annotations

import numpy as np

from avio.filter._simd import kernel_jit


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
    # Squares as products: numba's ``** 2`` is a loop (by squaring), which keeps the features' loop
    # around this (measure) from vectorising; x * x is the same number.
    wx, wy, ux, uy = w[0] * ifx, w[1] * ify, u[0] * ifx, u[1] * ify
    s = np.sqrt(wx * wx + wy * wy + ux * ux + uy * uy)
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
def _transfer_row(jp, R13, x1, t13, X, s1_psi, s1_t, s2_psi, s2_t, s2, J, row, S, f):
    # One row of Eq. (32) into row ``row`` of feature f's J (flat, stride S), from jp, that row of
    # Jp = d(pixel)/dX.
    jpr = rot(R13, jp)  # the row of Jp R13^T
    q1, q2 = dot(jpr, x1), dot(jpr, t13)
    jx = cross(jp, X)  # the row of Jp [X]x
    for c in range(3):
        J[(row * 12 + c) * S + f] = q1 * s1_psi[c] - q2 * s2_psi[c]
        J[(row * 12 + 3 + c) * S + f] = q1 * s1_t[c] - q2 * s2_t[c]
        J[(row * 12 + 6 + c) * S + f] = jx[c]
        J[(row * 12 + 9 + c) * S + f] = -s2 * jpr[c]


@kernel_jit(inline="always")
def trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy, J, S, f):
    """Point transfer 1→3 (pixels) of one feature; writes its Jacobian w.r.t.
    ``[psi12, dt12, psi13, dt13]`` into rows 2-3 of feature f's column of J and returns ``(u, v)``
    (J: a flat (4 * 12 * S,) array, entry (a, b) of feature f at ``(12 a + b) S + f``, S the feature
    stride: :func:`_feature_into`).

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
    # Eq. (32), one pixel row at a time: row i of Jp = d(pixel_i)/dX, (f iX2 e_i - f X_i iX2^2 e_2).
    # Written out rather than a loop over the 2 rows: the loop over the features around this
    # (measure) vectorises only when it contains no loop (LLVM's full unroll stops short of this body).
    _transfer_row((fx * iX2, 0.0, -fx * X[0] * iX2 * iX2), R13, x1, t13, X, s1_psi, s1_t, s2_psi, s2_t, s2, J, 2, S, f)
    _transfer_row((0.0, fy * iX2, -fy * X[1] * iX2 * iX2), R13, x1, t13, X, s1_psi, s1_t, s2_psi, s2_t, s2, J, 3, S, f)
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
def transfer_pixel_jacobian(R12, t12, R13, t13, x1, x2, w12, fx, fy, G, S, f):
    """-d(transfer pixel (u, v)) / d(u1, v1, u2, v2) into rows 2-3, columns 0-3 of feature f's G
    (flat, entry (a, c) at ``(6 a + c) S + f``, as J in :func:`trifocal_transfer`): how the
    transferred point moves with the measured points of images 1 and 2 (through x1, the epipolar
    line w12 of x1 and the perpendicular line through x2), negated as the residual ``m3 - (u, v)``
    sees it; the noise amplification of the transfer (docs/model.md, Eq. 34)."""
    a = fx / fy
    ia = 1.0 / a
    w0, w1 = w12[0], w12[1]
    l_n = (a * w1, -w0 * ia, -a * x2[0] * w1 + x2[1] * w0 * ia)
    lam = rot(R12, l_n)
    s1, s2 = dot(lam, t12), dot(lam, x1)
    X = rot_t(R13, _axpy(s1, x1, -s2, t13))
    # The four columns written out (as in trifocal_transfer: no loop inside the features' loop).
    _transfer_pix_col(R12, t12, R13, t13, x1, x2, lam, s1, s2, X, (1.0 / fx, 0.0, 0.0), a, ia, fx, fy, G, 0, S, f)
    _transfer_pix_col(R12, t12, R13, t13, x1, x2, lam, s1, s2, X, (0.0, 1.0 / fy, 0.0), a, ia, fx, fy, G, 1, S, f)
    zero = (0.0, 0.0, 0.0)
    du, dv = _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, zero, (0.0, 0.0, -a * w1 / fx), fx, fy)
    G[(2 * 6 + 2) * S + f], G[(3 * 6 + 2) * S + f] = -du, -dv
    du, dv = _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, zero, (0.0, 0.0, w0 * ia / fy), fx, fy)
    G[(2 * 6 + 3) * S + f], G[(3 * 6 + 3) * S + f] = -du, -dv


@kernel_jit(inline="always")
def _transfer_pix_col(R12, t12, R13, t13, x1, x2, lam, s1, s2, X, dx1, a, ia, fx, fy, G, c, S, f):
    # Column c of transfer_pixel_jacobian for a move dx1 of x1 (normalised): through x1 and w12.
    dw = rot_t(R12, cross(t12, dx1))
    dl = (a * dw[1], -dw[0] * ia, -a * x2[0] * dw[1] + x2[1] * dw[0] * ia)
    du, dv = _transfer_dpix(R12, t12, R13, t13, x1, lam, s1, s2, X, dx1, dl, fx, fy)
    G[(2 * 6 + c) * S + f], G[(3 * 6 + c) * S + f] = -du, -dv


@kernel_jit
def feature_residuals(uv, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, r, J, G, pair23=True):
    """Innovations ``r = z - h`` (4,) pixels, Jacobian ``J = dh/d[psi12, dt12, psi13, dt13]``
    (4, 12) of one feature (written into r, J), so that ``dr = -J d``, the Kalman convention,
    and ``G = dr / d(u1, v1, u2, v2, u3, v3)`` (4, 6), the residuals' sensitivity to the pixel
    measurements: with independent pixel noise of sigma px the residuals' covariance is
    ``sigma^2 G G^T`` (the two Sampson distances share m2 and the transfer reads all three
    images, so it is not diagonal). r, J, G contiguous.

    uv (3, 2) pixels in images 1, 2, 3; R12, R13, R23 (3, 3) and t12, t13, t23 (3-tuples) the
    relative poses (``R23 = R12^T R13``, ``t23 = R12^T (t13 - t12)``). The epipolar
    measurements are ``z = 0`` with ``h`` the Sampson distance; the transfer is ``z = m3``.
    Pair 2–3 is chained to camera 1: ``psi23 = psi13 - R23^T psi12``,
    ``dt23 = [t23]x psi12 + R12^T (dt13 - dt12)``. ``pair23=False`` skips r1 (row 1 of r, J
    and G are zero): the filter's update does not use it (avio/filter/update.py, USED_RESIDUALS);
    skipping it made the whole filter 8 % cheaper (benchmarks/README.md: the Sampson A/B).
    The filter runs the same arithmetic on all features at once (measurement.measure: :func:`features_block`).
    docs/model.md: r Eq. 29, J Eqs. 30-33, G Eq. 34.
    """
    r[0], r[1], r[2], r[3] = one_feature(uv, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, J.reshape(48),
                                          G.reshape(24), pair23)


@kernel_jit(inline="always")
def _feature_into(u1, v1, u2, v2, u3, v3, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, J, G, S, f, pair23):
    """:func:`feature_residuals` of the feature at pixels (u1, v1), (u2, v2), (u3, v3): its
    Jacobian and pixel sensitivities into feature f of the flat arrays J (4 * 12 * S,) and G
    (4 * 6 * S,) (entry (a, b) at ``(12 a + b) S + f``, resp. ``(6 a + b) S + f``: features last,
    S apart); returns its 4 innovations. Inlined into :func:`features_block`'s loop over the
    features, whose body then has no call and no loop and whose stores lie a compile-time S
    apart, so LLVM runs it on several features per instruction (the same operations per
    feature: the same bits)."""
    ifx, ify = 1.0 / fx, 1.0 / fy
    x1 = ((u1 - cx) * ifx, (v1 - cy) * ify, 1.0)
    x2 = ((u2 - cx) * ifx, (v2 - cy) * ify, 1.0)
    x3 = ((u3 - cx) * ifx, (v3 - cy) * ify, 1.0)
    # Eq. (29), row 0: the 1-2 Sampson distance; G row 0: Eq. (34).
    h0, gp0, gt0, w12, gx0 = epipolar_sampson(R12, t12, x1, x2, fx, fy)
    for c in range(6):
        for a in range(4):
            G[(a * 6 + c) * S + f] = 0.0
    for c in range(4):
        G[c * S + f] = -gx0[c]
    # Eq. (34): the transfer rows of G, [-dm3/d(m1, m2), I].
    transfer_pixel_jacobian(R12, t12, R13, t13, x1, x2, w12, fx, fy, G, S, f)
    for a in range(2):
        G[((2 + a) * 6 + 4 + a) * S + f] = 1.0
    for c in range(3):
        J[c * S + f], J[(3 + c) * S + f] = gp0[c], gt0[c]
        J[(6 + c) * S + f], J[(9 + c) * S + f] = 0.0, 0.0
    r1 = 0.0
    if pair23:
        h1, gp1, gt1, _, gx1 = epipolar_sampson(R23, t23, x2, x3, fx, fy)
        r1 = -h1
        for c in range(4):
            G[(1 * 6 + 2 + c) * S + f] = -gx1[c]
        Rg = rot(R23, gp1)
        gx = cross(gt1, t23)
        R12g = rot(R12, gt1)
        for c in range(3):
            J[(1 * 12 + c) * S + f] = -Rg[c] + gx[c]
            J[(1 * 12 + 3 + c) * S + f] = -R12g[c]
            J[(1 * 12 + 6 + c) * S + f] = gp1[c]
            J[(1 * 12 + 9 + c) * S + f] = R12g[c]
    else:
        for c in range(12):
            J[(1 * 12 + c) * S + f] = 0.0
    # Eq. (29), rows 2-3: m3 minus the transfer (Eq. 28); J rows 2-3: Eq. (32).
    u, v = trifocal_transfer(R12, t12, R13, t13, x1, x2, w12, fx, fy, cx, cy, J, S, f)
    return -h0, r1, u3 - u, v3 - v


#: Features per block of :func:`measure`: a block's features run in SIMD lanes. The block's scratch
#: has this compile-time stride, so LLVM sees the rows of J and G apart without runtime alias checks
#: (with the runtime feature count as stride it gives up: "too many memory checks").
LANES = 8


@kernel_jit
def features_block(uL, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, rL, JL, GL):
    """:func:`_feature_into` of the LANES features of a block, without the unused Sampson distance
    2-3 (``pair23=False``, the filter's update): pixels uL (6 * LANES,) (row ``2 i + j``: image
    i's coordinate j), innovations rL (4 * LANES,), Jacobians JL (48 * LANES,) and pixel
    sensitivities GL (24 * LANES,), all features last."""
    for f in range(LANES):
        rL[f], rL[LANES + f], rL[2 * LANES + f], rL[3 * LANES + f] = _feature_into(
            uL[f], uL[LANES + f], uL[2 * LANES + f], uL[3 * LANES + f], uL[4 * LANES + f], uL[5 * LANES + f],
            R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, JL, GL, LANES, f, False)


@kernel_jit
def one_feature(uv, R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, J, G, pair23):
    """:func:`_feature_into` of one feature at pixels uv (3, 2), into J (48,) and G (24,) (stride
    1); returns its 4 innovations."""
    return _feature_into(uv[0, 0], uv[0, 1], uv[1, 0], uv[1, 1], uv[2, 0], uv[2, 1], R12, t12, R13, t13, R23, t23,
                         fx, fy, cx, cy, J, G, 1, 0, pair23)
