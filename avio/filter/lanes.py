"""Filters in lock-step (issue 30): :func:`run_block` advances a block of :data:`LANES` filters
frame by frame, the dense covariance phases of all of them at once, the lane axis innermost, so
that LLVM packs each multiply-add of the block into one SIMD instruction (avio/filter/_simd.py:
non-aliasing arguments and SLP, with the lane count a compile-time constant).

In lock-step (``*_lanes``, arrays ``(..., LANES)``): the covariance prediction (Eq. 18), C P,
P C^T and Sigma = C P C^T (Eq. 37), the correction dx, the gain rows K and the downdate (Eqs.
41-42). Per lane inside the block (the per-filter functions of avio/filter/update.py and
kernels.py, unchanged): the state prediction, the measurement and noise model, the outlier tests,
the information sum and the 12x12 solve (each lane its own pivots, RANSAC winner and decisions),
the injection, the zero-velocity update, the slide and the divergence test (each lane its own
mask: a diverged or frozen lane is left alone by the per-lane steps; the lock-step phases keep
computing it, on numbers nobody reads).

Same bits as one filter alone: every lane sees the operations of avio.filter.kernels.run_filters
in the same order. Where the per-filter code skips a multiplication by an exact zero (C and Phi
are sparse), a lane keeps its value through a select, and a column is skipped only when it is zero
in every lane (adding ``0 * x`` is not a no-op when x is inf or NaN, or for the sign of a zero).
"""

from __future__ import annotations

import numpy as np

from avio.filter._linalg import copy1, copy2
from avio.filter._simd import kernel_jit
from avio.filter.interface import FilterState, NoiseWorkspace, UpdateWorkspace, UpdateWorkspaces
from avio.filter.kernels import (
    _bad,
    _clear_update,
    _clear_updates,
    _write_frame,
    slide,
    zero_velocity_update_into,
    zero_velocity_workspace,
)
from avio.filter.measurement import measure_workspace
from avio.filter.propagation import propagate_one, propagate_workspace
from avio.filter.update import (
    M,
    inject,
    noise_workspace,
    outlier_workspace,
    update_measure,
    update_solve,
    update_workspace,
)

#: Filters per block; a compile-time constant (LLVM packs only constant lane loops). Chosen by
#: measurement among 4 and 8 (benchmarks/README.md, issue 30).
LANES = 8


@kernel_jit(inline="always")
def _axpy_rows(dst, a, W, src, nk, ncols):
    """dst[a, :ncols, l] += W[a, k, l] src[k, :ncols, l] for k < nk in every lane l, in k order,
    a lane's term skipped where its W[a, k, l] is zero (as the per-filter code), a k skipped when
    W[a, k] is zero in every lane."""
    for k in range(nk):
        nz = False
        for lane in range(LANES):
            nz |= W[a, k, lane] != 0.0
        if nz:
            for b in range(ncols):
                for lane in range(LANES):
                    # every load first, then a select: LLVM packs selects, not branches around loads
                    w, old, x = W[a, k, lane], dst[a, b, lane], src[k, b, lane]
                    new = old + w * x
                    dst[a, b, lane] = new if w != 0.0 else old


@kernel_jit
def propagate_covariance_lanes(P, Phi, Qd, T, U):
    """avio.filter.kernels.propagate_covariance of the block: P (27, 27, L), Phi (15, 15, L),
    Qd (15, 15) shared, T (15, 27, L), U (15, 15, L) scratch (docs/model.md, Eq. 18)."""
    for a in range(15):
        for b in range(27):
            for lane in range(LANES):
                T[a, b, lane] = 0.0
        _axpy_rows(T, a, Phi, P, 15, 27)
    for a in range(15):
        for b in range(15):
            for lane in range(LANES):
                U[a, b, lane] = T[b, a, lane]
    for a in range(15):
        for b in range(15):
            for lane in range(LANES):
                P[a, b, lane] = Qd[a, b]
        _axpy_rows(P, a, Phi, U, 15, 15)
        for b in range(15, 27):
            for lane in range(LANES):
                P[a, b, lane] = T[a, b, lane]
                P[b, a, lane] = T[a, b, lane]


