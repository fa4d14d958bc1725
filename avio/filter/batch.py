"""The batched sliding-window trifocal VIO: n error-state Kalman filters in lock-step.

The model (state, prediction, measurement, noise, outliers, update, standstill, slide,
divergence) is written out with numbered equations in docs/model.md; this module runs it.

One call of :func:`run` runs one filter per candidate calibration over the same IMU and feature
tracks. Every array carries the calibration axis first. The calibration-independent work (IMU
preintegration, feature selection, process noise, standstill flags) is numpy, once per sequence
(:func:`prepare`, avio/filter/prepare.py); the filters themselves run in compiled kernels that
loop over calibrations and frames: blocks of 2, 4 or 8 filters in lock-step, their dense phases in C
(avio/filter/lanes/: :func:`block_size`, :func:`set_block`), or one filter after the other
(avio/filter/kernels.py: run_filters) for a batch of one and where no C compiler is found. Per
filter and frame the work is a few 27x27 products and ~16 features, far too small for numpy's
per-call cost (pure numpy reached ~20 evaluations/s at batch 64, see benchmarks/bench_filter.py for
the kernel's). The batch is split over threads (:func:`set_threads`: blocks, or single
calibrations, taken as threads come free; the kernels release the GIL) and each filter is computed
by one thread with the same operations as alone, so a batch gives the same bits as single runs whatever its size and
the thread count; no fastmath, so results are deterministic. The first call of a process with a
cold numba cache compiles the kernel and says so on stderr (:data:`COMPILE_ESTIMATE_S`).

In short (docs/model.md): nominal state ``p_world_imu``, ``R_world_imu``, ``v_world_imu``,
``b_a``, ``b_g`` and two clones of the exposure-time IMU pose of frames k-2, k-1; a 27-dim
error state with local rotation errors (Eqs. 7-8); initial state from the ground truth at frame
0 (Eq. 9); RK4 preintegration with first-order bias corrections (Eqs. 12-18); time offset to
first order (Eq. 19); per triplet the 1-2 Sampson distance and the trifocal transfer
(Eqs. 20-33) with ``R_f = sigma^2 G G^T`` from the pixel noise (Eqs. 34-36), 1-point RANSAC and
a chi-square gate (Eqs. 37-39), the Kalman update in information form over the 12 relative-pose
errors (Eqs. 40-43) and its innovation statistics (Eqs. 44-46); zero-velocity updates when the
IMU and the images both say standing still (Eqs. 47-49); slide (Eq. 50); a diverged filter
(Eq. 51) is frozen at its last good frame, and :func:`avio.metrics.position_rmse_objective`
turns a divergence into a finite penalty (Eq. 52).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import replace

import numba
import numpy as np

from avio.calibration import Calibration
from avio.filter import kernels as _kernels
from avio.filter.config import CORRECTION_CAP_SIGMAS, FilterConfig, FilterError, FilterResult
from avio.filter.interface import Calibrations, Outputs, SequenceInputs, Settings
from avio.filter.lanes import block as _block
from avio.filter.lanes import native as _native
from avio.filter.prepare import _Prepared, prepare
from avio.filter.update import MODE_BOTH, MODE_GATE, MODE_NONE, MODE_RANSAC
from avio.sequence import Sequence

_THREADS: int | None = None  # set_threads(); None: the default rule
_BLOCK: int | None = None  # set_block(); None: the default rule


def default_threads() -> int:
    """Threads of the filter when :func:`set_threads` was not called: numba's NUMBA_NUM_THREADS,
    i.e. the machine's cores unless the environment sets it. joblib's loky workers (the Hydra
    joblib launcher) get ``NUMBA_NUM_THREADS = cores // n_jobs`` from joblib, so two workers on
    two cores run one thread each and do not oversubscribe; at most ``os.cpu_count()``."""
    return max(1, min(int(numba.config.NUMBA_NUM_THREADS), os.cpu_count() or 1))


def set_threads(n: int | None = None) -> int:
    """Threads :func:`run` splits a batch over (contiguous ranges of calibrations, each filter on
    one thread, so results do not depend on it); None restores :func:`default_threads`. Rule
    for launchers running several filter processes on one machine:
    ``threads = max(1, cores // processes)``. At most ``os.cpu_count()``; returns the count in
    effect."""
    global _THREADS
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
        raise FilterError(f"set_threads: n must be an integer >= 1 or None, got {n!r}")
    _THREADS = None if n is None else min(int(n), os.cpu_count() or 1)
    return threads()


def threads() -> int:
    """The filter kernel's thread count now (:func:`set_threads`)."""
    return _THREADS if _THREADS is not None else default_threads()


def set_block(n: int | None = None) -> int | None:
    """Filters per lock-step block (avio/filter/lanes/): 2, 4 or 8; 1 for numba's per-filter kernel (the
    fallback where no C compiler is found); None for the default rule (:func:`block_size`). Results do
    not depend on it. Returns the setting in effect."""
    global _BLOCK
    if n is not None and (isinstance(n, bool) or n not in (1, *_native.BLOCK_SIZES)):
        raise FilterError(f"set_block: n must be one of {(1, *_native.BLOCK_SIZES)} or None, got {n!r}")
    _BLOCK = None if n is None else int(n)
    return _BLOCK


def block_setting() -> int | str:
    """:func:`set_block`'s setting: 1, 2, 4, 8, or "auto"."""
    return "auto" if _BLOCK is None else _BLOCK


def block_size(n: int, n_threads: int) -> int:
    """The lock-step block size for a batch of n on n_threads: :func:`set_block`'s, else the largest
    of 8, 4 and 2 that every thread fills at least once (8 at batch 64 on 2 threads:
    benchmarks/README.md), else 2; 1 for a batch of one calibration: numba's per-filter kernel, faster
    than a block of 2 there (benchmarks/README.md), which also runs wherever the C kernel is
    unavailable (avio.filter.lanes.native.unavailable says why). So a process whose batches hold two
    calibrations or more loads (or first compiles) one kernel, not two."""
    if _BLOCK == 1 or _native.library() is None:
        return 1
    if _BLOCK is not None:
        return _BLOCK
    if n == 1:
        return 1
    per_thread = -(-n // n_threads)
    return next((L for L in (8, 4) if L <= per_thread), 2)


def block_plan(n: int, n_threads: int) -> list[tuple[int, int, int]]:
    """The lock-step blocks ``(lo, hi, L)`` of a batch of n on n_threads, in the order the threads take
    them; [] where :func:`block_size` is 1 (numba's per-filter kernel). With :func:`set_block`'s L:
    consecutive blocks of L. By default the batch is cut into n_threads near-equal contiguous shares,
    each in blocks of :func:`block_size` and its rest in one block of 2 (at most 2 left), 4 (3 or 4) or
    8, the shares' blocks interleaved so that each thread takes about one share: a batch of 20 (a
    default job's) on 2 threads runs 8 + 2 on each thread, where blocks of 8, 8 and 4-in-8 left one
    thread idle for the last (benchmarks/README.md)."""
    L = block_size(n, n_threads)
    if L == 1:
        return []
    if _BLOCK is not None:
        return [(lo, min(lo + L, n), L) for lo in range(0, n, L)]
    shares = []
    for t in range(n_threads):
        lo, hi = t * n // n_threads, (t + 1) * n // n_threads
        blocks = []
        while lo < hi:
            left = hi - lo
            size = L if left >= L or left > 4 else (2 if left <= 2 else 4)
            blocks.append((lo, min(lo + size, hi), size))
            lo += size
        shares.append(blocks)
    order = []
    for k in range(max(len(blocks) for blocks in shares)):
        order += [blocks[k] for blocks in shares if k < len(blocks)]
    return order


#: First-run compile time of the kernel, seconds, quoted in the message before a cold compile:
#: measured 50-57 s CPU on a 2-core AVX-512 machine (2026-12-05) and 68-101 s on a 2-core AVX2
#: one (2026-12-06; benchmarks/README.md, `python benchmarks/ab_kernel.py --compile-pairs`).
COMPILE_ESTIMATE_S = 80
_HEARTBEAT_S = 5.0  # seconds between the "still compiling" lines (issue 13: no silent phase over 10 s)
_kernel_loaded: set = set()  # the kernels (numba dispatchers) this process has compiled or loaded


def _kernel_cached(kernel) -> bool | None:
    """Whether numba's cache holds ``kernel`` (a numba dispatcher) for the current source (None: unknown)."""
    try:
        return bool(kernel._cache._cache_file._load_index())
    except AttributeError:  # numba's private cache API changed: cannot tell
        return None


@contextmanager
def _announce_compile(kernel):
    """Say so on stderr when the first kernel call of the process will compile ``kernel`` (a cold
    numba cache), print a heartbeat every 5 s while it does and how long it took."""
    loaded = kernel in _kernel_loaded
    cached = False if loaded else _kernel_cached(kernel)
    if loaded or cached:
        _kernel_loaded.add(kernel)
        yield
        return
    if cached is None:  # cannot tell: say something only if the call turns out to be long
        t0 = time.perf_counter()
        yield
        _kernel_loaded.add(kernel)
        if time.perf_counter() - t0 > 5.0:
            print(f"compiled or loaded the VIO filter in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return
    where = numba.config.CACHE_DIR or os.path.join(os.path.dirname(kernel.py_func.__code__.co_filename), "__pycache__")
    print(f"compiling the VIO filter (first run only, ~{COMPILE_ESTIMATE_S} s; cached in {where})",
          file=sys.stderr, flush=True)
    done = threading.Event()
    t0 = time.perf_counter()

    def heartbeat():
        while not done.wait(_HEARTBEAT_S):
            print(f"  still compiling the VIO filter ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)

    beat = threading.Thread(target=heartbeat, name="avio-compile-heartbeat", daemon=True)
    beat.start()
    try:
        yield
    finally:
        done.set()
        beat.join()
    _kernel_loaded.add(kernel)
    print(f"compiled the VIO filter in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


class _State:
    """Initial nominal states and covariances of n filters (docs/model.md, Eq. 9): truth pose and
    velocity of frame 0, biases from the sequence (zero when unknown), clones at the origin (they
    are set by the first slides), ``P0`` diagonal."""

    def __init__(self, sequence: Sequence, n: int, config: FilterConfig):
        tr = sequence.truth
        self.R = np.repeat(tr.R_world_imu[:1], n, axis=0).astype(float)
        self.p = np.repeat(tr.p_world_imu_m[:1], n, axis=0).astype(float)
        self.v = np.repeat(tr.v_world_imu_mps[:1], n, axis=0).astype(float)
        self.ba = np.repeat(_bias(sequence.initial_accel_bias_mps2)[None], n, axis=0)
        self.bg = np.repeat(_bias(sequence.initial_gyro_bias_radps)[None], n, axis=0)
        self.cp = np.zeros((2, n, 3))  # clones (k-2, k-1): exposure-time IMU positions
        self.cR = np.repeat(np.eye(3)[None, None], 2, 0).repeat(n, 1)
        # P0: Eq. (9), in the error-state order of Eq. (8).
        c = config
        d = np.r_[[c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3, [c.init_sigma_v_mps] * 3,
                  [c.init_sigma_ba_mps2] * 3, [c.init_sigma_bg_radps] * 3, [c.init_sigma_p_m] * 3,
                  [c.init_sigma_theta_rad] * 3, [c.init_sigma_p_m] * 3, [c.init_sigma_theta_rad] * 3]
        self.P0 = np.diag(d**2)
        self.P = np.repeat(self.P0[None], n, axis=0)

def _bias(value) -> np.ndarray:
    return np.zeros(3) if value is None else np.asarray(value, float).reshape(3)


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _calibrations(cal: Calibration) -> Calibrations:
    """The kernel's Calibrations; a calibration with non-finite values is diverged before it
    starts (frame 0; Eq. 51)."""
    n = len(cal)
    frozen = ~np.all(np.isfinite(np.concatenate(
        [np.stack([cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px, cal.time_offset_s], 1),
         cal.R_cam_imu.reshape(n, 9), cal.p_imu_cam_m], axis=1)), axis=1)
    return Calibrations(fx=_f64(cal.fx_px), fy=_f64(cal.fy_px), cx=_f64(cal.cx_px), cy=_f64(cal.cy_px),
                        R_cam_imu=_f64(cal.R_cam_imu), p_imu_cam_m=_f64(cal.p_imu_cam_m), td_s=_f64(cal.time_offset_s),
                        frozen=frozen)


def _sequence_inputs(sequence: Sequence, prep: _Prepared, config: FilterConfig) -> SequenceInputs:
    """The kernel's SequenceInputs: the initial state (Eq. 9) and the prepared per-frame inputs."""
    st, pre = _State(sequence, 1, config), prep.pre
    return SequenceInputs(R0=st.R[0], p0=st.p[0], v0=st.v[0], P0=st.P0, ba0=st.ba[0], bg0=st.bg[0],
                          g=_f64(sequence.gravity_world_mps2), dR=pre.dR, dv=pre.dv, dp=pre.dp, S=pre.S, SS=pre.SS,
                          Vbg=pre.Vbg, Pbg=pre.Pbg, T_s=_f64(pre.T_s), gyro_frame=_f64(pre.gyro_frame_radps),
                          Qd=prep.Qd, triplet_of_frame=prep.triplet_of_frame, uv=prep.uv_px, valid=prep.valid,
                          stationary=prep.stationary)


def _outputs(n: int, N: int, used_shape: tuple) -> Outputs:
    """The kernel's Outputs for n filters and N frames (used: (n, n_trip, F) or (0, ...); the
    update's linearisation record with the same leading size)."""
    def i64():
        return np.zeros((n, N), np.int64)

    return Outputs(p=np.empty((n, N, 3)), R=np.empty((n, N, 3, 3)), v=np.empty((n, N, 3)), sigma=np.empty((n, N, 15)),
                   ba=np.empty((n, N, 3)), bg=np.empty((n, N, 3)), n_updates=i64(), n_outliers=i64(),
                   diverged_at=np.empty(n, np.int64), nis=np.empty((n, N)), log_det_S=np.empty((n, N)),
                   pose_trace=np.empty((n, N)), dof=i64(),
                   nll=np.empty((n, N)), nll_slots=i64(), used=np.zeros(used_shape, np.uint8),
                   pose_cov=np.zeros((used_shape[0], N, 12, 12)), update_poses=np.zeros((used_shape[0], N, 3, 4, 3)))


_MODES = {"none": MODE_NONE, "ransac": MODE_RANSAC, "mahalanobis": MODE_GATE,
          "both": MODE_BOTH}


def _check_input(sequence: Sequence, cal: Calibration) -> None:
    n = len(cal)
    shapes = {"fx_px": (n,), "fy_px": (n,), "cx_px": (n,), "cy_px": (n,), "R_cam_imu": (n, 3, 3),
              "p_imu_cam_m": (n, 3), "time_offset_s": (n,)}
    for k, s in shapes.items():
        if getattr(cal, k).shape != s:
            raise FilterError(f"Calibration.{k} has shape {getattr(cal, k).shape}, expected {s}")
    if n == 0:
        raise FilterError("empty batch of calibrations")
    if sequence.n_frames < 3:
        raise FilterError(f"sequence {sequence.name!r} has {sequence.n_frames} frames, need >= 3")


def _imposed(sequence: Sequence, config: FilterConfig, prep: _Prepared) -> tuple[_Prepared, FilterConfig]:
    """outlier_decisions="reference": the inputs with only the features the reference's own
    updates used as candidates, and a config that rejects nothing itself (FilterConfig)."""
    if "valid" not in prep.imposed:
        if sequence.reference_calibration is None:
            raise FilterError(f"outlier_decisions={config.outlier_decisions!r}: sequence {sequence.name!r} has no "
                              "reference calibration")
        own = replace(config, outlier_decisions="own")
        ref = run(sequence, sequence.reference_calibration, own, prepared=prep, record_used=True)
        if ref.diverged[0]:  # its decisions would end there, and every filter's updates with them
            raise FilterError(f"outlier_decisions={config.outlier_decisions!r}: the filter at the reference "
                              f"calibration diverges on {sequence.name!r} at frame {int(ref.diverged_at_frame[0])}")
        prep.imposed["valid"] = prep.valid & ref.used[0]
    return replace(prep, valid=prep.imposed["valid"]), replace(config, outlier_rejection="none")


def run(sequence: Sequence, calibrations: Calibration, config: FilterConfig = FilterConfig(),
        prepared: _Prepared | None = None, record_used: bool = False) -> FilterResult:
    """Run one filter per calibration over ``sequence``, all in one compiled kernel call.

    sequence: IMU, frame times, ground truth (for the initial state only) and tracks.
    calibrations: batch of n candidate calibrations.
    prepared: output of :func:`prepare` for this (sequence, config), to reuse across calls.
    record_used: also return which features each update used (FilterResult.used) and what each
        update linearised about (FilterResult.pose_cov, update_poses).
    Returns a :class:`FilterResult` with (n, N, ...) estimates at the frames.
    """
    _check_input(sequence, calibrations)
    prep = prepared if prepared is not None else prepare(sequence, config)
    result_config = config
    # reference_all: the imposed features are used whatever their transfer gain and baseline
    # here (the reference judged both; R_f grows with the gain, so they fade, not jump).
    everything = config.outlier_decisions == "reference_all"
    gain_limit = np.inf if everything else float(config.max_transfer_gain)
    min_parallax_m = 0.0 if everything else config.min_parallax_m
    if config.outlier_decisions != "own":  # imposed from the reference
        prep, config = _imposed(sequence, config, prep)
    n, N = len(calibrations), sequence.n_frames
    c = config
    seq = _sequence_inputs(sequence, prep, c)
    cal = _calibrations(calibrations)
    settings = Settings(sigma_px=float(c.pixel_sigma_px), max_transfer_gain=gain_limit,
                        min_parallax_m=float(min_parallax_m), mode=_MODES[c.outlier_rejection],
                        ransac_threshold_sigma=float(c.ransac_threshold_sigma), chi2_threshold=c.chi2_threshold,
                        zero_velocity_sigma_mps=float(c.zero_velocity_sigma_mps),
                        max_variance=float(c.divergence_max_variance), max_speed_mps=float(c.divergence_max_speed_mps),
                        correction_cap_px=CORRECTION_CAP_SIGMAS * float(c.pixel_sigma_px)
                        if c.jacobian_pixels != "measured" else 0.0,
                        correct_noise_model=c.jacobian_pixels == "corrected")
    out = _outputs(n, N, (n if record_used else 0, *prep.valid.shape))
    # The kernel releases the GIL: the filters of the batch run on threads at once, each filter
    # on one thread (numba prange was tried: +41 s, +31 %, on the first compile). One task per
    # filter, taken as threads come free, since filters that diverge early stop early: on a
    # default job's batches four ranges per thread idled a thread for ~10 % of the time
    # (`python benchmarks/bench_filter.py schedule`); a kernel call costs ~12 us against ~12 ms.
    n_threads = min(threads(), n)
    blocks = block_plan(n, n_threads)
    if blocks:  # blocks of filters in lock-step (avio/filter/lanes/), one task each
        kernel = _block.run_block
        tasks = [(lo, hi, L, seq, cal, settings, out, _native.functions(L)) for lo, hi, L in blocks]
    else:  # numba's per-filter kernel, one task per filter
        kernel = _kernels.run_filters
        tasks = [(i, i + 1, seq, cal, settings, out) for i in range(n)] if n_threads > 1 else [(0, n, seq, cal,
                                                                                                settings, out)]
    # Degenerate geometry of a wild candidate gives non-finite intermediate values, which the
    # kernel tests for and drops; the floating-point warnings carry no information.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"), _announce_compile(kernel):
        if n_threads == 1:
            for task in tasks:
                kernel(*task)
        else:
            with ThreadPoolExecutor(n_threads, thread_name_prefix="avio-filter") as pool:
                for job in [pool.submit(kernel, *task) for task in tasks]:
                    job.result()
    o = out
    return FilterResult(o.p, o.R, o.v, o.diverged_at >= 0, o.diverged_at, o.n_updates, o.n_outliers, o.sigma, o.ba,
                        o.bg, o.nis, o.log_det_S, o.dof, o.nll, o.nll_slots,
                        used=o.used.astype(bool) if record_used else None,
                        pose_cov=o.pose_cov if record_used else None,
                        update_poses=o.update_poses if record_used else None,
                        pose_trace=o.pose_trace,
                        meta={"config": result_config})
