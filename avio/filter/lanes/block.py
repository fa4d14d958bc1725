"""Filters in lock-step (issue 30): a block of L = 2, 4 or 8 filters advanced frame by frame together, the dense
phases of every frame (the covariance prediction, C P and Sigma, the 12x12 solve, the gain and
downdate) run for all L at once in C (covariance.c, update.c: the lanes of one SIMD operation are L
filters), the rest (propagation of the state, measurement, outlier tests, information sum, statistics,
injection, standstill, slide, divergence) per lane with the per-filter code of avio/filter/kernels.py
and update.py.

Every lane computes with the operations of its filter alone, in the same order (the C has the numba
code's order; -ffp-contract=off, no fast-math; a lane's pivot, zero skips and outlier decisions its
own), so a block gives the bits of single runs whatever its size (tests/avio/filter/test_lanes.py and
test_against_history.py). A lane whose filter diverged (or that holds none: the last block of a
range) is inactive: it gets benign values (P0, no update) and nothing of it is read.

Layout: the dense phases' arrays lanes last (avio.filter.interface.DenseLanes: entry [a, b, q] of
lane q); each lane's state and what its update keeps between stages lanes first (LaneStates,
LaneKeep); one set of per-filter scratch for whichever lane runs (FrameWorkspace, UpdateWorkspaces).
The block's update and the per-lane helpers that take those structures are inlined (``inline="always"``:
a call would store their flattened arrays on the stack, _simd.kernel_jit). Equations: docs/model.md.
"""

from __future__ import annotations

import numpy as np

from avio.filter._linalg import copy1, copy2
from avio.filter._simd import kernel_jit
from avio.filter.interface import (
    DenseLanes,
    FilterState,
    FrameWorkspace,
    LaneKeep,
    LaneStates,
    NoiseWorkspace,
    UpdateWorkspace,
    UpdateWorkspaces,
)
from avio.filter.kernels import (
    _clear_update,
    _clear_updates,
    _record_poses,
    _write_frame,
    diverges,
    zero_velocity_update_into,
    zero_velocity_workspace,
)
from avio.filter.measurement import measure_workspace, shifted_pose
from avio.filter.propagation import propagate_one, propagate_workspace
from avio.filter.update import (
    M,
    inject,
    noise_workspace,
    outlier_workspace,
    update_information,
    update_measure,
    update_workspace,
)


@kernel_jit(nogil=True, allocates=True)
def run_block(lo, hi, L, seq, cal, cfg, out, fns):
    """All frames of filters lo..hi-1 (hi - lo <= L) in one block of L lanes, filter lo + q in lane q;
    fns: avio.filter.lanes.native.LaneFunctions for L. Inputs and outputs as
    :func:`avio.filter.kernels.run_filters` (seq, cal, cfg, out: avio.filter.interface structures).
    Allocates the block's workspaces (nothing is allocated per frame); releases the GIL."""
    F, z = seq.uv.shape[1], np.zeros
    st = LaneStates(R=z((L, 3, 3)), p=z((L, 3)), v=z((L, 3)), ba=z((L, 3)), bg=z((L, 3)), cp=z((L, 2, 3)),
                    cR=z((L, 2, 3, 3)), R_new=z((L, 3, 3)), p_new=z((L, 3)), v_new=z((L, 3)), omega=z((L, 3)),
                    ba_s=z((L, 3)), bg_s=z((L, 3)), active=z(L, np.bool_), k_stop=z(L, np.int64),
                    counts=z((L, 3), np.int64), sums=z((L, 3)), stats=z((L, 2)))
    keep = LaneKeep(ok=z((L, F), np.bool_), r=z((L, M, F)), J=z((L, M, 12, F)), Rm=z((L, M, M, F)), sd=z((L, M, F)),
                    Lm=z((L, M, M, F)), ldR=z((L, F)), beta=z((L, 12)))
    dn = DenseLanes(P=z((27, 27, L)), Phi=z((15, 15, L)), T=z((15, 27, L)), U=z((15, 15, L)), C=z((12, 27, L)),
                    CP=z((12, 27, L)), PCt=z((27, 12, L)), Sig=z((12, 12, L)), Mx=z((12, 12, L)), X=z((12, 13, L)),
                    K=z((27, 12, L)), ra=z(12 * L), rb=z(13 * L), dx=z((27, L)), J=z((6, 15, L)),
                    NR=z((6, 27, L)), bad=z(L, np.uint8))
    uws = UpdateWorkspaces(update=update_workspace(F), measure=measure_workspace(), noise=noise_workspace(F),
                           outliers=outlier_workspace(F))
    fws = FrameWorkspace(
        omega=z(3), R=z((3, 3)), p=z(3), v=z(3), ba=z(3), bg=z(3), cp=z((2, 3)), cR=z((2, 3, 3)), P=z((27, 27)),
        R_new=z((3, 3)), v_new=z(3), p_new=z(3), Phi=z((15, 15)), E=z((3, 3)), T3=z((3, 3)), Tq=z((15, 27)),
        U=z((15, 15)), R3=z((3, 3)), p3=z(3), Jsh=z((6, 15)), NR=z((6, 27)), ba_s=z(3), bg_s=z(3),
        sig0=np.sqrt(np.abs(np.diag(seq.P0)[:15])), no_record=z(F, np.uint8))
    _run_block_frames(lo, hi, L, seq, cal, cfg, out, fns, st, keep, dn, uws, propagate_workspace(),
                      zero_velocity_workspace(), fws)


