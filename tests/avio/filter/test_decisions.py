"""FilterConfig.outlier_decisions: the updates' decisions taken from a filter at the reference
calibration and imposed on every filter of the batch, so that they do not jump with the
calibration (studies/identifiability/README.md: "Where the runs end instead")."""

from __future__ import annotations

import numpy as np
import pytest
from test_batch import FIELDS, _candidates
from test_filter import make_circle_sequence

from avio.calibration import Calibration
from avio.filter.batch import run, set_threads
from avio.filter.config import FilterConfig, FilterError
from avio.filter.prepare import prepare

POSE = ("p_world_imu_m", "R_world_imu", "v_world_imu_mps", "sigma", "b_a_mps2", "b_g_radps", "n_updates")


@pytest.fixture(scope="module")
def drive():
    seq = make_circle_sequence(60, seed=3, pixel_noise_px=0.5, outlier_fraction=0.1)
    return seq, FilterConfig(max_update_features=20)


def test_the_recorded_decisions_are_the_features_each_update_used(drive):
    seq, cfg = drive
    prep = prepare(seq, cfg)
    res = run(seq, _candidates(seq.reference_calibration, 5, seed=0), cfg, prep, record_used=True)
    assert res.used.shape == (5, *prep.valid.shape) and not (res.used & ~prep.valid).any()
    np.testing.assert_array_equal(res.used.sum(axis=(1, 2)), res.n_updates.sum(axis=1))
    assert (res.n_outliers.sum() > 0) and run(seq, seq.reference_calibration, cfg, prep).used is None


def test_the_record_holds_each_updates_linearisation_and_changes_nothing_else(drive):
    seq, cfg = drive
    prep = prepare(seq, cfg)
    cal = _candidates(seq.reference_calibration, 3, seed=2)
    cal = Calibration(**{**cal.__dict__, "time_offset_s": np.zeros(3)})  # clones at the frame times
    plain = run(seq, cal, cfg, prep)
    rec = run(seq, cal, cfg, prep, record_used=True)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(rec, name), getattr(plain, name), err_msg=name)
    assert plain.pose_cov is None and plain.update_poses is None
    n, N = rec.n_updates.shape
    assert rec.pose_cov.shape == (n, N, 12, 12) and rec.update_poses.shape == (n, N, 3, 4, 3)
    updated = rec.dof > 0
    # Sigma = C P C^T: symmetric positive definite where an update ran, zero elsewhere
    Sig = rec.pose_cov[updated]
    np.testing.assert_array_equal(Sig, np.swapaxes(Sig, 1, 2))
    assert np.all(np.linalg.eigvalsh(Sig) > 0) and not rec.pose_cov[~updated].any()
    # the clone of frame k-1 is that frame's estimate, copied at the slide (no time offset)
    i, k = np.nonzero(updated)
    np.testing.assert_array_equal(rec.update_poses[i, k, 1, :3], rec.R_world_imu[i, k - 1])
    np.testing.assert_array_equal(rec.update_poses[i, k, 1, 3], rec.p_world_imu_m[i, k - 1])


@pytest.mark.parametrize("source", ["reference", "reference_all"])
def test_at_the_reference_imposed_decisions_give_the_filters_own_estimates_bit_for_bit(drive, source):
    seq, cfg = drive
    own = run(seq, seq.reference_calibration, cfg)
    imposed = run(seq, seq.reference_calibration, FilterConfig(max_update_features=20, outlier_decisions=source))
    for name in POSE:
        np.testing.assert_array_equal(getattr(imposed, name), getattr(own, name), err_msg=name)
    assert own.n_outliers.sum() > 0 and imposed.n_outliers.sum() == 0  # nothing left to reject


@pytest.mark.parametrize("source", ["reference", "reference_all"])
def test_imposed_decisions_are_the_same_candidates_for_the_whole_batch_and_a_batch_is_single_runs(drive, source):
    seq, _ = drive
    cfg = FilterConfig(max_update_features=20, outlier_decisions=source)
    prep = prepare(seq, cfg)
    cal = _candidates(seq.reference_calibration, 6, seed=1)
    set_threads(2)
    batch = run(seq, cal, cfg, prep, record_used=True)
    imposed = prep.imposed["valid"]
    assert not (batch.used & ~imposed).any()  # every filter chose among the reference's features only
    assert batch.n_outliers.sum() == 0
    set_threads(1)
    for i in range(len(cal)):
        one = run(seq, Calibration(*(np.asarray(getattr(cal, k))[[i]] for k in Calibration.__dataclass_fields__)),
                  cfg, prep)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(one, name)[0], getattr(batch, name)[i], err_msg=name)


def test_with_reference_all_every_filter_uses_every_imposed_feature_whatever_its_gain_and_baseline(drive):
    seq, _ = drive
    cal = _candidates(seq.reference_calibration, 6, seed=2)
    strict = FilterConfig(max_update_features=20, outlier_decisions="reference", max_transfer_gain=2.0)
    res = run(seq, cal, strict, record_used=True)
    imposed = prepare(seq, strict)
    run(seq, seq.reference_calibration, strict, imposed)  # makes the imposed features
    assert (res.used[~res.diverged] != imposed.imposed["valid"]).any()  # a strict gain check drops some per filter
    every = FilterConfig(max_update_features=20, outlier_decisions="reference_all", max_transfer_gain=2.0)
    prep = prepare(seq, every)
    res = run(seq, cal, every, prep, record_used=True)
    going = ~res.diverged  # a diverged filter records no decisions from its divergence on
    assert going.sum() >= 4
    np.testing.assert_array_equal(res.used[going], np.broadcast_to(prep.imposed["valid"], res.used[going].shape))


def test_an_unknown_decision_source_is_a_clear_error():
    with pytest.raises(FilterError, match="outlier_decisions must be one of"):
        FilterConfig(outlier_decisions="mine")


def test_imposed_decisions_need_a_reference_calibration(drive):
    from dataclasses import replace

    seq, _ = drive
    cfg = FilterConfig(max_update_features=20, outlier_decisions="reference")
    with pytest.raises(FilterError, match="has no reference calibration"):
        run(replace(seq, reference_calibration=None), seq.reference_calibration, cfg)
