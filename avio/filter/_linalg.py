"""Small dense linear algebra and rotations compiled with numba (``cache=True``, no fastmath),
for the per-filter kernels of the VIO filter (avio/filter/kernels.py, update.py, measurement.py,
outliers.py, propagation.py), and the least-norm pixel correction of one feature (Eq. 35a).

Hand-written because the matrices are 3x3 to 27x27: a LAPACK/BLAS call or a numpy call per
matrix costs more than the arithmetic.
"""

from __future__ import annotations

import numpy as np

from avio.filter._simd import kernel_jit


@kernel_jit
def so3_exp(w0, w1, w2, out):
    """Rodrigues' formula of the rotation vector (w0, w1, w2) rad into out (3, 3); small
    angles use the Taylor series (docs/model.md, Eq. 2)."""
    th2 = w0 * w0 + w1 * w1 + w2 * w2
    if th2 < 1e-12:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    # I + a [w]x + b [w]x^2, with [w]x^2 = w w^T - |w|^2 I written out.
    out[0, 0] = 1.0 - b * (w1 * w1 + w2 * w2)
    out[1, 1] = 1.0 - b * (w0 * w0 + w2 * w2)
    out[2, 2] = 1.0 - b * (w0 * w0 + w1 * w1)
    out[0, 1] = -a * w2 + b * w0 * w1
    out[1, 0] = a * w2 + b * w0 * w1
    out[0, 2] = a * w1 + b * w0 * w2
    out[2, 0] = -a * w1 + b * w0 * w2
    out[1, 2] = -a * w0 + b * w1 * w2
    out[2, 1] = a * w0 + b * w1 * w2


@kernel_jit
def copy1(dst, src):
    """dst[:] = src for 1-D arrays of equal length (an explicit loop: numba's array-to-array
    slice assignment compiles a shape check and its error message, ~8 s of the first compile)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@kernel_jit
def copy2(dst, src):
    """dst[:, :] = src for 2-D arrays of equal shape (as :func:`copy1`)."""
    for i in range(dst.shape[0]):
        for j in range(dst.shape[1]):
            dst[i, j] = src[i, j]


@kernel_jit
def matmul(A, B, out):
    """out = A @ B for small 2-D arrays (i-k-j order: the inner loop runs over contiguous rows)."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            out[i, j] = 0.0
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[k, j]


@kernel_jit
def matmul12(A, B, out):
    """:func:`matmul` for B with 12 columns (the update's ``A Sigma``, Eq. 41): each row's 12 sums
    held in registers rather than summed in ``out`` (whose stores and reloads chained the sums), with
    the same operations in the same order, zeros of A skipped alike: the same bits, 3.2-3.6x faster
    on a 12x12 product (benchmarks/README.md, 2026-12-07)."""
    for i in range(A.shape[0]):
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = s10 = s11 = 0.0
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                s0, s1, s2, s3 = s0 + a * B[k, 0], s1 + a * B[k, 1], s2 + a * B[k, 2], s3 + a * B[k, 3]
                s4, s5, s6, s7 = s4 + a * B[k, 4], s5 + a * B[k, 5], s6 + a * B[k, 6], s7 + a * B[k, 7]
                s8, s9, s10, s11 = s8 + a * B[k, 8], s9 + a * B[k, 9], s10 + a * B[k, 10], s11 + a * B[k, 11]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = s0, s1, s2, s3, s4, s5
        out[i, 6], out[i, 7], out[i, 8], out[i, 9], out[i, 10], out[i, 11] = s6, s7, s8, s9, s10, s11


@kernel_jit
def solve(A, B):
    """Solve A X = B in place (B becomes X; A is destroyed) by Gaussian elimination with
    partial pivoting (as LAPACK's gesv; written out for the 12x12 systems of every filter
    and frame, where a LAPACK call costs more than the arithmetic)."""
    m, k = A.shape[0], B.shape[1]
    for c in range(m):
        piv, big = c, abs(A[c, c])
        for i in range(c + 1, m):
            if abs(A[i, c]) > big:
                piv, big = i, abs(A[i, c])
        if piv != c:
            for j in range(m):
                A[c, j], A[piv, j] = A[piv, j], A[c, j]
            for j in range(k):
                B[c, j], B[piv, j] = B[piv, j], B[c, j]
        inv = 1.0 / A[c, c]
        for i in range(c + 1, m):
            f = A[i, c] * inv
            if f != 0.0:
                for j in range(c + 1, m):
                    A[i, j] -= f * A[c, j]
                for j in range(k):
                    B[i, j] -= f * B[c, j]
    for c in range(m - 1, -1, -1):
        # Row operations (contiguous) rather than per-column dot products (strided).
        for i in range(c + 1, m):
            f = A[c, i]
            for j in range(k):
                B[c, j] -= f * B[i, j]
        inv = 1.0 / A[c, c]
        for j in range(k):
            B[c, j] *= inv


@kernel_jit(inline="always")
def dot6(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


@kernel_jit
def corrected_pixels(uv, r, G, cap, out):
    """A feature's pixels moved to satisfy its used residuals (0, 2, 3) to first order, the
    least-norm step ``u - G^T (G G^T)^-1 r`` (Sampson's correction, docs/model.md, Eq. 35a;
    avio.filter.measurement.measure), into out (3, 2) px.
    uv (3, 2) the measured pixels, r (4,) their innovations, G (4, 6) ``dr/d(u1, v1, .., v3)``;
    cap: the step's largest length, px (a longer one is shortened along itself, Eq. 35b: where
    ``G G^T`` is nearly singular the first-order step leaves the region where it holds).
    Returns False (out unset) where r or G is not finite or ``G G^T`` is not positive definite."""
    # Hand-written 3x3 Cholesky: np.linalg allocates, and this runs per feature in the kernel.
    g0, g1, g2 = G[0], G[2], G[3]
    a00, a01, a02 = dot6(g0, g0), dot6(g0, g1), dot6(g0, g2)
    a11, a12, a22 = dot6(g1, g1), dot6(g1, g2), dot6(g2, g2)
    y0, y1, y2 = r[0], r[2], r[3]
    if not (np.isfinite(a00 + a01 + a02 + a11 + a12 + a22) and np.isfinite(y0 + y1 + y2)) or a00 <= 0.0:
        return False
    l00 = np.sqrt(a00)
    l10, l20 = a01 / l00, a02 / l00
    d1 = a11 - l10 * l10
    if d1 <= 1e-12 * a11:
        return False
    l11 = np.sqrt(d1)
    l21 = (a12 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if d2 <= 1e-12 * a22:
        return False
    l22 = np.sqrt(d2)
    z0 = y0 / l00
    z1 = (y1 - l10 * z0) / l11
    z2 = (y2 - l20 * z0 - l21 * z1) / l22
    w2 = z2 / l22
    w1 = (z1 - l21 * w2) / l11
    w0 = (z0 - l10 * w1 - l20 * w2) / l00
    norm2 = 0.0
    for c in range(6):
        step = g0[c] * w0 + g1[c] * w1 + g2[c] * w2
        out[c // 2, c % 2] = step
        norm2 += step * step
    # Eq. (35b): continuous in the step, so the likelihood stays continuous in the calibration.
    scale = 1.0 if norm2 <= cap * cap else cap / np.sqrt(norm2)
    for c in range(6):
        out[c // 2, c % 2] = uv[c // 2, c % 2] - scale * out[c // 2, c % 2]
    return True