@kernel_jit(inline="always")
def _lane_workspaces(uws, keep, q):
    """The update's workspaces of lane q: its kept arrays (LaneKeep) and the shared scratch."""
    u, n = uws.update, uws.noise
    return UpdateWorkspaces(
        update=UpdateWorkspace(r4=u.r4, J4=u.J4, C=u.C, PCt=u.PCt, Sig=u.Sig, t12=u.t12, t13=u.t13, HP=u.HP, z=u.z,
                               ok=keep.ok[q], inl=u.inl, gate=u.gate, A=u.A, Mx=u.Mx, X=u.X, K=u.K, dx=u.dx, CP=u.CP,
                               E3=u.E3, T3=u.T3),
        measure=uws.measure,
        noise=NoiseWorkspace(G4=n.G4, r=keep.r[q], J=keep.J[q], Gp=n.Gp, Rm=keep.Rm[q], sd=keep.sd[q], Lm=keep.Lm[q],
                             ldR=keep.ldR[q], ldS=n.ldS, rw=n.rw, Jw=n.Jw, jw_f=n.jw_f, beta=keep.beta[q]),
        outliers=uws.outliers)


@kernel_jit
def _gather(dst, src, q):
    """dst[a, b] = src[a, b, q]: lane q of a lanes-last array into a per-filter one."""
    for a in range(dst.shape[0]):
        for b in range(dst.shape[1]):
            dst[a, b] = src[a, b, q]


@kernel_jit
def _scatter(dst, src, q):
    """dst[a, b, q] = src[a, b]."""
    for a in range(src.shape[0]):
        for b in range(src.shape[1]):
            dst[a, b, q] = src[a, b]


@kernel_jit
def _benign(dn, q, P0):
    """Lane q's dense arrays set to values the C computes on harmlessly (an inactive lane: no update,
    P grows by the process noise from P0)."""
    for a in range(27):
        for b in range(27):
            dn.P[a, b, q] = P0[a, b]
    for a in range(15):
        for b in range(15):
            dn.Phi[a, b, q] = 1.0 if a == b else 0.0
    for a in range(6):
        for b in range(15):
            dn.J[a, b, q] = 0.0
    for a in range(12):
        for b in range(27):
            dn.C[a, b, q] = 0.0
        for b in range(12):
            dn.Mx[a, b, q] = 1.0 if a == b else 0.0
        for b in range(13):
            dn.X[a, b, q] = 0.0


@kernel_jit
def _start(q, i, hi, N, seq, cal, out, st, dn, record):
    """Lane q's filter i at the initial state (Eq. 9), its update outputs cleared; inactive where it
    holds no filter (i >= hi) or a frozen one (a non-finite calibration: diverged at frame 0)."""
    copy2(st.R[q], seq.R0)
    copy1(st.p[q], seq.p0)
    copy1(st.v[q], seq.v0)
    copy1(st.ba[q], seq.ba0)
    copy1(st.bg[q], seq.bg0)
    st.cp[q] = 0.0
    st.cR[q] = 0.0
    for a in range(3):
        st.cR[q, 0, a, a] = 1.0
        st.cR[q, 1, a, a] = 1.0
    _benign(dn, q, seq.P0)
    st.active[q] = False
    if i < hi:
        _clear_updates(out, i, record)
        frozen = cal.frozen[i]
        out.diverged_at[i] = 0 if frozen else -1
        st.k_stop[q] = 0 if frozen else N
        st.active[q] = not frozen


