"""The trifocal update of one filter at one frame (compiled): measurement chain, noise model,
outlier rejection, Kalman update in information form, and the injection of the correction.

Equations: docs/model.md, Sections "Noise model" to "Innovation statistics" (Eqs. 29, 34-46);
the measurement chain and Jacobians are avio/filter/measurement.py (Eqs. 19-33). Called by
:func:`avio.filter.kernels.run_filters`, once per filter and update frame, with workspaces
allocated once per filter range, and in stages by avio/filter/lanes/block.py; both inlined where called
(``inline="always"``: a call would store its flattened workspaces on the stack, _simd.kernel_jit)."""

from __future__ import annotations

import numpy as np

from avio.filter._linalg import copy2, matmul, matmul12, so3_exp, solve
from avio.filter._simd import kernel_jit
from avio.filter.interface import NoiseWorkspace, OutlierWorkspace, UpdateWorkspace
from avio.filter.measurement import measure
from avio.filter.outliers import (
    cholesky_lanes,
    feature_innovations_into,
    forward_lanes,
    innovations_workspace,
    log_det_lanes,
    mahalanobis_gate,
    one_point_ransac_into,
    ransac_workspace,
)


@kernel_jit
def _rotate(Rm, dtheta, E, T):
    so3_exp(dtheta[0], dtheta[1], dtheta[2], E)
    matmul(Rm, E, T)
    copy2(Rm, T)


@kernel_jit
def inject(R, p, v, ba, bg, cp0, cR0, cp1, cR1, dx, E, T):
    """Add the error-state correction dx (27,) to one filter's nominal state (local rotation
    errors, ``R <- R exp(dtheta)``), in place (E, T (3, 3): scratch); docs/model.md, Eq. 8."""
    for i in range(3):
        p[i] += dx[i]
        v[i] += dx[6 + i]
        ba[i] += dx[9 + i]
        bg[i] += dx[12 + i]
        cp0[i] += dx[15 + i]
        cp1[i] += dx[21 + i]
    _rotate(R, dx[3:6], E, T)
    _rotate(cR0, dx[18:21], E, T)
    _rotate(cR1, dx[24:27], E, T)


@kernel_jit(allocates=True)
def update_workspace(F):
    """Scratch arrays of :func:`update` for F features (allocated once per run;
    avio.filter.interface.UpdateWorkspace)."""
    d = 12
    return UpdateWorkspace(
        r4=np.empty((4, F)), J4=np.empty((4, d, F)), C=np.empty((d, 27)), PCt=np.empty((27, d)), Sig=np.empty((d, d)),
        t12=np.empty(3), t13=np.empty(3), HP=np.empty((M, d, F)), z=np.empty((M, F)), ok=np.empty(F, np.bool_),
        inl=np.empty(F, np.bool_), gate=np.empty(F, np.bool_), A=np.empty((d, d)), Mx=np.empty((d, d)),
        X=np.empty((d, d + 1)), K=np.empty((27, d)), dx=np.empty(27), CP=np.empty((d, 27)), E3=np.empty((3, 3)),
        T3=np.empty((3, 3)))


@kernel_jit(allocates=True)
def noise_workspace(F):
    """Scratch arrays of the measurement-noise model of :func:`update` for F features: the
    pixel sensitivities of the 4 residuals (4, 6, F); then, features last as well
    (avio/filter/outliers.py), the M used residuals, their Jacobians and pixel
    sensitivities (M, F), (M, 12, F), (M, 6, F); covariances R_f and their Cholesky factors
    (M, M, F), standard deviations (M, F), log det R_f and log det S_f (F,), the whitened
    residuals and Jacobians (M, F), (M, 12, F), one feature's whitened Jacobian (M, 12) and a
    (12,) vector."""
    return NoiseWorkspace(G4=np.empty((4, 6, F)), r=np.empty((M, F)), J=np.empty((M, 12, F)), Gp=np.empty((M, 6, F)),
                          Rm=np.empty((M, M, F)), sd=np.empty((M, F)), Lm=np.zeros((M, M, F)), ldR=np.empty(F),
                          ldS=np.empty(F), rw=np.empty((M, F)), Jw=np.empty((M, 12, F)), jw_f=np.empty((M, 12)),
                          beta=np.empty(12))


@kernel_jit(allocates=True)
def outlier_workspace(F):
    """Scratch arrays of the outlier tests of :func:`update` for F features
    (avio.filter.outliers.innovations_workspace, then avio.filter.outliers.ransac_workspace)."""
    Lp, S, L, y = innovations_workspace(M, 12, F)
    Y, moved, inlier, count = ransac_workspace(F, M, 12)
    return OutlierWorkspace(Lp=Lp, S=S, L=L, y=y, Y=Y, moved=moved, inlier=inlier, count=count)


