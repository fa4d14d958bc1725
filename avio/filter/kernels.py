"""Compiled kernels of the batched VIO filter (avio/filter/batch.py): the whole run of n filters
(:func:`run_filters`) and its per-filter steps: prediction of the covariance, the zero-velocity
update, the window slide and the divergence test; the trifocal update (measurement chain,
outlier rejection, Kalman update, injection) is avio/filter/update.py. Equations: docs/model.md.

Why compiled: per frame and filter the work is ~16 features x 4 residuals with 12-column Jacobians,
16 hypotheses of 1-point RANSAC and a few 12x12 and 27x27 products: small work that numpy spread
over ~200 calls per frame, whose overhead cost more than the arithmetic. numba with non-aliasing
array arguments and LLVM's SLP vectoriser (avio/filter/_simd.py: kernel_jit; the same bits, packed
instructions where LLVM finds them) and ``cache=True`` (compiled once, then loaded from
avio/filter/__pycache__; NB numba's cache does not notice edits to functions of other modules called
from a cached one: after editing avio/filter/update.py, measurement.py, trifocal.py, outliers.py, _linalg.py or
propagation.py, delete avio/filter/__pycache__/*.nbi and *.nbc), ``error_model="numpy"`` (a division
by zero gives inf/NaN as numpy did; such features are dropped) and no fastmath, so every run gives
the same bits. Each filter runs alone on one thread (:func:`run_filters` runs a contiguous range of
the batch, one filter after the other, with one set of workspaces allocated once, so nothing is
allocated per frame; it releases the GIL and avio/filter/batch.py runs one range per thread), so a
batch gives the same numbers as single runs whatever the thread count.

Error state (27): ``[dp, dtheta, dv, db_a, db_g, dp1, dtheta1, dp2, dtheta2]`` (docs/model.md, Eq. 8).
One filter: R (3, 3) ``R_world_imu``; p, v, ba, bg (3,); clones cp0, cp1 (3,), cR0, cR1 (3, 3)
(frames k-2, k-1); covariance P (27, 27); calibration fx, fy, cx, cy, td scalars, Rci
``R_cam_imu`` (3, 3), pic ``p_imu_cam_m`` (3,). ``*_all`` wrappers take the same with a
leading n axis (clones (2, n, ...)).
"""

from __future__ import annotations

import numpy as np

from avio.filter._linalg import copy1, copy2, solve
from avio.filter._simd import kernel_jit
from avio.filter.interface import FilterState, FrameWorkspace, UpdateWorkspaces, ZeroVelocityWorkspace
from avio.filter.measurement import measure_workspace, shifted_pose
from avio.filter.propagation import propagate_one, propagate_workspace
from avio.filter.update import inject, noise_workspace, outlier_workspace, update, update_workspace


@kernel_jit
def propagate_covariance(Pi, Phi, Qd, T, U):
    """Covariance prediction of one filter, in place: ``P <- F P F^T + Q`` with
    ``F = blockdiag(Phi, I_12)`` (clones have no dynamics), Phi (15, 15) the core error
    transition of the interval, with the zero pattern of Eq. 16 (avio.filter.propagation.propagate_one:
    only the entries :func:`_phi_product` reads may be nonzero), Qd (15, 15) its discrete process
    noise (T (15, 27), U (15, 15): scratch). (docs/model.md, Eq. 18; Phi: Eq. 16, Qd: Eq. 17.)"""
    # T = Phi P[0:15, :] (rows of the new cross-covariances and of W = Phi P15), U = W^T.
    _phi_product(Phi, Pi, Qd, T, 27, False)
    for a in range(15):
        for b in range(15):
            U[a, b] = T[b, a]
    # Eq. (18): P15 <- Phi W^T + Q = Phi P15 Phi^T + Q; cross blocks <- T[:, 15:27].
    _phi_product(Phi, U, Qd, Pi, 15, True)
    for a in range(15):
        for b in range(15, 27):
            Pi[a, b] = T[a, b]
            Pi[b, a] = T[a, b]


