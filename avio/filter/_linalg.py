"""Small dense linear algebra and rotations compiled with numba (``cache=True``, no fastmath),
for the per-filter kernels of the VIO filter (avio/filter/kernels.py, update.py, measurement.py,
outliers.py, propagation.py).

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
