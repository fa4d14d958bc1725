"""The kernel's inputs, outputs and workspaces in a few named structures (issue 30).

:func:`avio.filter.kernels.run_filters` takes five: :class:`SequenceInputs` (what the sequence
gives every filter), :class:`Calibrations` (one row per filter), :class:`Settings` (the scalar
configuration), :class:`Outputs` (written by the kernel) and the range of filters to run; its
scratch is :class:`FrameWorkspace` and :class:`UpdateWorkspaces`. Each is a ``typing.NamedTuple``, which numba types
as a record of its fields: passed by value, the fields read by name in compiled code and
compiled to the same loads as separate arguments (the bits and the call cost are those of the
positional tuple of 55 parameters it replaced; benchmarks/README.md). numba's structref was the
other candidate: a heap object with a boxing class to write, for no gain on a call made once per
batch. Shapes: n filters, N frames, n_trip triplets, F features per triplet. Equations:
docs/model.md.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class SequenceInputs(NamedTuple):
    """What the sequence gives every filter (avio/filter/prepare.py; calibration-independent)."""

    R0: np.ndarray  #: (3, 3) initial R_world_imu (Eq. 9)
    p0: np.ndarray  #: (3,) initial p_world_imu, m
    v0: np.ndarray  #: (3,) initial v_world_imu, m/s
    P0: np.ndarray  #: (27, 27) initial covariance (Eq. 9)
    ba0: np.ndarray  #: (3,) initial accelerometer bias, m/s^2
    bg0: np.ndarray  #: (3,) initial gyro bias, rad/s
    g: np.ndarray  #: (3,) gravity in the world frame, m/s^2
    dR: np.ndarray  #: (N, 3, 3) preintegrated rotation of interval k (Eq. 12; row 0 unused)
    dv: np.ndarray  #: (N, 3) preintegrated velocity increment, m/s
    dp: np.ndarray  #: (N, 3) preintegrated position increment, m
    S: np.ndarray  #: (N, 3, 3) int dR ds, s (Eq. 12)
    SS: np.ndarray  #: (N, 3, 3) int S ds, s^2
    Vbg: np.ndarray  #: (N, 3, 3) int [dR a]x S ds
    Pbg: np.ndarray  #: (N, 3, 3) int Vbg ds
    T_s: np.ndarray  #: (N,) interval lengths, s
    gyro_frame: np.ndarray  #: (N, 3) the gyro at the frame times, rad/s
    Qd: np.ndarray  #: (N, 15, 15) discrete process noise of interval k (Eq. 17)
    triplet_of_frame: np.ndarray  #: (N,) int64: triplet updated at frame k, -1 for none
    uv: np.ndarray  #: (n_trip, F, 3, 2) pixels of each feature in images 1, 2, 3
    valid: np.ndarray  #: (n_trip, F) bool: the feature is a candidate
    stationary: np.ndarray  #: (N,) bool: standing still at frame k (Eqs. 47-48)


class Calibrations(NamedTuple):
    """The candidate calibrations, row i for filter i."""

    fx: np.ndarray  #: (n,) focal length x, px
    fy: np.ndarray  #: (n,) focal length y, px
    cx: np.ndarray  #: (n,) principal point x, px
    cy: np.ndarray  #: (n,) principal point y, px
    R_cam_imu: np.ndarray  #: (n, 3, 3)
    p_imu_cam_m: np.ndarray  #: (n, 3) the camera origin in the IMU frame, m
    td_s: np.ndarray  #: (n,) time offset, s (Eq. 19)
    frozen: np.ndarray  #: (n,) bool: a non-finite calibration, diverged at frame 0 (Eq. 51)


class Settings(NamedTuple):
    """The scalar configuration of the kernel (from :class:`avio.filter.config.FilterConfig`)."""

    sigma_px: float  #: pixel noise, px (Eq. 35)
    max_transfer_gain: float  #: transfer gain limit, px per px of noise (Eq. 36)
    min_parallax_m: float  #: baseline needed for a trifocal update, m (Eq. 36)
    mode: int  #: outlier rejection, avio.filter.update.MODE_*
    ransac_threshold_sigma: float  #: RANSAC inlier threshold, standard deviations (Eq. 38)
    chi2_threshold: float  #: chi-square gate of one feature (Eq. 39)
    zero_velocity_sigma_mps: float  #: zero-velocity pseudo-measurement noise, m/s (Eq. 49); 0: off
    max_variance: float  #: divergence: largest covariance diagonal (Eq. 51)
    max_speed_mps: float  #: divergence: largest speed, m/s (Eq. 51)
    #: J_f (and G_f: correct_noise_model) at the corrected pixels (Eqs. 35a-c), the step at most this long, px;
    #: 0: at the measured pixels
    correction_cap_px: float
    #: with correction_cap_px > 0: G_f (so R_f) at the corrected pixels too (Eq. 35a); False: J_f alone (Eq. 35c)
    correct_noise_model: bool


class Outputs(NamedTuple):
    """What the kernel writes, row i for filter i (avio.filter.config.FilterResult)."""

    p: np.ndarray  #: (n, N, 3) p_world_imu, m
    R: np.ndarray  #: (n, N, 3, 3) R_world_imu
    v: np.ndarray  #: (n, N, 3) v_world_imu, m/s
    sigma: np.ndarray  #: (n, N, 15) square roots of the core covariance diagonal
    ba: np.ndarray  #: (n, N, 3) accelerometer bias, m/s^2
    bg: np.ndarray  #: (n, N, 3) gyro bias, rad/s
    n_updates: np.ndarray  #: (n, N) int64 features used by frame k's update
    n_outliers: np.ndarray  #: (n, N) int64 features rejected
    diverged_at: np.ndarray  #: (n,) int64 frame of the divergence, -1 for none
    nis: np.ndarray  #: (n, N) NIS of the update (Eq. 44)
    log_det_S: np.ndarray  #: (n, N) log det S of the update (Eq. 45)
    pose_trace: np.ndarray  #: (n, N) tr(J^T S^-1 J Sigma), the pose's share of S (Eq. 55b)
    dof: np.ndarray  #: (n, N) int64 residual count of the update
    nll: np.ndarray  #: (n, N) NLL contribution of the update (Eq. 46)
    nll_slots: np.ndarray  #: (n, N) int64 residual slots it covers
    used: np.ndarray  #: (n, n_trip, F) uint8 features used, or (0, n_trip, F): not recorded
    pose_cov: np.ndarray  #: (n, N, 12, 12) Sigma = C P C^T of frame k's update (Eq. 37), or (0, N, 12, 12)
    update_poses: np.ndarray  #: (n, N, 3, 4, 3) the IMU poses frame k's update linearises about, or (0, ...)


class FilterState(NamedTuple):
    """One filter's nominal state (views into :class:`Workspace` arrays; Eq. 8's order)."""

    R: np.ndarray  #: (3, 3) R_world_imu
    p: np.ndarray  #: (3,) m
    v: np.ndarray  #: (3,) m/s
    ba: np.ndarray  #: (3,) m/s^2
    bg: np.ndarray  #: (3,) rad/s
    cp0: np.ndarray  #: (3,) clone of frame k-2: exposure-time IMU position, m
    cR0: np.ndarray  #: (3, 3) its rotation
    cp1: np.ndarray  #: (3,) clone of frame k-1, m
    cR1: np.ndarray  #: (3, 3)
    P: np.ndarray  #: (27, 27) covariance of the error state


class UpdateWorkspace(NamedTuple):
    """Scratch of the Kalman update (avio.filter.update.update), d = 12 relative-pose errors."""

    r4: np.ndarray  #: (4, F) residuals of avio.filter.measurement, px
    J4: np.ndarray  #: (4, d, F) their Jacobians
    C: np.ndarray  #: (d, 27) error state -> relative-pose errors (Eq. 24)
    PCt: np.ndarray  #: (27, d) P C^T
    Sig: np.ndarray  #: (d, d) Sigma = C P C^T (Eq. 37)
    t12: np.ndarray  #: (3,) predicted baseline 1-2, m
    t13: np.ndarray  #: (3,) predicted baseline 1-3, m
    HP: np.ndarray  #: (M, d, F) per-feature B = J L
    z: np.ndarray  #: (M, F) S_f^-1 r_f
    ok: np.ndarray  #: (F,) bool usable features
    inl: np.ndarray  #: (F,) bool inliers
    gate: np.ndarray  #: (F,) bool gate decisions
    A: np.ndarray  #: (d, d) information J^T R^-1 J (Eq. 40)
    Mx: np.ndarray  #: (d, d) I + A Sigma
    X: np.ndarray  #: (d, d + 1) (I + A Sigma)^-1 [A | beta]
    K: np.ndarray  #: (27, d) gain rows
    dx: np.ndarray  #: (27,) correction
    CP: np.ndarray  #: (d, 27) C P
    E3: np.ndarray  #: (3, 3)
    T3: np.ndarray  #: (3, 3)


class NoiseWorkspace(NamedTuple):
    """Scratch of the measurement-noise model, features last (M used residuals)."""

    G4: np.ndarray  #: (4, 6, F) pixel sensitivities of the 4 residuals
    r: np.ndarray  #: (M, F) used residuals, px
    J: np.ndarray  #: (M, 12, F) their Jacobians
    Gp: np.ndarray  #: (M, 6, F) their pixel sensitivities
    Rm: np.ndarray  #: (M, M, F) covariances R_f, px^2 (Eq. 35)
    sd: np.ndarray  #: (M, F) standard deviations, px
    Lm: np.ndarray  #: (M, M, F) Cholesky factors of R_f
    ldR: np.ndarray  #: (F,) log det R_f
    ldS: np.ndarray  #: (F,) log det S_f
    rw: np.ndarray  #: (M, F) whitened residuals
    Jw: np.ndarray  #: (M, 12, F) whitened Jacobians
    jw_f: np.ndarray  #: (M, 12) one feature's whitened Jacobian
    beta: np.ndarray  #: (12,) J^T R^-1 r


class OutlierWorkspace(NamedTuple):
    """Scratch of the outlier tests (avio/filter/outliers.py)."""

    Lp: np.ndarray  #: (12, 12) Cholesky factor of Sigma
    S: np.ndarray  #: (M, M, F) innovation covariances
    L: np.ndarray  #: (M, M, F) their factors
    y: np.ndarray  #: (M, F)
    Y: np.ndarray  #: (12, F) RANSAC corrections
    moved: np.ndarray  #: (F M, F) residuals moved by each hypothesis
    inlier: np.ndarray  #: (F, F) bool
    count: np.ndarray  #: (F,) int64


class MeasureWorkspace(NamedTuple):
    """Scratch of avio.filter.measurement.measure (G and D keep their zero pattern)."""

    R3: np.ndarray  #: (3, 3) exposure-time rotation of image 3
    p3: np.ndarray  #: (3,)
    Jsh: np.ndarray  #: (6, 15) its Jacobian (Eq. 19)
    Rc: np.ndarray  #: (3, 3, 3) camera rotations of images 1-3
    pc: np.ndarray  #: (3, 3) camera positions, m
    G: np.ndarray  #: (18, 27) camera pose errors <- state error
    M: np.ndarray  #: (6, 6)
    R12: np.ndarray  #: (3, 3)
    R13: np.ndarray  #: (3, 3)
    R23: np.ndarray  #: (3, 3)
    D: np.ndarray  #: (12, 18) camera pose errors -> relative-pose errors
    E: np.ndarray  #: (3, 3)
    uc: np.ndarray  #: (3, 2) a feature's corrected pixels (Eq. 35a), px
    uL: np.ndarray  #: (6 * LANES,) a block of features' pixels, px (trifocal.LANES; features last)
    fL: np.ndarray  #: (LANES,) int64: which feature each lane of a block of corrected pixels holds
    rL: np.ndarray  #: (4 * LANES,) their innovations, px
    JL: np.ndarray  #: (48 * LANES,) their Jacobians (4, 12) w.r.t. the relative-pose errors
    GL: np.ndarray  #: (24 * LANES,) their pixel sensitivities (4, 6)


class PropagateWorkspace(NamedTuple):
    """Scratch of avio.filter.propagation.propagate_one."""

    E: np.ndarray  #: (3, 3)
    RdR: np.ndarray  #: (3, 3)
    M: np.ndarray  #: (3, 3)
    dv: np.ndarray  #: (3,)
    dp: np.ndarray  #: (3,)
    sb: np.ndarray  #: (3,)
    Delta: np.ndarray  #: (3,)
    Pi: np.ndarray  #: (3,)


class ZeroVelocityWorkspace(NamedTuple):
    """Scratch of the zero-velocity update (avio.filter.kernels.zero_velocity_update_into)."""

    S: np.ndarray  #: (3, 3)
    Z: np.ndarray  #: (3, 28)
    dx: np.ndarray  #: (27,)
    K: np.ndarray  #: (27, 27)


class FrameWorkspace(NamedTuple):
    """Scratch of the frame loop (avio.filter.kernels.run_filters): one filter's state and the
    prediction, slide and divergence scratch (allocated once per run)."""

    omega: np.ndarray  #: (3,) gyro minus bias at the frame time, rad/s
    R: np.ndarray  #: (3, 3) the state at the last frame: R_world_imu
    p: np.ndarray  #: (3,) m
    v: np.ndarray  #: (3,) m/s
    ba: np.ndarray  #: (3,) m/s^2
    bg: np.ndarray  #: (3,) rad/s
    cp: np.ndarray  #: (2, 3) the clones' positions (frames k-2, k-1), m
    cR: np.ndarray  #: (2, 3, 3) their rotations
    P: np.ndarray  #: (27, 27) covariance
    R_new: np.ndarray  #: (3, 3) the predicted state
    v_new: np.ndarray  #: (3,)
    p_new: np.ndarray  #: (3,)
    Phi: np.ndarray  #: (15, 15) the interval's error transition
    E: np.ndarray  #: (3, 3)
    T3: np.ndarray  #: (3, 3)
    Tq: np.ndarray  #: (15, 27)
    U: np.ndarray  #: (15, 15)
    R3: np.ndarray  #: (3, 3) the exposure-time pose of the slide
    p3: np.ndarray  #: (3,)
    Jsh: np.ndarray  #: (6, 15) its Jacobian
    NR: np.ndarray  #: (6, 27) the new clone's covariance rows
    ba_s: np.ndarray  #: (3,) the biases before the frame (restored where it diverges)
    bg_s: np.ndarray  #: (3,)
    sig0: np.ndarray  #: (15,) the initial sigmas (reported after a divergence)
    no_record: np.ndarray  #: (F,) uint8, where the decisions are not recorded


class UpdateWorkspaces(NamedTuple):
    """Everything the trifocal update needs besides the state (nothing is allocated per frame)."""

    update: UpdateWorkspace
    measure: MeasureWorkspace
    noise: NoiseWorkspace
    outliers: OutlierWorkspace


class LaneStates(NamedTuple):
    """The filters of a lock-step block (avio/filter/lanes/block.py), lane l at index l: their
    states and what each keeps between the stages of a frame (L lanes)."""

    R: np.ndarray  #: (L, 3, 3) R_world_imu at the last frame
    p: np.ndarray  #: (L, 3) m
    v: np.ndarray  #: (L, 3) m/s
    ba: np.ndarray  #: (L, 3) m/s^2
    bg: np.ndarray  #: (L, 3) rad/s
    cp: np.ndarray  #: (L, 2, 3) the clones' positions (frames k-2, k-1), m
    cR: np.ndarray  #: (L, 2, 3, 3) their rotations
    R_new: np.ndarray  #: (L, 3, 3) the predicted state
    p_new: np.ndarray  #: (L, 3)
    v_new: np.ndarray  #: (L, 3)
    omega: np.ndarray  #: (L, 3) gyro minus bias at the frame time, rad/s
    ba_s: np.ndarray  #: (L, 3) the biases before the frame (restored where it diverges)
    bg_s: np.ndarray  #: (L, 3)
    active: np.ndarray  #: (L,) bool: the lane runs a filter that has not diverged
    k_stop: np.ndarray  #: (L,) int64: the frame its estimates stop at (N: none)
    counts: np.ndarray  #: (L, 3) int64: this frame's usable, valid and used features
    sums: np.ndarray  #: (L, 3): this frame's r^T R^-1 r, sum log det R_f over the inliers and NLL
    stats: np.ndarray  #: (L, 2): this frame's NIS and pose trace (Eqs. 44, 55b)


class LaneKeep(NamedTuple):
    """What each lane's update keeps from its measurement stage to its last (features last, as
    :class:`NoiseWorkspace`; L lanes)."""

    ok: np.ndarray  #: (L, F) bool usable features
    r: np.ndarray  #: (L, M, F) used residuals, px
    J: np.ndarray  #: (L, M, 12, F) their Jacobians
    Rm: np.ndarray  #: (L, M, M, F) covariances R_f, px^2
    sd: np.ndarray  #: (L, M, F) standard deviations, px
    Lm: np.ndarray  #: (L, M, M, F) Cholesky factors of R_f (upper triangle zero)
    ldR: np.ndarray  #: (L, F) log det R_f
    beta: np.ndarray  #: (L, 12) J^T R^-1 r


class DenseLanes(NamedTuple):
    """The dense phases' arrays of a lock-step block, lanes last (entry [a, b, l] of lane l), as
    the C of avio/filter/lanes/ takes them."""

    P: np.ndarray  #: (27, 27, L) covariances
    Phi: np.ndarray  #: (15, 15, L) the interval's error transitions
    T: np.ndarray  #: (15, 27, L) scratch of the prediction
    U: np.ndarray  #: (15, 15, L)
    C: np.ndarray  #: (12, 27, L) error state -> relative-pose errors
    CP: np.ndarray  #: (12, 27, L) C P
    PCt: np.ndarray  #: (27, 12, L) P C^T
    Sig: np.ndarray  #: (12, 12, L) Sigma = C P C^T
    Mx: np.ndarray  #: (12, 12, L) I + A Sigma, then its elimination
    X: np.ndarray  #: (12, 13, L) [A | beta], then (I + A Sigma)^-1 [A | beta]
    K: np.ndarray  #: (27, 12, L) gain rows
    ra: np.ndarray  #: (12 L,) the solve's pivot row
    rb: np.ndarray  #: (13 L,)
    dx: np.ndarray  #: (27, L) the updates' corrections (Eq. 41)
    J: np.ndarray  #: (6, 15, L) the slide's Jacobians of the new clones (Eq. 19)
    NR: np.ndarray  #: (6, 27, L) the new clones' covariance rows
    bad: np.ndarray  #: (L,) uint8: a non-finite covariance