@kernel_jit(inline="always")
def _diverged(st, q, dn, cfg):
    """Divergence test of lane q after its slide (avio.filter.kernels._bad, Eq. 51), its covariance's
    finiteness from ``dn.bad``."""
    too_uncertain = False
    for a in range(27):
        too_uncertain |= dn.P[a, a, q] > cfg.max_variance
    return diverges(st.R_new[q], st.p_new[q], st.v_new[q], dn.bad[q] != 0, too_uncertain, cfg.max_speed_mps)


@kernel_jit(inline="always")
def _state(st, q, P):
    """Lane q's predicted state as a FilterState (views; P the per-filter covariance scratch)."""
    return FilterState(R=st.R_new[q], p=st.p_new[q], v=st.v_new[q], ba=st.ba[q], bg=st.bg[q], cp0=st.cp[q, 0],
                       cR0=st.cR[q, 0], cp1=st.cp[q, 1], cR1=st.cR[q, 1], P=P)


@kernel_jit
def _run_block_frames(lo, hi, L, seq, cal, cfg, out, fns, st, keep, dn, uws, pws, zws, fws):
    """The frame loop of :func:`run_block` with its workspaces (compiled without reference counting)."""
    N = seq.T_s.shape[0]
    record = out.used.shape[0] > 0
    zv_sigma = cfg.zero_velocity_sigma_mps
    Pg = fws.P
    for q in range(L):
        _start(q, lo + q, hi, N, seq, cal, out, st, dn, record)
    for k in range(N):
        if not st.active.any():
            break
        j = seq.triplet_of_frame[k]
        # Prediction: nominal state (Eqs. 14-16) per lane, covariance (Eq. 18) in lock-step.
        for q in range(L):
            if st.active[q]:
                copy1(st.ba_s[q], st.ba[q])
                copy1(st.bg_s[q], st.bg[q])
                if k > 0:
                    propagate_one(st.R[q], st.v[q], st.p[q], st.ba[q], st.bg[q], seq.g, seq.dR[k], seq.dv[k], seq.dp[k],
                                  seq.S[k], seq.SS[k], seq.Vbg[k], seq.Pbg[k], seq.T_s[k], st.R_new[q], st.v_new[q],
                                  st.p_new[q], fws.Phi, pws)
                    _scatter(dn.Phi, fws.Phi, q)
                else:
                    copy2(st.R_new[q], st.R[q])
                    copy1(st.v_new[q], st.v[q])
                    copy1(st.p_new[q], st.p[q])
                # omega of the time shift, Eq. (19): the gyro at the frame time minus the bias.
                for a in range(3):
                    st.omega[q, a] = seq.gyro_frame[k, a] - st.bg[q, a]
        if k > 0:
            fns.pred(dn.P.ctypes.data, dn.Phi.ctypes.data, seq.Qd[k].ctypes.data, dn.T.ctypes.data, dn.U.ctypes.data)
        if k >= 2 and seq.stationary[k] and zv_sigma > 0:
            # Standing still (Eqs. 47-48): the zero-velocity update (Eq. 49), per lane.
            for q in range(L):
                if st.active[q]:
                    _gather(Pg, dn.P, q)
                    zero_velocity_update_into(st.R_new[q], st.p_new[q], st.v_new[q], st.ba[q], st.bg[q], st.cp[q, 0],
                                              st.cR[q, 0], st.cp[q, 1], st.cR[q, 1], Pg, zv_sigma, fws.E, fws.T3, zws)
                    _scatter(dn.P, Pg, q)
        elif k >= 2 and j >= 0:
            _update_block(lo, k, j, L, seq, cal, cfg, out, fns, st, keep, dn, uws, fws, record)
        # Slide (Eq. 50): the new clone per lane, the covariance in lock-step; divergence (Eq. 51).
        for q in range(L):
            if st.active[q]:
                shifted_pose(st.R_new[q], st.p_new[q], st.v_new[q], st.omega[q], cal.td_s[lo + q], fws.R3, fws.p3,
                             fws.Jsh, fws.E)
                copy1(st.cp[q, 0], st.cp[q, 1])
                copy2(st.cR[q, 0], st.cR[q, 1])
                copy1(st.cp[q, 1], fws.p3)
                copy2(st.cR[q, 1], fws.R3)
                _scatter(dn.J, fws.Jsh, q)
        fns.slide(dn.P.ctypes.data, dn.J.ctypes.data, dn.NR.ctypes.data)
        fns.finite(dn.P.ctypes.data, dn.bad.ctypes.data)
        for q in range(L):
            if not st.active[q]:
                continue
            i = lo + q
            if _diverged(st, q, dn, cfg):
                out.diverged_at[i] = k
                _clear_update(out, i, k, j, record)
                copy1(st.ba[q], st.ba_s[q])
                copy1(st.bg[q], st.bg_s[q])
                st.k_stop[q] = k
                st.active[q] = False
                _benign(dn, q, seq.P0)
                continue
            copy2(st.R[q], st.R_new[q])
            copy1(st.p[q], st.p_new[q])
            copy1(st.v[q], st.v_new[q])
            _write_frame(out, i, k, st.R[q], st.p[q], st.v[q], st.ba[q], st.bg[q])
            for a in range(15):
                out.sigma[i, k, a] = np.sqrt(abs(dn.P[a, a, q]))
    # From the divergence on: the last good state (biases included), the initial sigmas.
    for q in range(hi - lo):
        for k in range(st.k_stop[q], N):
            _write_frame(out, lo + q, k, st.R[q], st.p[q], st.v[q], st.ba[q], st.bg[q])
            copy1(out.sigma[lo + q, k], fws.sig0)


