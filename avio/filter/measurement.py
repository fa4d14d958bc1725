"""Trifocal measurement model of the filter: residuals and analytic Jacobians (docs/model.md,
Sections "Time offset" to "Noise model", Eqs. 19-34).

The residuals of one feature (four, pixels: two Sampson distances, the point transfer) and their
derivatives are avio/filter/trifocal.py.

Relative poses (Eq. 21; camera frames, x right, y down, z forward): ``R1j = R_world_cam1^T R_world_camj``
maps camera-j vectors into camera 1, ``t1j = R_world_cam1^T (p_world_camj - p_world_cam1)``
is camera j's origin in camera 1.

Jacobians are taken with respect to the 12 relative-pose perturbations
``[psi12, dt12, psi13, dt13]`` with ``R1j <- R1j exp(psi1j)``, ``t1j <- t1j + dt1j`` (Eqs. 30-33);
:func:`measure` chains them to the filter's 27-dim error state (Eqs. 20-24).

Compiled with numba (``cache=True``, no fastmath). Shapes: F features.
"""

from __future__ import annotations

import numpy as np

from avio.errors import AvioError
from avio.filter._linalg import corrected_pixels, matmul, so3_exp
from avio.filter._simd import kernel_jit
from avio.filter.interface import MeasureWorkspace
from avio.filter.trifocal import LANES, features_block, rot_t


class MeasurementError(AvioError):
    """Bad input to the measurement model; the message names what and where."""


@kernel_jit(inline="always")
def _copy_out(JL, GL, S, lo, n, J, Gp, f0, with_gp=True):
    # Features lo..lo+n-1 of the flat JL, GL (stride S) into features f0.. of J (4, 12, F), Gp (4, 6, F)
    # (Gp left as it is when not with_gp).
    for a in range(4):
        for b in range(12):
            for lane in range(n):
                J[a, b, f0 + lane] = JL[(12 * a + b) * S + lo + lane]
        if not with_gp:
            continue
        for b in range(6):
            for lane in range(n):
                Gp[a, b, f0 + lane] = GL[(6 * a + b) * S + lo + lane]


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



@kernel_jit(allocates=True)
def measure_workspace():
    """Scratch arrays of :func:`measure` (allocated once per batch, not per filter;
    avio.filter.interface.MeasureWorkspace)."""
    return MeasureWorkspace(R3=np.empty((3, 3)), p3=np.empty(3), Jsh=np.empty((6, 15)), Rc=np.empty((3, 3, 3)),
                            pc=np.empty((3, 3)), G=np.zeros((18, 27)), M=np.empty((6, 6)), R12=np.empty((3, 3)),
                            R13=np.empty((3, 3)), R23=np.empty((3, 3)), D=np.zeros((12, 18)), E=np.empty((3, 3)),
                            uc=np.empty((3, 2)), uL=np.empty(6 * LANES), fL=np.zeros(LANES, np.int64),
                            rL=np.empty(4 * LANES), JL=np.empty(48 * LANES), GL=np.empty(24 * LANES))



@kernel_jit
def measure(R, p, v, cp0, cR0, cp1, cR1, omega, td, fx, fy, cx, cy, Rci, pic, uv, r, J, Gp, C, t12, t13, ws, cap=0.0,
            noise_too=True):
    """Innovations r (4, F) pixels, their Jacobians J (4, 12, F) w.r.t. the relative-pose errors
    ``[psi12, dt12, psi13, dt13]``, their pixel sensitivities Gp (4, 6, F) (the measurement
    noise model, avio.filter.trifocal.feature_residuals, which writes one feature's column: features
    last, as the update uses them) and the map C (12, 27) from the error
    state to those (so ``H = J C``, ``dr = -H dx``) of one filter, written into the arrays;
    also t12, t13 (3,).

    Chain: state error -> exposure-time IMU poses of images 1, 2, 3 (clones, shifted current
    pose) -> camera pose errors ``[dp_cam, phi]`` (``phi = R_cam_imu dtheta``,
    ``dp_cam = dp - R_world_imu [p_imu_cam]x dtheta``) -> relative-pose errors
    (``psi1j = phi_j - R1j^T phi_1``, ``dt1j = [t1j]x phi_1 + R_world_cam1^T (dp_cam_j - dp_cam_1)``)
    -> residuals (avio.filter.trifocal.feature_residuals, without residual 1: the Sampson distance
    2-3, which the update does not use, is left zero, with its rows of J and Gp). With ``cap > 0``
    (px) each feature's J and (with ``noise_too``) Gp are taken again at its corrected pixels
    (:func:`corrected_pixels`, Eqs. 35a-b, the step at most ``cap`` long; r stays the measured
    pixels' innovation).
    docs/model.md: shifted pose Eq. 19, camera poses Eq. 20, relative poses Eq. 21, camera pose
    errors Eq. 22, relative-pose errors Eq. 23, C Eq. 24.
    """
    R3, p3, Jsh, Rc, pc, G, M, R12, R13 = ws.R3, ws.p3, ws.Jsh, ws.Rc, ws.pc, ws.G, ws.M, ws.R12, ws.R13
    R23, D, E, uc, uL, fL, rL, JL, GL = ws.R23, ws.D, ws.E, ws.uc, ws.uL, ws.fL, ws.rL, ws.JL, ws.GL
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
    # Eqs. (29)-(34): LANES features at a time, SIMD across them (a last, partial block repeats its
    # last feature in the spare lanes: computed, not copied out). Residual 1 is not computed
    # (trifocal.features_block); the kernel compiles no one-feature path, which saved ~9 s of its
    # first compile (benchmarks/README.md).
    F = uv.shape[0]
    for f0 in range(0, F, LANES):
        n = min(LANES, F - f0)
        for i in range(6):
            for lane in range(LANES):
                uL[i * LANES + lane] = uv[f0 + min(lane, n - 1), i // 2, i % 2]
        features_block(uL, R12, a12, R13, a13, R23, a23, fx, fy, cx, cy, rL, JL, GL)
        for a in range(4):
            for lane in range(n):
                r[a, f0 + lane] = rL[a * LANES + lane]
        _copy_out(JL, GL, LANES, 0, n, J, Gp, f0)
    # Eq. (35a): J and Gp (or J alone, Eq. 35c) again at the corrected pixels (r stays the measured
    # pixels' innovation), the corrected features LANES at a time as above (a feature's correction
    # reads its own column only, so the order of the copies does not matter).
    if cap > 0.0:
        n = 0
        for f in range(F):
            if corrected_pixels(uv[f], r[:, f], Gp[:, :, f], cap, uc):
                fL[n] = f
                for i in range(6):
                    uL[i * LANES + n] = uc[i // 2, i % 2]
                n += 1
            if n == LANES or (n > 0 and f == F - 1):
                for i in range(6):
                    for lane in range(n, LANES):
                        uL[i * LANES + lane] = uL[i * LANES + n - 1]
                features_block(uL, R12, a12, R13, a13, R23, a23, fx, fy, cx, cy, rL, JL, GL)
                for lane in range(n):
                    _copy_out(JL, GL, LANES, lane, 1, J, Gp, fL[lane], noise_too)
                n = 0
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