@kernel_jit
def project_lanes(C, P, CP, PCt, Sig):
    """avio.filter.update.project of the block: CP = C P (12, 27, L), PCt (27, 12, L) its
    transpose, Sig = C P C^T (12, 12, L) symmetrised; C (12, 27, L), P (27, 27, L) (Eq. 37)."""
    for i in range(12):
        for j in range(27):
            for lane in range(LANES):
                CP[i, j, lane] = 0.0
        _axpy_rows(CP, i, C, P, 27, 27)
    for a in range(27):
        for b in range(12):
            for lane in range(LANES):
                PCt[a, b, lane] = CP[b, a, lane]
    for i in range(12):
        for j in range(12):
            for lane in range(LANES):
                Sig[i, j, lane] = 0.0
        _axpy_rows(Sig, i, C, PCt, 27, 12)
    for a in range(12):
        for b in range(a):
            for lane in range(LANES):
                s = 0.5 * (Sig[a, b, lane] + Sig[b, a, lane])
                Sig[a, b, lane] = s
                Sig[b, a, lane] = s


@kernel_jit
def gain_downdate_lanes(PCt, X, CP, P, dx, K):
    """avio.filter.update.gain_downdate of the block: dx (27, L) = PCt X[:, 12], K (27, 12, L) =
    PCt X[:, :12], P -= K CP on the lower triangle, mirrored; X (12, 13, L) (Eqs. 41-42)."""
    for a in range(27):
        for lane in range(LANES):
            dx[a, lane] = 0.0
        for b in range(12):
            for lane in range(LANES):
                dx[a, lane] += PCt[a, b, lane] * X[b, 12, lane]
    for a in range(27):
        for b in range(12):
            for lane in range(LANES):
                K[a, b, lane] = 0.0
        for c in range(12):
            for b in range(12):
                for lane in range(LANES):
                    K[a, b, lane] += PCt[a, c, lane] * X[c, b, lane]
    for a in range(27):
        for b in range(12):
            for c in range(a + 1):
                for lane in range(LANES):
                    P[a, c, lane] -= K[a, b, lane] * CP[b, c, lane]
        for c in range(a):
            for lane in range(LANES):
                P[c, a, lane] = P[a, c, lane]


@kernel_jit
def _lane_arrays(F):
    """What a lane's update keeps between its measurement and its solve (the other lanes' stages
    run in between): usable features ok (L, F) and, features last, the used residuals r (L, M, F),
    Jacobians J (L, M, 12, F), covariances Rm (L, M, M, F), standard deviations sd (L, M, F), Cholesky
    factors Lm (L, M, M, F) and log det ldR (L, F). Everything else of the update is scratch, one
    set for the block."""
    L = LANES
    return (np.zeros((L, F), np.bool_), np.zeros((L, M, F)), np.zeros((L, M, 12, F)), np.zeros((L, M, M, F)),
            np.zeros((L, M, F)), np.zeros((L, M, M, F)), np.zeros((L, F)))


@kernel_jit
def _lane_workspaces(ws, kept, lane):
    """The block's scratch ws (interface.UpdateWorkspaces) with lane ``lane``'s kept arrays."""
    ok, r, J, Rm, sd, Lm, ldR = kept
    u, n = ws.update, ws.noise
    upd = UpdateWorkspace(r4=u.r4, J4=u.J4, C=u.C, PCt=u.PCt, Sig=u.Sig, t12=u.t12, t13=u.t13, HP=u.HP, z=u.z,
                          ok=ok[lane], inl=u.inl, gate=u.gate, A=u.A, Mx=u.Mx, X=u.X, K=u.K, dx=u.dx, CP=u.CP,
                          E3=u.E3, T3=u.T3)
    noise = NoiseWorkspace(G4=n.G4, r=r[lane], J=J[lane], Gp=n.Gp, Rm=Rm[lane], sd=sd[lane], Lm=Lm[lane],
                           ldR=ldR[lane], ldS=n.ldS, rw=n.rw, Jw=n.Jw, jw_f=n.jw_f, beta=n.beta)
    return UpdateWorkspaces(update=upd, measure=ws.measure, noise=noise, outliers=ws.outliers)