@kernel_jit(inline="always")
def _update_block(lo, k, j, L, seq, cal, cfg, out, fns, st, keep, dn, uws, fws, record):
    """Frame k's trifocal update (triplet j) of every active lane: avio.filter.update.update's stages,
    the dense ones (C P and Sigma, the solve, the downdate) for the whole block at once."""
    u_ = uws.update
    uv, valid = seq.uv[j], seq.valid[j]
    for q in range(L):
        if st.active[q]:
            i = lo + q
            x = _state(st, q, fws.P)
            if record:
                _record_poses(out.update_poses[i, k], x)
            n_ok, n_valid = update_measure(x, st.omega[q], cal, i, uv, valid, cfg, _lane_workspaces(uws, keep, q))
            st.counts[q, 0], st.counts[q, 1] = n_ok, n_valid
            _scatter(dn.C, u_.C, q)
    fns.proj(dn.C.ctypes.data, dn.P.ctypes.data, dn.CP.ctypes.data, dn.PCt.ctypes.data, dn.Sig.ctypes.data)
    for q in range(L):
        if st.active[q]:
            i = lo + q
            _gather(u_.Sig, dn.Sig, q)
            decided = out.used[i, j] if record else fws.no_record
            used, rr, log_det_R, nll = update_information(valid, cfg, _lane_workspaces(uws, keep, q), record, decided)
            st.counts[q, 2] = used
            st.sums[q, 0], st.sums[q, 1], st.sums[q, 2] = rr, log_det_R, nll
            _scatter(dn.Mx, u_.Mx, q)
            _scatter(dn.X, u_.X, q)
    fns.solve(dn.Mx.ctypes.data, dn.X.ctypes.data, dn.ra.ctypes.data, dn.rb.ctypes.data)
    fns.stats(dn.Sig.ctypes.data, dn.X.ctypes.data, dn.PCt.ctypes.data, keep.beta.ctypes.data, st.sums.ctypes.data,
              dn.dx.ctypes.data, st.stats.ctypes.data)
    for q in range(L):
        if st.active[q]:
            i = lo + q
            # Eq. (45): log det S = sum_f log det R_f + log det(I + A Sigma), the pivots of the elimination.
            log_det_S = st.sums[q, 1]
            for a in range(12):
                log_det_S += np.log(abs(dn.Mx[a, a, q]))
            used = st.counts[q, 2]
            out.n_updates[i, k], out.n_outliers[i, k] = used, st.counts[q, 0] - used
            out.nis[i, k], out.log_det_S[i, k], out.dof[i, k] = st.stats[q, 0], log_det_S, M * used
            out.pose_trace[i, k] = st.stats[q, 1]
            out.nll[i, k], out.nll_slots[i, k] = st.sums[q, 2], M * st.counts[q, 1]
            if record:
                _gather(out.pose_cov[i, k], dn.Sig, q)
            # Eq. (8): the injection (before the downdate here; neither reads what the other writes).
            for a in range(27):
                u_.dx[a] = dn.dx[a, q]
            x = _state(st, q, fws.P)
            inject(x.R, x.p, x.v, x.ba, x.bg, x.cp0, x.cR0, x.cp1, x.cR1, u_.dx, u_.E3, u_.T3)
    fns.gain(dn.P.ctypes.data, dn.PCt.ctypes.data, dn.X.ctypes.data, dn.CP.ctypes.data, dn.K.ctypes.data)