@kernel_jit(inline="always")
def _phi_product(Phi, X, Q, out, n, with_q):
    """out[a, b] = (Q[a, b] if with_q else 0) + sum_c Phi[a, c] X[c, b] for a < 15, b < n, the sum
    over the columns where row a of Phi (Eq. 16) can be nonzero, c in order: rows 0-2 (dp)
    columns a, 3-5, 6 + a, 9-14; rows 3-5 (dtheta) 3-5, 12-14; rows 6-8 (dv) 3-5, a, 9-14; the
    bias rows their diagonal. Each sum in a register over lanes of b (the loops over c have
    fixed lengths and unroll). The same bits as skipping every zero of Phi (the loop this
    replaced, issue 30): a sum from +0 (or Q >= 0) is never -0, so adding 0 * x (x finite: P is,
    or the filter has stopped) changes nothing."""
    for i in range(3):
        for b in range(n):
            acc = Q[i, b] if with_q else 0.0
            acc += Phi[i, i] * X[i, b]
            for c in range(3, 6):
                acc += Phi[i, c] * X[c, b]
            acc += Phi[i, 6 + i] * X[6 + i, b]
            for c in range(9, 15):
                acc += Phi[i, c] * X[c, b]
            out[i, b] = acc
    for a in range(3, 6):
        for b in range(n):
            acc = Q[a, b] if with_q else 0.0
            for c in range(3, 6):
                acc += Phi[a, c] * X[c, b]
            for c in range(12, 15):
                acc += Phi[a, c] * X[c, b]
            out[a, b] = acc
    for a in range(6, 9):
        for b in range(n):
            acc = Q[a, b] if with_q else 0.0
            for c in range(3, 6):
                acc += Phi[a, c] * X[c, b]
            acc += Phi[a, a] * X[a, b]
            for c in range(9, 15):
                acc += Phi[a, c] * X[c, b]
            out[a, b] = acc
    for a in range(9, 15):
        for b in range(n):
            acc = Q[a, b] if with_q else 0.0
            out[a, b] = acc + Phi[a, a] * X[a, b]


@kernel_jit
def slide(R, p, v, omega, td, cp, cR, Pi, R3, p3, J, E, NR):
    """Slide the window of one filter, in place: drop clone k-2 (cp (2, 3), cR (2, 3, 3)), move
    k-1 down, clone the current exposure-time pose (:func:`shifted_pose`); its covariance rows
    are ``J P[0:15]`` (R3, p3, J, E, NR (6, 27): scratch). (docs/model.md, Eq. 50; the shifted
    pose and J: Eq. 19.)"""
    # Eq. (19): the exposure-time pose and its Jacobian J (6, 15).
    shifted_pose(R, p, v, omega, td, R3, p3, J, E)
    copy1(cp[0], cp[1])
    copy2(cR[0], cR[1])
    copy1(cp[1], p3)
    copy2(cR[1], R3)
    # Eq. (50): the new clone's rows J P[0:15, :], its block J P_cc J^T; clone k-1 moves down.
    for a in range(6):
        for b in range(27):
            NR[a, b] = 0.0
        for c in range(15):
            f = J[a, c]
            if f != 0.0:
                for b in range(27):
                    NR[a, b] += f * Pi[c, b]  # NR = J P[0:15, :]
    for a in range(6):
        for b in range(15, 21):
            NR[a, b] = NR[a, b + 6]
    # Clone k-1 (rows/columns 21:27) moves to 15:21; in place is safe because each entry is
    # read from the same or a later, not yet written position. Contiguous runs (they vectorise):
    # the core rows' columns 21:27, then the clone's rows; the core block stays where it is.
    for a in range(15):
        for b in range(15, 21):
            Pi[a, b] = Pi[a, b + 6]
    for a in range(15, 21):
        for b in range(15):
            Pi[a, b] = Pi[a + 6, b]
        for b in range(15, 21):
            Pi[a, b] = Pi[a + 6, b + 6]
    for a in range(6):
        for b in range(21):
            Pi[21 + a, b] = NR[a, b]
            Pi[b, 21 + a] = NR[a, b]
        for b in range(6):
            acc = 0.0
            for c in range(15):
                acc += NR[a, c] * J[b, c]
            Pi[21 + a, 21 + b] = acc


@kernel_jit(allocates=True)
def zero_velocity_update(R, p, v, ba, bg, cp0, cR0, cp1, cR1, Pi, sigma_mps, E, T):
    """Pseudo-measurement v = 0 with noise sigma_mps (m/s) of one filter, in place: the
    Kalman update ``S = P_vv + sigma^2 I``, ``dx = -P_xv S^-1 v``, ``P -= P_xv S^-1 P_vx``
    (symmetrised), then the injection (docs/model.md, Eq. 49; injection Eq. 8). A full update:
    the position error accumulated while braking is corrected through the position-velocity
    correlation (a "consider" update of the velocity and biases only was tried: 4.9 m instead
    of 1.4 m at the truth, seed 0).
    Allocates its scratch; the filter calls :func:`zero_velocity_update_into`."""
    zero_velocity_update_into(R, p, v, ba, bg, cp0, cR0, cp1, cR1, Pi, sigma_mps, E, T, zero_velocity_workspace())