MODE_NONE, MODE_RANSAC, MODE_GATE, MODE_BOTH = 0, 1, 2, 3  # outlier rejection of update()
LOG_2PI = np.log(2.0 * np.pi)
#: The residuals the update uses, of the 4 of avio.filter.measurement (docs/model.md, Eq. 29):
#: the 1-2 Sampson distance and the two transfer coordinates. A point seen in three images gives
#: 3 independent constraints (6 measured coordinates minus its 3 coordinates): to first order
#: the 2-3 Sampson distance is a combination of the other three, so the 4x4 covariance from the
#: pixel noise is singular (smallest eigenvalue ~1e-4 sigma^2 against ~0.6 sigma^2 for these
#: three on the default drive) and whitening all four would turn linearisation error into
#: near-certain information.
USED_RESIDUALS = (0, 2, 3)
M = 3  # residuals used per feature


#: R_f gets (NOISE_FLOOR * sigma)^2 on its diagonal (docs/model.md, Eq. 35): keeps it positive
#: definite when a geometry makes two residuals react to the pixels in the same way (it changes
#: no decision).
NOISE_FLOOR = 0.01


@kernel_jit
def _noise_model(Gp, sigma_px, Rm, sd, Lm, ldR):
    """R_f = sigma^2 G G^T + (NOISE_FLOOR sigma)^2 I of every feature (G (M, 6, F) the used
    residuals' pixel sensitivities), its Cholesky factor, the standard deviations and
    log det R_f, into the workspace arrays (features last: (M, M, F), (M, F), (F,)).
    docs/model.md, Eq. 35 (G: Eq. 34)."""
    s2 = sigma_px * sigma_px
    F = Gp.shape[2]
    # Eq. (35): R_f = sigma^2 G G^T + (NOISE_FLOOR sigma)^2 I.
    for a in range(M):
        for b in range(a + 1):
            for f in range(F):
                acc = 0.0
                for c in range(6):
                    acc += Gp[a, c, f] * Gp[b, c, f]
                Rm[a, b, f] = s2 * acc
                Rm[b, a, f] = s2 * acc
        for f in range(F):
            Rm[a, a, f] += s2 * NOISE_FLOOR * NOISE_FLOOR
            sd[a, f] = np.sqrt(Rm[a, a, f])
    cholesky_lanes(Rm, Lm)
    log_det_lanes(Lm, ldR)


@kernel_jit(inline="always")
def update(x, omega, cal, i, uv, valid, cfg, ws, record, decided):
    """One trifocal update of filter ``i``: its predicted state x (avio.filter.interface.FilterState,
    covariance included) in place, its calibration row i of ``cal`` (interface.Calibrations), the
    settings ``cfg`` (interface.Settings), the features uv (F, 3, 2) px and valid (F,) of the
    frame's triplet, omega (3,) rad/s the gyro minus the bias at the frame time.

    Residuals and Jacobians of the features (invalid, non-finite, without baseline or with a transfer
    that amplifies the pixel noise more than ``max_transfer_gain`` times: not used), each one's
    ``R_f = sigma_px^2 G G^T`` (avio.filter.trifocal.feature_residuals), outlier rejection (``mode``:
    MODE_*), then the Kalman update in information form over the 12 relative-pose errors ``C dx``:
    ``P+ = P - P C^T (I + A Sigma)^-1 A C P``, ``dx = P C^T (I + A Sigma)^-1 beta``, ``Sigma = C P C^T``,
    ``A = J^T R^-1 J``, ``beta = J^T R^-1 r``; its likelihood (avio/objectives.py) from the same
    factors: ``NIS = r^T R^-1 r - beta^T Sigma (I + A Sigma)^-1 beta`` (Woodbury), ``log det S = log
    det R + log det(I + A Sigma)``. Returns (used, rejected, nis, log_det_S, dof, nll, slots,
    pose_trace): features used and rejected, NIS, log det S, residual count, the NLL contribution
    (with the capped terms of the valid features not used), the residual slots (M per valid
    feature), the pose's share of S ``tr(J^T S^-1 J Sigma)`` (Eq. 55b). With ``record`` the
    decisions go to ``decided`` (F,) (1: used). ws: interface.UpdateWorkspaces (nothing is
    allocated here); the per-feature steps run features last, every feature at once in SIMD
    (avio/filter/outliers.py). Eqs. 19-33 (measurement), 34-36 (noise), 37-39 (outliers), 40-43
    (update), 44-46 (statistics). In stages, which avio/filter/lanes/block.py runs for a block of
    filters in lock-step, the dense ones (:func:`project`, the solve, :func:`downdate`) for the whole
    block at once: :func:`update_measure`, :func:`project`, :func:`update_information`, ``solve``,
    :func:`update_statistics`, :func:`downdate`, :func:`inject`.
    """
    u_ = ws.update
    n_ok, n_valid = update_measure(x, omega, cal, i, uv, valid, cfg, ws)
    project(u_.C, x.P, u_.CP, u_.PCt, u_.Sig)
    used, rr, log_det_R, nll = update_information(valid, cfg, ws, record, decided)
    solve(u_.Mx, u_.X)  # X = (I + A Sigma)^-1 [A | beta] (Eqs. 41-42)
    nis, log_det_S, pose_trace = update_statistics(ws, rr, log_det_R)
    downdate(x.P, u_.PCt, u_.X, u_.CP, u_.K)
    # Eq. (8): the injection.
    inject(x.R, x.p, x.v, x.ba, x.bg, x.cp0, x.cR0, x.cp1, x.cR1, u_.dx, u_.E3, u_.T3)
    return used, n_ok - used, nis, log_det_S, M * used, nll, M * n_valid, pose_trace


