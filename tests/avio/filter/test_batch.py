"""The threaded filter kernel (avio/filter/kernels.py: run_filters, a batch split over threads) gives
the same bits whatever the batch size and thread count: every FilterResult array, divergence
decisions and innovation statistics included (the same bits as a commit of the git history:
test_against_history.py)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from test_filter import make_circle_sequence

from avio.calibration import Calibration
from avio.filter import batch as avio_filter
from avio.filter.batch import run, set_threads, threads
from avio.filter.config import FilterConfig, FilterError
from avio.filter.prepare import prepare
from avio.geometry import so3_exp

FIELDS = ("p_world_imu_m", "R_world_imu", "v_world_imu_mps", "diverged", "diverged_at_frame", "n_updates",
          "n_outliers", "sigma", "b_a_mps2", "b_g_radps", "nis", "log_det_S", "dof", "nll", "nll_slots", "pose_trace")


def _candidates(cal: Calibration, n: int, seed: int) -> Calibration:
    """n perturbed calibrations around cal (one wild focal length, one non-finite)."""
    rng = np.random.default_rng(seed)
    c = cal.repeat(n)
    fx = c.fx_px + rng.normal(0, 5, n)
    fx[-1] *= 1.6
    fx[n // 2] = np.nan
    return Calibration(fx_px=fx, fy_px=c.fy_px + rng.normal(0, 5, n), cx_px=c.cx_px + rng.normal(0, 5, n),
                       cy_px=c.cy_px + rng.normal(0, 5, n),
                       R_cam_imu=so3_exp(rng.normal(0, 0.01, (n, 3))) @ c.R_cam_imu,
                       p_imu_cam_m=c.p_imu_cam_m + rng.normal(0, 0.05, (n, 3)),
                       time_offset_s=rng.normal(0, 0.003, n))


def _subset(cal: Calibration, idx) -> Calibration:
    return Calibration(*(np.asarray(getattr(cal, k))[idx] for k in (
        "fx_px", "fy_px", "cx_px", "cy_px", "R_cam_imu", "p_imu_cam_m", "time_offset_s")))


def _assert_same_bits(got, want, label: str) -> None:
    for f in FIELDS:
        a, b = np.ascontiguousarray(getattr(got, f)), np.ascontiguousarray(getattr(want, f))
        assert a.shape == b.shape and a.dtype == b.dtype, f"{label}: {f} {a.shape}/{a.dtype} vs {b.shape}/{b.dtype}"
        if a.tobytes() != b.tobytes():
            bad = np.argwhere(~((a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else a != b))
            pytest.fail(f"{label}: {f} differs at {len(bad)} entries, first {bad[:3].tolist()}")


@pytest.fixture(autouse=True)
def _restore_threads():
    yield
    set_threads(None)


def test_batch_size_and_thread_count_do_not_change_the_bits():
    seq = make_circle_sequence(40, seed=3, pixel_noise_px=0.5, outlier_fraction=0.1)
    # A speed limit just above the drive's 7.004 m/s: some calibrations diverge mid-run.
    cfg = FilterConfig(divergence_max_speed_mps=7.02)
    prep = prepare(seq, cfg)
    cal = _candidates(seq.truth_calibration, 7, seed=0)
    set_threads(1)
    serial = run(seq, cal, cfg, prep)
    at = serial.diverged_at_frame
    assert at[3] == 0 and np.any(at > 0) and np.any(at < 0), at  # frozen, mid-run and no divergence
    assert serial.n_updates.sum() > 0 and serial.n_outliers.sum() > 0
    assert np.ptp(serial.p_world_imu_m[:, -1, 0][at < 0]) > 0  # the calibrations do differ
    set_threads(2)
    assert threads() == min(2, avio_filter.default_threads())
    _assert_same_bits(run(seq, cal, cfg, prep), serial, "2 threads")
    for i in range(len(cal)):
        one = run(seq, _subset(cal, [i]), cfg, prep)
        for f in FIELDS:
            assert np.ascontiguousarray(getattr(one, f)[0]).tobytes() == \
                np.ascontiguousarray(getattr(serial, f)[i]).tobytes(), f"calibration {i} alone: {f}"
    order = [6, 0, 5, 1, 4, 2, 3]
    _assert_same_bits(run(seq, _subset(cal, order), cfg, prep), _subset_result(serial, order), "reordered batch")


def _subset_result(res, idx):
    return type("R", (), {f: getattr(res, f)[idx] for f in FIELDS})


def test_set_threads_refuses_bad_counts():
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(FilterError, match="set_threads"):
            set_threads(bad)
    assert set_threads(10**6) == os.cpu_count()  # more threads than cores only costs
    assert set_threads(None) == avio_filter.default_threads()


def test_a_cold_compile_is_announced_with_a_heartbeat_and_its_duration(monkeypatch, capsys):
    import time

    kernel = avio_filter._kernels.run_filters
    monkeypatch.setattr(avio_filter, "_kernel_loaded", set())
    monkeypatch.setattr(avio_filter, "_kernel_cached", lambda k: False)
    monkeypatch.setattr(avio_filter, "_HEARTBEAT_S", 0.02)
    with avio_filter._announce_compile(kernel):
        time.sleep(0.1)
    err = capsys.readouterr().err
    assert f"compiling the VIO filter (first run only, ~{avio_filter.COMPILE_ESTIMATE_S} s" in err
    assert "still compiling the VIO filter" in err
    assert "compiled the VIO filter in" in err
    # Once loaded (or with a warm cache), nothing is printed.
    with avio_filter._announce_compile(kernel):
        pass
    monkeypatch.setattr(avio_filter, "_kernel_loaded", set())
    monkeypatch.setattr(avio_filter, "_kernel_cached", lambda k: True)
    with avio_filter._announce_compile(kernel):
        pass
    assert capsys.readouterr().err == ""
    # Each kernel is announced on its own: the lock-step one after the per-filter one was loaded.
    monkeypatch.setattr(avio_filter, "_kernel_cached", lambda k: False)
    with avio_filter._announce_compile(avio_filter._block.run_block):
        pass
    assert "compiling the VIO filter" in capsys.readouterr().err


def test_the_kernel_cache_is_recognised_once_compiled():
    seq = make_circle_sequence(8, seed=0)
    run(seq, seq.truth_calibration, FilterConfig())
    assert avio_filter._kernel_cached(avio_filter._kernels.run_filters) is True  # a batch of 1: the per-filter kernel


def test_joblib_workers_default_to_cores_over_workers():
    """The rule that keeps two joblib workers on two cores from oversubscribing: loky sets
    NUMBA_NUM_THREADS = cores // n_jobs in its workers and the filter's default follows it."""
    from joblib import Parallel, delayed

    got = Parallel(n_jobs=2)(delayed(avio_filter.default_threads)() for _ in range(2))
    assert got == [max(1, os.cpu_count() // 2)] * 2