@kernel_jit(allocates=True)
def zero_velocity_workspace():
    """Scratch arrays of :func:`zero_velocity_update_into` (avio.filter.interface.ZeroVelocityWorkspace)."""
    return ZeroVelocityWorkspace(S=np.empty((3, 3)), Z=np.empty((3, 28)), dx=np.empty(27), K=np.empty((27, 27)))


@kernel_jit
def zero_velocity_update_into(R, p, v, ba, bg, cp0, cR0, cp1, cR1, Pi, sigma_mps, E, T, zws):
    """:func:`zero_velocity_update` with its scratch zws passed in (:func:`zero_velocity_workspace`)."""
    S, Z, dx, K = zws.S, zws.Z, zws.dx, zws.K
    # Eq. (49): S = P_vv + sigma^2 I and Z = S^-1 [P_v. | -v].
    for a in range(3):
        for b in range(3):
            S[a, b] = Pi[6 + a, 6 + b] + (sigma_mps * sigma_mps if a == b else 0.0)
        for b in range(27):
            Z[a, b] = Pi[6 + a, b]
        Z[a, 27] = -v[a]
    solve(S, Z)
    # Eq. (49): dx = P_.v S^-1 (0 - v), P <- sym(P - P_.v S^-1 P_v.).
    for a in range(27):
        dx[a] = Pi[a, 6] * Z[0, 27] + Pi[a, 7] * Z[1, 27] + Pi[a, 8] * Z[2, 27]
    for a in range(27):
        for b in range(27):
            K[a, b] = Pi[a, 6] * Z[0, b] + Pi[a, 7] * Z[1, b] + Pi[a, 8] * Z[2, b]
    for a in range(27):
        for b in range(a + 1):
            s = 0.5 * ((Pi[a, b] - K[a, b]) + (Pi[b, a] - K[b, a]))
            Pi[a, b], Pi[b, a] = s, s
    # Eq. (8): the injection.
    inject(R, p, v, ba, bg, cp0, cR0, cp1, cR1, dx, E, T)


@kernel_jit
def _bad(R, p, v, Pi, max_variance, max_speed):
    """Divergence test of one filter (docs/model.md, Eq. 51): non-finite state or covariance, a
    covariance diagonal above max_variance, or a speed above max_speed."""
    nonfinite = False  # x - x is NaN exactly for inf and NaN; no early exit, so it vectorises
    for a in range(27):
        for b in range(27):
            nonfinite |= (Pi[a, b] - Pi[a, b]) != 0.0
    too_uncertain = False
    for a in range(27):
        too_uncertain |= Pi[a, a] > max_variance
    return diverges(R, p, v, nonfinite, too_uncertain, max_speed)


@kernel_jit
def diverges(R, p, v, P_nonfinite, too_uncertain, max_speed):
    """Eq. 51 given the covariance's two tests (a non-finite entry; a diagonal above the limit): those,
    a non-finite R (3, 3), p, v (3,), or a speed above max_speed (m/s)."""
    nonfinite = P_nonfinite
    for a in range(3):
        nonfinite |= (p[a] - p[a]) != 0.0 or (v[a] - v[a]) != 0.0
        for b in range(3):
            nonfinite |= (R[a, b] - R[a, b]) != 0.0
    if nonfinite or too_uncertain:
        return True
    return np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) > max_speed


