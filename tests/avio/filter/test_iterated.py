"""The iterated trifocal update (avio/filter/iterated.py, FilterConfig.update_iterations): the first
pass's innovation statistics, a batch equal to single runs, the predicted state's first update
re-linearised, bad settings refused."""

from __future__ import annotations

import numpy as np
import pytest
from test_batch import FIELDS, _candidates
from test_filter import make_circle_sequence

from avio.calibration import Calibration
from avio.filter.batch import run, set_threads
from avio.filter.config import FilterConfig, FilterError
from avio.filter.prepare import prepare


@pytest.fixture(scope="module")
def drive():
    return make_circle_sequence(40, seed=3, pixel_noise_px=0.7)


@pytest.mark.parametrize("bad", [0, 11, 2.0, True, "2"])
def test_a_bad_iteration_count_is_refused_naming_the_key(bad):
    with pytest.raises(FilterError, match="update_iterations"):
        FilterConfig(update_iterations=bad)


def test_the_first_update_scores_the_same_prediction_and_corrects_it_otherwise(drive):
    plain, iterated = (run(drive, drive.truth_calibration, FilterConfig(update_iterations=n)) for n in (1, 3))
    k = int(np.argmax(plain.dof[0] > 0))  # the first update: the same predicted state in both
    assert k >= 2
    for name in ("nis", "log_det_S", "dof", "nll", "n_updates"):
        assert getattr(plain, name)[0, k] == getattr(iterated, name)[0, k], name
    assert not np.array_equal(plain.R_world_imu[0, k], iterated.R_world_imu[0, k])
    # the re-linearisation moves the estimate by a second-order amount: far less than the update itself
    moved = np.abs(iterated.p_world_imu_m[0, k] - plain.p_world_imu_m[0, k]).max()
    assert 0 < moved < 1e-3
    # and the whole drive stays on the truth as the plain filter does
    err = [np.linalg.norm(r.p_world_imu_m[0] - drive.truth.p_world_imu_m, axis=-1).max() for r in (plain, iterated)]
    assert err[1] < 2 * err[0] + 0.05, err


def test_an_iterated_batch_equals_single_runs_on_any_thread_count(drive):
    cfg = FilterConfig(update_iterations=3)
    prep = prepare(drive, cfg)
    cal = _candidates(drive.reference_calibration, 5, seed=4)
    set_threads(2)
    batch = run(drive, cal, cfg, prep)
    set_threads(1)
    for i in range(len(cal)):
        one = run(drive, Calibration(*(np.asarray(getattr(cal, k))[[i]] for k in Calibration.__dataclass_fields__)),
                  cfg, prep)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(one, name)[0], getattr(batch, name)[i], err_msg=f"{name} of {i}")
