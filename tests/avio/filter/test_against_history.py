"""Today's filter gives, to the bit, every output of the filter of a pinned commit taken from the
git history (tests/avio/filter/git_reference.py): numba's per-filter kernel and the lock-step blocks of
2, 4 and 8 filters (avio/filter/lanes/), at batch sizes 1, 3 and 8 and 1 or 2 threads, for every
outlier mode, on a short simulated drive (and on kitti00 15-796 with the real data).

The reference is frozen: the whole avio package of that commit, imported under a private name,
kernel, preparation and geometry included (the 799-line copy of the 958a2e6 kernel this replaces
imported live modules, so it froze nothing). Compared: every array field of the reference's
FilterResult (fields added later are not in it; move the commit forward to guard them too)."""

from __future__ import annotations

import dataclasses
import importlib
import time

import git_reference
import numpy as np
import pytest
from test_batch import _candidates, _subset
from test_filter import make_circle_sequence

from avio.calibration import Calibration
from avio.filter import FilterConfig, prepare, run, set_threads
from avio.filter.batch import set_block
from avio.filter.lanes import native

#: The commit whose filter today's must equal bit for bit (full sha; ``git log -1 --format=%H``).
#: Move it forward only to a commit whose outputs were checked equal to the previous pin's, or
#: that changed the numbers on purpose (and said so): the kernel restructure of issue 30 pins it to
#: the commit that added the joint likelihood's outputs (issue 33). Only this commit's layout
#: (avio/filter/ a package exporting run, prepare, set_threads, FilterConfig) needs to load.
REFERENCE_COMMIT = "888043f4451513dd84ada7c9d63d7e0d8ccf9930"


@pytest.fixture(scope="module")
def ref():
    """The avio package of REFERENCE_COMMIT, its kernel compiled (or loaded from its cache) once."""
    why = git_reference.unavailable(REFERENCE_COMMIT)
    if why:
        pytest.skip(f"bit-identity guard against {REFERENCE_COMMIT[:12]} skipped: {why}")
    t = time.process_time()
    pkg = compiled_reference()
    print(f"reference {REFERENCE_COMMIT[:12]}: kernel compiled or loaded in {time.process_time() - t:.1f} s CPU")
    yield pkg
    importlib.import_module(f"{pkg.__name__}.filter").set_threads(None)
    set_threads(None)
    set_block(None)


def compiled_reference():
    """The avio package of REFERENCE_COMMIT with its kernel compiled (or loaded from numba's cache) by one
    short run; tests/conftest.py calls it too, before the xdist workers start."""
    pkg = git_reference.load(REFERENCE_COMMIT)
    filt = importlib.import_module(f"{pkg.__name__}.filter")
    seq = make_circle_sequence(8, seed=0)
    filt.run(seq, _frozen_cal(pkg, seq.truth_calibration), filt.FilterConfig())
    return pkg


def _frozen_cal(pkg, cal: Calibration):
    """``cal`` as the reference package's Calibration."""
    mod = importlib.import_module(f"{pkg.__name__}.calibration")
    return mod.Calibration(*(np.asarray(getattr(cal, k)) for k in _CAL_FIELDS))


_CAL_FIELDS = ("fx_px", "fy_px", "cx_px", "cy_px", "R_cam_imu", "p_imu_cam_m", "time_offset_s")


def _arrays(result) -> dict[str, np.ndarray]:
    """Every array field of a FilterResult (meta and absent outputs left out)."""
    return {f.name: np.asarray(getattr(result, f.name)) for f in dataclasses.fields(result)
            if isinstance(getattr(result, f.name), np.ndarray)}


def _assert_same_bits(got, want: dict[str, np.ndarray], idx, label: str) -> None:
    """Every array of the reference (rows ``idx``) equals today's to the bit."""
    have = _arrays(got)
    for f, full in want.items():
        assert f in have, f"{label}: today's result lacks the reference's {f}"
        a, b = np.ascontiguousarray(have[f]), np.ascontiguousarray(full[idx])
        assert a.shape == b.shape and a.dtype == b.dtype, f"{label}: {f} {a.shape}/{a.dtype} vs {b.shape}/{b.dtype}"
        if a.tobytes() != b.tobytes():
            bad = np.argwhere(~((a == b) | (np.isnan(a) & np.isnan(b))) if a.dtype.kind == "f" else a != b)
            pytest.fail(f"{label}: {f} differs from {REFERENCE_COMMIT[:12]} at {len(bad)} entries, first {bad[:3].tolist()}")


def _reference(ref, seq, cal, record_used=False, **config):
    """The reference's outputs for the batch ``cal`` (one call, one thread)."""
    filt = importlib.import_module(f"{ref.__name__}.filter")
    filt.set_threads(1)
    cfg = filt.FilterConfig(**config)
    return _arrays(filt.run(seq, _frozen_cal(ref, cal), cfg, filt.prepare(seq, cfg), record_used=record_used))


