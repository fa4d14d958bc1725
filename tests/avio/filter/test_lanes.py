"""The lock-step blocks (avio/filter/lanes/): every block size gives the bits of numba's per-filter kernel
(lanes that diverge, partial blocks, recorded decisions); the block size and the C kernel's build are
chosen or refused with one message, and a failed build falls back to the per-filter kernel."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest
from test_batch import _candidates
from test_filter import make_circle_sequence

from avio.filter import FilterConfig, FilterError, prepare, run, set_threads
from avio.filter.batch import block_plan, block_size, set_block
from avio.filter.lanes import native

needs_c = pytest.mark.skipif(native.unavailable() is not None, reason=f"no C kernel: {native.unavailable()}")


@pytest.fixture(autouse=True)
def _restore():
    yield
    set_block(None)
    set_threads(None)


def _arrays(result) -> dict[str, np.ndarray]:
    return {f.name: getattr(result, f.name) for f in dataclasses.fields(result)
            if isinstance(getattr(result, f.name), np.ndarray)}


@needs_c
def test_every_block_size_gives_the_per_filter_kernels_bits():
    seq = make_circle_sequence(30, seed=5, pixel_noise_px=0.5, outlier_fraction=0.1)
    cfg = FilterConfig(divergence_max_speed_mps=7.02)  # some lanes diverge mid-run, the others go on
    prep = prepare(seq, cfg)
    cal = _candidates(seq.truth_calibration, 11, seed=2)  # 11: blocks of 2, 4 and 8 end part-empty
    set_threads(1)
    set_block(1)
    want = _arrays(run(seq, cal, cfg, prep, record_used=True))
    at = want["diverged_at_frame"]
    assert np.any(at > 0) and np.any(at < 0) and want["used"].any(), at
    for block in (*native.BLOCK_SIZES, None):  # None: the default plan (at 1 thread a block of 8, then one of 4)
        set_block(block)
        for n_threads in (1, 2):
            set_threads(n_threads)
            got = _arrays(run(seq, cal, cfg, prep, record_used=True))
            for name, a in want.items():
                assert a.tobytes() == got[name].tobytes(), f"block {block}, {n_threads} thread(s): {name} differs"


def test_the_block_size_is_one_of_its_values_or_one_message():
    for bad in (0, 3, 16, -1, True, 4.5, "8"):
        with pytest.raises(FilterError, match=r"set_block: n must be one of \(1, 2, 4, 8\) or None"):
            set_block(bad)
    assert set_block(4) == 4 and set_block(None) is None


@needs_c
def test_the_default_block_fills_every_thread():
    set_block(None)
    # a batch of one: numba's per-filter kernel; two or more: blocks, so one kernel serves them all
    assert [block_size(n, 2) for n in (1, 2, 3, 7, 8, 16, 64)] == [1, 2, 2, 4, 4, 8, 8]
    assert block_size(1, 1) == 1 and block_size(3, 1) == 2 and block_size(8, 1) == 8
    set_block(1)
    assert block_size(64, 2) == 1


@needs_c
@pytest.mark.parametrize("n", [2, 3, 4, 9, 11, 17, 20, 33, 64])
@pytest.mark.parametrize("n_threads", [1, 2])
def test_the_default_plan_covers_the_batch_once_in_equal_shares(n, n_threads):
    set_block(None)
    plan = block_plan(n, n_threads)
    assert sorted(i for lo, hi, _ in plan for i in range(lo, hi)) == list(range(n))
    assert all(0 < hi - lo <= L and L in native.BLOCK_SIZES for lo, hi, L in plan)
    assert all(hi - lo > 4 for lo, hi, L in plan if L == 8)  # a rest of at most 4 takes a block of 4 or 2
    assert all(hi - lo > 2 for lo, hi, L in plan if L == 4 and hi - lo < 4)  # a rest of 1 or 2: a block of 2
    # each thread's share (every n_threads-th block from its first) holds n / n_threads filters, +-1
    shares = [sum(hi - lo for lo, hi, _ in plan[t::n_threads]) for t in range(n_threads)]
    assert max(shares) - min(shares) <= 1 or n_threads == 1, plan
    set_block(8)
    assert block_plan(n, n_threads) == [(lo, min(lo + 8, n), 8) for lo in range(0, n, 8)]


def test_the_default_plan_of_a_default_jobs_batch():
    """psoga's batches of 20 on 2 threads: 8 + 2 on each thread, not 8, 8 and a block of 8 holding 4; the
    problem's two anchors (the reference and true calibrations) one on each thread, in the same kernel."""
    set_block(None)
    if native.unavailable() is not None:
        assert block_plan(20, 2) == block_plan(2, 2) == []
    else:
        assert block_plan(20, 2) == [(0, 8, 8), (10, 18, 8), (8, 10, 2), (18, 20, 2)]
        assert block_plan(2, 2) == [(0, 1, 2), (1, 2, 2)] and block_plan(1, 2) == []


def _fallback_run(env: dict) -> subprocess.CompletedProcess:
    code = ("import sys; sys.path[:0] = ['tests/avio/filter']\n"
            "from test_filter import make_circle_sequence\n"
            "from avio.filter import FilterConfig, run\n"
            "from avio.filter.batch import block_size\n"
            "from avio.filter.lanes import native\n"
            "from test_batch import _candidates\n"
            "seq = make_circle_sequence(12, seed=0)\n"
            "r = run(seq, _candidates(seq.truth_calibration, 4, seed=0), FilterConfig())\n"
            "print('block', block_size(64, 2), 'why', native.unavailable(), 'finite', bool(abs(r.p_world_imu_m).max() < 1e9))\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **env},
                          cwd=native.HERE.parents[2], timeout=600)


def test_a_failed_build_says_how_to_fall_back_and_the_filter_still_runs(tmp_path):
    done = _fallback_run({"CC": "false", "AVIO_NATIVE_CACHE": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    assert "block 1 why" in done.stdout and "finite True" in done.stdout
    assert "lock-step C kernel is not available" in done.stderr and "AVIO_NATIVE=0" in done.stderr
    assert done.stderr.count("is not available") == 1  # once per process
    assert not list(tmp_path.glob("*.so")), "a failed build left a library behind"
    quiet = _fallback_run({"AVIO_NATIVE": "0"})
    assert quiet.returncode == 0 and "block 1 why AVIO_NATIVE=0" in quiet.stdout
    assert "not available" not in quiet.stderr


@needs_c
def test_the_library_is_built_once_per_cache_and_loaded_after(tmp_path):
    env = {"AVIO_NATIVE_CACHE": str(tmp_path)}
    first = _fallback_run(env)
    assert first.returncode == 0 and "block 8 why None" in first.stdout, first.stderr
    assert "building the VIO filter's lock-step C kernel" in first.stderr
    assert len(list(tmp_path.glob("lanes-*.so"))) == 1
    again = _fallback_run(env)
    assert again.returncode == 0 and "building" not in again.stderr