@kernel_jit(inline="always")
def update_measure(x, omega, cal, i, uv, valid, cfg, ws):
    """Stage 1 of :func:`update`: the measurement of the F features (residuals, Jacobians, the chain C
    into ``ws.update.C``), the usable features ``ws.update.ok`` and their noise model (ws.noise).
    Returns (n_ok, n_valid): the usable and the valid features."""
    F, d = uv.shape[0], 12
    u_, n_ = ws.update, ws.noise
    r4, J4, C, t12, t13, ok = u_.r4, u_.J4, u_.C, u_.t12, u_.t13, u_.ok
    G4, r, J, Gp, Rm, sd, Lm, ldR = n_.G4, n_.r, n_.J, n_.Gp, n_.Rm, n_.sd, n_.Lm, n_.ldR
    sigma_px, max_transfer_gain, min_parallax_m = cfg.sigma_px, cfg.max_transfer_gain, cfg.min_parallax_m
    # Eqs. (19)-(34): residuals r4, Jacobians J4 w.r.t. the relative-pose errors, pixel sensitivities
    # G4 and the chain C (H = J C).
    measure(x.R, x.p, x.v, x.cp0, x.cR0, x.cp1, x.cR1, omega, cal.td_s[i], cal.fx[i], cal.fy[i], cal.cx[i],
            cal.cy[i], cal.R_cam_imu[i], cal.p_imu_cam_m[i], uv, r4, J4, G4, C, t12, t13, ws.measure,
            cfg.correction_cap_px, cfg.correct_noise_model)
    # Eq. (36): without baseline the epipolar geometry and the transfer are undefined (standing still).
    b12 = np.sqrt(t12[0] ** 2 + t12[1] ** 2 + t12[2] ** 2)
    b23 = np.sqrt((t13[0] - t12[0]) ** 2 + (t13[1] - t12[1]) ** 2 + (t13[2] - t12[2]) ** 2)
    moving = b12 > min_parallax_m and b23 > min_parallax_m
    n_valid = 0
    gain_limit2 = (max_transfer_gain * sigma_px) ** 2
    log_s2 = np.log(sigma_px * sigma_px)
    # The used rows (Eq. 29), features last (avio/filter/outliers.py): every step below runs over all F
    # features at once (SIMD); a feature's own operations are those of one feature alone.
    for a in range(M):
        u = USED_RESIDUALS[a]
        for f in range(F):
            r[a, f] = r4[u, f]
        for b in range(d):
            for f in range(F):
                J[a, b, f] = J4[u, b, f]
        for b in range(6):
            for f in range(F):
                Gp[a, b, f] = G4[u, b, f]
    # Degenerate geometry (a point at the epipole, a wild candidate) is non-finite.
    for f in range(F):
        n_valid += valid[f]
        ok[f] = valid[f] and moving
    for a in range(M):
        for f in range(F):
            ok[f] &= np.isfinite(r[a, f])
        for b in range(d):
            for f in range(F):
                ok[f] &= np.isfinite(J[a, b, f])
        for b in range(6):
            for f in range(F):
                ok[f] &= np.isfinite(Gp[a, b, f])
    _noise_model(Gp, sigma_px, Rm, sd, Lm, ldR)  # all features; only those still ok keep it
    n_ok = 0
    # Eq. (36): the transfer gain, sqrt(R_f[i, i]) <= max_transfer_gain sigma on the transfer's rows.
    for f in range(F):
        ok[f] &= Rm[1, 1, f] <= gain_limit2 and Rm[2, 2, f] <= gain_limit2  # the transfer's rows
        n_ok += ok[f]
    for f in range(F):
        if not ok[f]:
            ldR[f] = M * log_s2
            for a in range(M):
                r[a, f] = 0.0
                sd[a, f] = sigma_px
                for b in range(d):
                    J[a, b, f] = 0.0
                for b in range(M):
                    Rm[a, b, f] = sigma_px * sigma_px if a == b else 0.0
    return n_ok, n_valid