#: The kernels compared: numba's per-filter one (1) and the lock-step blocks of the C (avio/filter/lanes/).
BLOCKS = [1, *(pytest.param(L, marks=pytest.mark.skipif(native.unavailable() is not None, reason=f"no C kernel: "
                                                         f"{native.unavailable()}")) for L in native.BLOCK_SIZES)]


@pytest.mark.parametrize("block", BLOCKS)
def test_same_bits_as_the_reference_commit_at_every_batch_size_and_thread_count(ref, block):
    seq = make_circle_sequence(40, seed=3, pixel_noise_px=0.5, outlier_fraction=0.1)
    # A speed limit just above the drive's 7.004 m/s: some calibrations diverge mid-run.
    config = {"divergence_max_speed_mps": 7.02}
    cal = _candidates(seq.truth_calibration, 8, seed=0)
    want = _reference(ref, seq, cal, record_used=True, **config)
    at = want["diverged_at_frame"]
    assert at[4] == 0 and np.any(at > 0) and np.any(at < 0), at  # frozen, mid-run and no divergence
    assert want["n_updates"].sum() > 0 and want["n_outliers"].sum() > 0 and want["used"].any()
    cfg = FilterConfig(**config)
    prep = prepare(seq, cfg)
    batches = {1: [7], 3: [6, 0, 4], 8: list(range(8))}  # the wild one alone; a reordered three; all
    set_block(block)  # a block of 4 or 8 runs the batch of 3 in one partly empty block, 2 in two
    for n_threads in (1, 2):
        set_threads(n_threads)
        for size, idx in batches.items():
            got = run(seq, _subset(cal, idx), cfg, prep, record_used=True)
            _assert_same_bits(got, want, idx, f"block {block}, batch {size}, {n_threads} thread(s)")


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["both", "none", "ransac", "mahalanobis"])
def test_same_bits_as_the_reference_commit_in_every_outlier_mode(ref, mode):
    seq = make_circle_sequence(60, seed=1, pixel_noise_px=0.5, outlier_fraction=0.1)
    cal = _candidates(seq.truth_calibration, 8, seed=7)
    config = {"outlier_rejection": mode, "divergence_max_speed_mps": 7.02}
    want = _reference(ref, seq, cal, **config)
    set_threads(2)
    cfg = FilterConfig(**config)
    for block in (1, None):  # numba's per-filter kernel; the default blocks (4 on 2 threads)
        set_block(block)
        _assert_same_bits(run(seq, cal, cfg, prepare(seq, cfg)), want, slice(None), f"circle, {mode}, block {block}")


@pytest.mark.slow
@pytest.mark.data
def test_same_bits_as_the_reference_commit_on_kitti00(ref, shared_data):
    from avio.datasets.kitti00 import load_kitti00

    seq = load_kitti00(shared_data / "kitti00", 15, 796, seed=0)
    cal = _candidates(seq.truth_calibration, 6, seed=7)
    # The default thresholds and a variance limit that makes every filter diverge mid-run.
    for config in ({}, {"divergence_max_variance": 25.0}):
        want = _reference(ref, seq, cal, **config)
        set_threads(2)
        cfg = FilterConfig(**config)
        for block in (1, None):
            set_block(block)
            got = run(seq, cal, cfg, prepare(seq, cfg))
            _assert_same_bits(got, want, slice(None), f"kitti00 15-796, {config}, block {block}")
    assert np.all(got.diverged_at_frame > 0) | np.isnan(cal.fx_px).any()


def test_the_guard_sees_a_change_of_one_ulp_in_one_input(ref):
    """The comparison is not vacuous: one calibration's focal length moved by one ulp changes bits."""
    seq = make_circle_sequence(20, seed=3, pixel_noise_px=0.5)
    cal = _candidates(seq.truth_calibration, 3, seed=0)
    want = _reference(ref, seq, cal)
    moved = _subset(cal, [0, 1, 2])
    moved.fx_px[0] = np.nextafter(moved.fx_px[0], np.inf)
    with pytest.raises(pytest.fail.Exception, match="differs from"):
        _assert_same_bits(run(seq, moved, FilterConfig()), want, slice(None), "one ulp")


def test_the_reference_imports_only_itself(ref):
    """Frozen means frozen: no module of the copy imports the live avio."""
    import re
    from pathlib import Path

    pkg = Path(ref.__file__).parent
    sources = {p.relative_to(pkg).as_posix(): p.read_text() for p in pkg.rglob("*.py")}
    assert "filter/kernels.py" in sources and "filter/update.py" in sources
    for name, text in sources.items():
        assert not re.search(r"^\s*(from|import) avio\b", text, re.MULTILINE), name
    assert importlib.import_module(f"{ref.__name__}.filter.kernels").__file__.startswith(str(pkg))


def test_a_commit_missing_from_the_history_is_a_reason_to_skip():
    if git_reference.unavailable("HEAD") is not None:
        pytest.skip(git_reference.unavailable("HEAD"))
    why = git_reference.unavailable("0" * 40)
    assert why is not None and "not in this checkout's history" in why and "shallow" in why