@kernel_jit
def _trifocal_lanes(k, j, lo, active, seq, cal, cfg, out, st, lw, ws, kept, record, no_record):
    """The trifocal update of frame k (triplet j) of every active lane: per lane the measurement,
    in lock-step C P and Sigma, per lane the outlier tests and the solve, in lock-step the
    correction and the downdate, per lane the injection (avio.filter.update.update, split)."""
    R_new, p_new, v_new, ba, bg, cp, cR, Pl, omega = st
    P, C, CP, PCt, Sig, X, K, dx, counts = lw
    for lane in range(LANES):
        if not active[lane]:
            continue
        x = FilterState(R=R_new[lane], p=p_new[lane], v=v_new[lane], ba=ba[lane], bg=bg[lane], cp0=cp[lane, 0],
                        cR0=cR[lane, 0], cp1=cp[lane, 1], cR1=cR[lane, 1], P=Pl[lane])
        i = lo + lane
        n_valid, n_ok = update_measure(x, omega[lane], cal, i, seq.uv[j], seq.valid[j], cfg,
                                       _lane_workspaces(ws, kept, lane))
        counts[0, lane], counts[1, lane] = n_valid, n_ok
        Cl = ws.update.C
        for a in range(12):
            for b in range(27):
                C[a, b, lane] = Cl[a, b]
    project_lanes(C, P, CP, PCt, Sig)
    for lane in range(LANES):
        if not active[lane]:
            continue
        i, u_ = lo + lane, ws.update
        for a in range(12):
            for b in range(12):
                u_.Sig[a, b] = Sig[a, b, lane]
        decided = out.used[i, j] if record else no_record
        used, nis, ldS, dof, nll = update_solve(seq.valid[j], cfg, _lane_workspaces(ws, kept, lane), record, decided)
        out.n_updates[i, k], out.n_outliers[i, k] = used, counts[1, lane] - used
        out.nis[i, k], out.log_det_S[i, k], out.dof[i, k] = nis, ldS, dof
        out.nll[i, k], out.nll_slots[i, k] = nll, M * counts[0, lane]
        for a in range(12):
            for b in range(13):
                X[a, b, lane] = u_.X[a, b]
    gain_downdate_lanes(PCt, X, CP, P, dx, K)
    for lane in range(LANES):
        if active[lane]:
            u_ = ws.update
            for a in range(27):
                u_.dx[a] = dx[a, lane]
            inject(R_new[lane], p_new[lane], v_new[lane], ba[lane], bg[lane], cp[lane, 0], cR[lane, 0], cp[lane, 1],
                   cR[lane, 1], u_.dx, u_.E3, u_.T3)


@kernel_jit(nogil=True)
def run_block(lo, hi, seq, cal, cfg, out):
    """avio.filter.kernels.run_filters of filters lo..hi-1 (at most LANES) in lock-step: lane l is
    filter lo + l, its outputs the bits of that filter run alone (same arguments as run_filters:
    avio.filter.interface.SequenceInputs, Calibrations, Settings, Outputs). A block of fewer
    filters leaves its last lanes idle. The state of lane l: R, p, v, ba, bg, clones (L, ...);
    its covariance in lock-step P (27, 27, L) and, for the per-lane steps, Pl[l] (27, 27)."""
    L = LANES
    N, F = seq.T_s.shape[0], seq.uv.shape[1]
    ws = UpdateWorkspaces(update=update_workspace(F), measure=measure_workspace(), noise=noise_workspace(F),
                          outliers=outlier_workspace(F))
    kept = _lane_arrays(F)
    pws, zws = propagate_workspace(), zero_velocity_workspace()
    R, p, v, ba, bg = np.empty((L, 3, 3)), np.empty((L, 3)), np.empty((L, 3)), np.empty((L, 3)), np.empty((L, 3))
    R_new, p_new, v_new = np.empty((L, 3, 3)), np.empty((L, 3)), np.empty((L, 3))
    ba_s, bg_s, omega = np.empty((L, 3)), np.empty((L, 3)), np.empty((L, 3))
    cp, cR = np.zeros((L, 2, 3)), np.zeros((L, 2, 3, 3))
    P, Pl, Phi, Phil = np.zeros((27, 27, L)), np.empty((L, 27, 27)), np.zeros((15, 15, L)), np.empty((15, 15))
    Tq, U = np.empty((15, 27, L)), np.empty((15, 15, L))
    E, T3, R3, p3, Jsh, NR = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((6, 15)), \
        np.empty((6, 27))
    lw = (P, np.zeros((12, 27, L)), np.zeros((12, 27, L)), np.zeros((27, 12, L)), np.zeros((12, 12, L)),
          np.zeros((12, 13, L)), np.zeros((27, 12, L)), np.zeros((27, L)), np.zeros((2, L), np.int64))
    st = (R_new, p_new, v_new, ba, bg, cp, cR, Pl, omega)
    sig0 = np.sqrt(np.abs(np.diag(seq.P0)[:15]))
    record = out.used.shape[0] > 0
    no_record = np.zeros(F, np.uint8)
    zv_sigma = cfg.zero_velocity_sigma_mps
    active, k_stop = np.zeros(L, np.bool_), np.zeros(L, np.int64)
    for lane in range(hi - lo):
        i = lo + lane
        copy2(R[lane], seq.R0)
        copy1(p[lane], seq.p0)
        copy1(v[lane], seq.v0)
        copy1(ba[lane], seq.ba0)
        copy1(bg[lane], seq.bg0)
        for a in range(27):
            for b in range(27):
                P[a, b, lane] = seq.P0[a, b]
        for a in range(3):
            cR[lane, 0, a, a] = 1.0
            cR[lane, 1, a, a] = 1.0
        _clear_updates(out, i, record)
        out.diverged_at[i] = 0 if cal.frozen[i] else -1
        active[lane] = not cal.frozen[i]
        k_stop[lane] = 0 if cal.frozen[i] else N
    for k in range(N):
        if not active.any():
            break
        for lane in range(L):
            if active[lane]:
                copy1(ba_s[lane], ba[lane])
                copy1(bg_s[lane], bg[lane])
                # Prediction: nominal state (Eqs. 14-16); the covariance (Eq. 18) in lock-step below.
                if k > 0:
                    propagate_one(R[lane], v[lane], p[lane], ba[lane], bg[lane], seq.g, seq.dR[k], seq.dv[k],
                                  seq.dp[k], seq.S[k], seq.SS[k], seq.Vbg[k], seq.Pbg[k], seq.T_s[k], R_new[lane],
                                  v_new[lane], p_new[lane], Phil, pws)
                    for a in range(15):
                        for b in range(15):
                            Phi[a, b, lane] = Phil[a, b]
                else:
                    copy2(R_new[lane], R[lane])
                    copy1(v_new[lane], v[lane])
                    copy1(p_new[lane], p[lane])
                # omega of the time shift, Eq. (19): the gyro at the frame time minus the bias.
                for a in range(3):
                    omega[lane, a] = seq.gyro_frame[k, a] - bg[lane, a]
        if k > 0:
            propagate_covariance_lanes(P, Phi, seq.Qd[k], Tq, U)
        j = seq.triplet_of_frame[k]
        standstill = k >= 2 and seq.stationary[k] and zv_sigma > 0
        if not standstill and k >= 2 and j >= 0:
            _trifocal_lanes(k, j, lo, active, seq, cal, cfg, out, st, lw, ws, kept, record, no_record)
        for lane in range(L):
            if active[lane]:
                _finish_frame(k, j, lo + lane, lane, standstill, seq, cal, cfg, out, st, P, R, p, v, ba_s, bg_s,
                              active, k_stop, zws, E, T3, R3, p3, Jsh, NR, record)
    # From the divergence on: the last good state (biases included), the initial sigmas.
    for lane in range(hi - lo):
        i = lo + lane
        for k in range(k_stop[lane], N):
            _write_frame(out, i, k, R[lane], p[lane], v[lane], ba[lane], bg[lane])
            copy1(out.sigma[i, k], sig0)