@kernel_jit(nogil=True, allocates=True)
def run_filters(lo, hi, seq, cal, cfg, out):
    """All frames of filters lo..hi-1 (avio/filter/batch.py: run): each filter alone, one after the
    other (so a batch gives the same bits as single runs), its frames in order (docs/model.md,
    "One frame, in order"): prediction
    (:func:`avio.filter.propagation.propagate_one`, :func:`propagate_covariance`), the trifocal
    :func:`update` or, standing still, :func:`zero_velocity_update`, :func:`slide`, the
    divergence test. A diverged filter (or one with ``cal.frozen`` set: a non-finite calibration)
    keeps the estimates of its last good frame, reports the initial sigmas and no updates
    from then on.

    seq: avio.filter.interface.SequenceInputs (the biases start at seq.ba0, seq.bg0, the prior
    means); cal: interface.Calibrations (row i for filter i); cfg: interface.Settings; out:
    interface.Outputs, rows lo..hi-1 written: estimates, update counts, divergence frame and the
    innovation statistics of each frame's update (NIS, log det S, residual count, NLL
    contribution and residual slots; zero where no trifocal update ran); ``out.used`` (n, n_trip,
    F) uint8, or (0, ...) not to record them: which features each triplet's update used; with it
    ``out.pose_cov`` and ``out.update_poses``: each update's relative-pose covariance and the
    poses it linearised about.
    One set of workspaces is allocated here (nothing is allocated in the frame loop); it releases
    the GIL, so avio/filter/batch.py runs contiguous ranges of a batch on several threads at once
    (each filter on one thread, with the same operations as alone: the bits do not depend on the
    batch or thread count).
    """
    F = seq.uv.shape[1]
    uws = UpdateWorkspaces(update=update_workspace(F), measure=measure_workspace(), noise=noise_workspace(F),
                           outliers=outlier_workspace(F))
    fws = FrameWorkspace(
        omega=np.empty(3), R=np.empty((3, 3)), p=np.empty(3), v=np.empty(3), ba=np.empty(3), bg=np.empty(3),
        cp=np.empty((2, 3)), cR=np.empty((2, 3, 3)), P=np.empty((27, 27)), R_new=np.empty((3, 3)), v_new=np.empty(3),
        p_new=np.empty(3), Phi=np.empty((15, 15)), E=np.empty((3, 3)), T3=np.empty((3, 3)), Tq=np.empty((15, 27)),
        U=np.empty((15, 15)), R3=np.empty((3, 3)), p3=np.empty(3), Jsh=np.empty((6, 15)), NR=np.empty((6, 27)),
        ba_s=np.empty(3), bg_s=np.empty(3), sig0=np.sqrt(np.abs(np.diag(seq.P0)[:15])), no_record=np.zeros(F, np.uint8))
    _run_range(lo, hi, seq, cal, cfg, out, uws, propagate_workspace(), zero_velocity_workspace(), fws)


@kernel_jit
def _run_range(lo, hi, seq, cal, cfg, out, uws, pws, zws, fws):
    """The frame loop of :func:`run_filters` with its workspaces (interface.FrameWorkspace fws),
    compiled without reference counting (kernel_jit; it allocates nothing)."""
    N = seq.T_s.shape[0]
    omega, R, p, v, ba, bg, cp, cR, P = fws.omega, fws.R, fws.p, fws.v, fws.ba, fws.bg, fws.cp, fws.cR, fws.P
    R_new, v_new, p_new, Phi, E, T3, Tq, U = fws.R_new, fws.v_new, fws.p_new, fws.Phi, fws.E, fws.T3, fws.Tq, fws.U
    R3, p3, Jsh, NR, ba_s, bg_s, sig0, no_record = fws.R3, fws.p3, fws.Jsh, fws.NR, fws.ba_s, fws.bg_s, fws.sig0, \
        fws.no_record
    # The predicted state the updates correct: views, so made once.
    x = FilterState(R=R_new, p=p_new, v=v_new, ba=ba, bg=bg, cp0=cp[0], cR0=cR[0], cp1=cp[1], cR1=cR[1], P=P)
    record = out.used.shape[0] > 0
    zv_sigma = cfg.zero_velocity_sigma_mps
    for i in range(lo, hi):
        copy2(R, seq.R0)
        copy1(p, seq.p0)
        copy1(v, seq.v0)
        copy2(P, seq.P0)
        copy1(ba, seq.ba0)
        copy1(bg, seq.bg0)
        cp[:] = 0.0
        cR[:] = 0.0
        for a in range(3):
            cR[0, a, a] = 1.0
            cR[1, a, a] = 1.0
        _clear_updates(out, i, record)
        frozen = cal.frozen[i]
        out.diverged_at[i] = 0 if frozen else -1
        k_stop = 0 if frozen else N
        for k in range(k_stop):
            copy1(ba_s, ba)
            copy1(bg_s, bg)
            # Prediction: nominal state (Eqs. 14-16), covariance (Eq. 18).
            if k > 0:
                propagate_one(R, v, p, ba, bg, seq.g, seq.dR[k], seq.dv[k], seq.dp[k], seq.S[k], seq.SS[k],
                              seq.Vbg[k], seq.Pbg[k], seq.T_s[k], R_new, v_new, p_new, Phi, pws)
                propagate_covariance(P, Phi, seq.Qd[k], Tq, U)
            else:
                copy2(R_new, R)
                copy1(v_new, v)
                copy1(p_new, p)
            # omega of the time shift, Eq. (19): the gyro at the frame time minus the bias.
            for a in range(3):
                omega[a] = seq.gyro_frame[k, a] - bg[a]
            j = seq.triplet_of_frame[k]
            # Standing still (Eqs. 47-48): the zero-velocity update (Eq. 49) replaces the trifocal
            # update (Eqs. 20-46).
            if k >= 2 and seq.stationary[k] and zv_sigma > 0:
                zero_velocity_update_into(R_new, p_new, v_new, ba, bg, cp[0], cR[0], cp[1], cR[1], P, zv_sigma, E, T3,
                                          zws)
            elif k >= 2 and j >= 0:
                decided = out.used[i, j] if record else no_record
                if record:
                    _record_poses(out.update_poses[i, k], x)
                used, rej, nis, ldS, dof, nll, slots, trace = update(x, omega, cal, i, seq.uv[j], seq.valid[j], cfg,
                                                                     uws, record, decided)
                out.n_updates[i, k], out.n_outliers[i, k] = used, rej
                out.nis[i, k], out.log_det_S[i, k], out.dof[i, k] = nis, ldS, dof
                out.pose_trace[i, k] = trace
                out.nll[i, k], out.nll_slots[i, k] = nll, slots
                if record:
                    copy2(out.pose_cov[i, k], uws.update.Sig)
            # Slide (Eq. 50).
            slide(R_new, p_new, v_new, omega, cal.td_s[i], cp, cR, P, R3, p3, Jsh, E, NR)
            # Divergence (Eq. 51): this frame's outputs are those of the last good one.
            if _bad(R_new, p_new, v_new, P, cfg.max_variance, cfg.max_speed_mps):
                out.diverged_at[i] = k
                _clear_update(out, i, k, j, record)
                copy1(ba, ba_s)
                copy1(bg, bg_s)
                k_stop = k
                break
            copy2(R, R_new)
            copy1(p, p_new)
            copy1(v, v_new)
            _write_frame(out, i, k, R, p, v, ba, bg)
            for a in range(15):
                out.sigma[i, k, a] = np.sqrt(abs(P[a, a]))
        # From the divergence on: the last good state (biases included), the initial sigmas.
        for k in range(k_stop, N):
            _write_frame(out, i, k, R, p, v, ba, bg)
            copy1(out.sigma[i, k], sig0)