@kernel_jit
def project(C, P, CP, PCt, Sig):
    """Stage 2 of :func:`update`, one filter: CP = C P (12, 27), PCt (27, 12) its transpose, Sigma
    = C P C^T (12, 12), from C (12, 27) and P (27, 27) (Eq. 37; lock-step: avio/filter/lanes/update.c)."""
    # CP = C P (C is ~60 % zeros, which matmul skips), PCt = its transpose (P is
    # symmetric), Sigma = C P C^T (symmetrised; Eq. 37).
    matmul(C, P, CP)
    for a in range(27):
        for b in range(12):
            PCt[a, b] = CP[b, a]
    matmul12(C, PCt, Sig)
    for a in range(12):
        for b in range(a):
            s = 0.5 * (Sig[a, b] + Sig[b, a])
            Sig[a, b], Sig[b, a] = s, s


@kernel_jit(inline="always")
def update_information(valid, cfg, ws, record, decided):
    """Stage 3 of :func:`update` (Sigma in ``ws.update.Sig``): the features' innovations, the NLL
    score, the outlier rejection and the information sum over the inliers, which leaves
    ``Mx = I + A Sigma`` and ``X = [A | beta]`` for the solve (Eqs. 37-42). Returns (used, rr,
    log_det_R, nll): the inliers, r^T R^-1 r and sum log det R_f over them, the frame's NLL."""
    F, d = valid.shape[0], 12
    u_, n_, o_ = ws.update, ws.noise, ws.outliers
    Sig, HP, z, ok, inl, gate, A, Mx, X = u_.Sig, u_.HP, u_.z, u_.ok, u_.inl, u_.gate, u_.A, u_.Mx, u_.X
    r, J, Rm, sd, Lm, ldR, ldS = n_.r, n_.J, n_.Rm, n_.sd, n_.Lm, n_.ldR, n_.ldS
    rw, Jw, jw_f, beta = n_.rw, n_.Jw, n_.jw_f, n_.beta
    sigma_px, mode, chi2_threshold = cfg.sigma_px, cfg.mode, cfg.chi2_threshold
    log_s2 = np.log(sigma_px * sigma_px)
    for f in range(F):
        inl[f] = ok[f]
    # Eq. (37): per feature S_f = J_f Sigma J_f^T + R_f, z_f = S_f^-1 r_f, log det S_f.
    feature_innovations_into(r, J, Sig, Rm, HP, z, ldS, o_.Lp, o_.S, o_.L, o_.y)
    # The score (avio/objectives.py; Eq. 46): every valid feature's own innovation likelihood, its
    # squared Mahalanobis distance capped at the gate, whatever the update does with it.
    nll = 0.0
    for f in range(F):
        if valid[f]:
            if ok[f]:
                d2 = 0.0
                for a in range(M):
                    d2 += r[a, f] * z[a, f]
                nll += 0.5 * (min(d2, chi2_threshold) + ldS[f] + M * LOG_2PI)
            else:
                nll += 0.5 * (chi2_threshold + M * log_s2 + M * LOG_2PI)
    # Outlier rejection: 1-point RANSAC (Eq. 38), then the chi-square gate (Eq. 39).
    if mode == MODE_RANSAC or mode == MODE_BOTH:
        one_point_ransac_into(r, HP, z, sd, ok, cfg.ransac_threshold_sigma, inl, o_.Y, o_.moved, o_.inlier, o_.count)
    if mode == MODE_GATE or mode == MODE_BOTH:
        mahalanobis_gate(r, z, inl, chi2_threshold, gate)
        for f in range(F):
            inl[f] = gate[f]
    # Information form over the inliers (Eq. 40): A = Jw^T Jw, beta = Jw^T rw with the whitened
    # Jw = L_f^-1 J_f, rw = L_f^-1 r_f (R_f = L_f L_f^T): the whitening of all features at
    # once (forward substitution, one residual row at a time), then the sums over the inliers
    # in feature order.
    forward_lanes(Lm, r, rw)
    for a in range(M):
        for b in range(d):
            for f in range(F):
                acc = J[a, b, f]
                for k in range(a):
                    acc -= Lm[a, k, f] * Jw[k, b, f]
                Jw[a, b, f] = acc / Lm[a, a, f]
    A[:] = 0.0
    beta[:] = 0.0
    used = 0
    rr = 0.0
    log_det_R = 0.0
    if record:
        for f in range(F):
            decided[f] = inl[f]
    for f in range(F):
        if not inl[f]:
            continue
        used += 1
        log_det_R += ldR[f]
        for a in range(M):
            rr += rw[a, f] * rw[a, f]
            for b in range(d):
                jw_f[a, b] = Jw[a, b, f]
        # Whole rows of A (12, the lanes of one SIMD operation and a half) and no test for zeros:
        # adding jb * x = +-0 leaves a sum that started at +0 unchanged (in round-to-nearest it is
        # never -0), so the upper triangle has the bits of the triangular, zero-skipping sum this
        # replaced (issue 30); the lower triangle is overwritten by the mirror below.
        for a in range(M):
            rwa = rw[a, f]
            for b in range(d):
                beta[b] += jw_f[a, b] * rwa
            for b in range(d):
                jb = jw_f[a, b]
                for c in range(d):
                    A[b, c] += jb * jw_f[a, c]
    for b in range(d):
        X[b, d] = beta[b]
        for c in range(b):
            A[b, c] = A[c, b]
    # X = (I + A Sigma)^-1 [A | beta] (Eqs. 41-42)
    matmul12(A, Sig, Mx)
    for a in range(d):
        Mx[a, a] += 1.0
        for b in range(d):
            X[a, b] = A[a, b]
    return used, rr, log_det_R, nll