@kernel_jit
def _finish_frame(k, j, i, lane, standstill, seq, cal, cfg, out, st, P, R, p, v, ba_s, bg_s, active, k_stop, zws,
                  E, T3, R3, p3, Jsh, NR, record):
    """Frame k of one lane after the lock-step phases: its covariance out of the block (Pl[lane]),
    the zero-velocity update when standing still (Eq. 49), the slide (Eq. 50), the divergence test
    (Eq. 51: the lane stops, its outputs those of the last good frame) or the frame's outputs; the
    covariance back into the block."""
    R_new, p_new, v_new, ba, bg, cp, cR, Pl, omega = st
    Pi = Pl[lane]
    for a in range(27):
        for b in range(27):
            Pi[a, b] = P[a, b, lane]
    if standstill:
        zero_velocity_update_into(R_new[lane], p_new[lane], v_new[lane], ba[lane], bg[lane], cp[lane, 0], cR[lane, 0],
                                  cp[lane, 1], cR[lane, 1], Pi, cfg.zero_velocity_sigma_mps, E, T3, zws)
    slide(R_new[lane], p_new[lane], v_new[lane], omega[lane], cal.td_s[i], cp[lane], cR[lane], Pi, R3, p3, Jsh, E, NR)
    if _bad(R_new[lane], p_new[lane], v_new[lane], Pi, cfg.max_variance, cfg.max_speed_mps):
        out.diverged_at[i] = k
        _clear_update(out, i, k, j, record)
        copy1(ba[lane], ba_s[lane])
        copy1(bg[lane], bg_s[lane])
        k_stop[lane] = k
        active[lane] = False
        return
    copy2(R[lane], R_new[lane])
    copy1(p[lane], p_new[lane])
    copy1(v[lane], v_new[lane])
    _write_frame(out, i, k, R[lane], p[lane], v[lane], ba[lane], bg[lane])
    for a in range(15):
        out.sigma[i, k, a] = np.sqrt(abs(Pi[a, a]))
    for a in range(27):
        for b in range(27):
            P[a, b, lane] = Pi[a, b]