@kernel_jit
def _write_frame(out, i, k, R, p, v, ba, bg):
    """Filter i's estimates at frame k into out (interface.Outputs)."""
    copy1(out.p[i, k], p)
    copy2(out.R[i, k], R)
    copy1(out.v[i, k], v)
    copy1(out.ba[i, k], ba)
    copy1(out.bg[i, k], bg)


@kernel_jit
def _clear_updates(out, i, record):
    """Filter i's update statistics (and recorded decisions) zeroed before its run."""
    out.n_updates[i, :] = 0
    out.n_outliers[i, :] = 0
    out.nis[i, :] = 0.0
    out.log_det_S[i, :] = 0.0
    out.pose_trace[i, :] = 0.0
    out.dof[i, :] = 0
    out.nll[i, :] = 0.0
    out.nll_slots[i, :] = 0
    if record:
        out.used[i] = 0
        out.pose_cov[i] = 0.0
        out.update_poses[i] = 0.0


@kernel_jit
def _clear_update(out, i, k, j, record):
    """Frame k's update of filter i undone in the outputs (it diverged there; j its triplet)."""
    out.n_updates[i, k] = 0
    out.n_outliers[i, k] = 0
    out.nis[i, k] = 0.0
    out.log_det_S[i, k] = 0.0
    out.pose_trace[i, k] = 0.0
    out.dof[i, k] = 0
    out.nll[i, k] = 0.0
    out.nll_slots[i, k] = 0
    if record and j >= 0:
        out.used[i, j] = 0
    if record:
        out.pose_cov[i, k] = 0.0
        out.update_poses[i, k] = 0.0


@kernel_jit
def _record_poses(poses, x):
    """The IMU poses an update linearises about into poses (3, 4, 3): the clones of frames k-2,
    k-1 and the predicted frame k (FilterState x), rows 0-2 R_world_imu, row 3 p_world_imu."""
    for a in range(3):
        for b in range(3):
            poses[0, a, b] = x.cR0[a, b]
            poses[1, a, b] = x.cR1[a, b]
            poses[2, a, b] = x.R[a, b]
        poses[0, 3, a] = x.cp0[a]
        poses[1, 3, a] = x.cp1[a]
        poses[2, 3, a] = x.p[a]