@kernel_jit
def update_statistics(ws, rr, log_det_R):
    """Stage 4 of :func:`update`, after the solve (X = (I + A Sigma)^-1 [A | beta], Mx its
    elimination): log det S, NIS and the pose trace (Eqs. 44, 45, 55b), and the correction
    ``ws.update.dx`` (Eq. 41). Returns (nis, log_det_S, pose_trace)."""
    u_, d = ws.update, 12
    Mx, X, Sig, PCt, dx, beta = u_.Mx, u_.X, u_.Sig, u_.PCt, u_.dx, ws.noise.beta
    # Eq. (45): log det S = sum_f log det R_f + log det(I + A Sigma).
    log_det_S = log_det_R
    for a in range(d):
        log_det_S += np.log(abs(Mx[a, a]))  # the pivots of the elimination: det(I + A Sigma) > 0
    # Eq. (44): NIS = r^T R^-1 r - beta^T Sigma (I + A Sigma)^-1 beta.
    nis = rr
    for a in range(d):
        acc = 0.0
        for b in range(d):
            acc += Sig[a, b] * X[b, d]
        nis -= beta[a] * acc
    # Eq. (55b): the pose's share of S, tr(J^T S^-1 J Sigma) = tr((I + A Sigma)^-1 A Sigma).
    pose_trace = 0.0
    for a in range(d):
        for b in range(d):
            pose_trace += X[a, b] * Sig[b, a]
    # Eq. (41): dx = P C^T (I + A Sigma)^-1 beta.
    for a in range(27):
        acc = 0.0
        for b in range(d):
            acc += PCt[a, b] * X[b, d]
        dx[a] = acc
    return nis, log_det_S, pose_trace


@kernel_jit
def downdate(P, PCt, X, CP, K):
    """Stage 5 of :func:`update`, one filter: P (27, 27) -= (PCt X[:, :12]) CP, K (27, 12) scratch
    (Eq. 42; lock-step: avio/filter/lanes/lanes.c)."""
    # Eq. (42): P -= (PCt X[:, :12]) CP: the lower triangle, mirrored (P stays exactly symmetric).
    for a in range(27):
        for b in range(12):
            K[a, b] = 0.0
        for c in range(12):
            f = PCt[a, c]
            for b in range(12):
                K[a, b] += f * X[c, b]
    # Each entry's 12 terms are summed in a register (the loop over b, of fixed length, unrolls: the
    # loop over c vectorises), in the order of the row updates this replaced (issue 30); row a runs
    # over its lower triangle rounded up to whole SIMD lanes (8): the extra entries are in the upper
    # triangle, which no later row reads and the mirror of row c > a overwrites.
    for a in range(27):
        n = min(27, (a // 8 + 1) * 8)
        for c in range(n):
            acc = P[a, c]
            for b in range(12):
                acc -= K[a, b] * CP[b, c]
            P[a, c] = acc
        for c in range(a):
            P[c, a] = P[a, c]
