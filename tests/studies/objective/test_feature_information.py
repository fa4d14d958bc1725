"""studies/objective/feature_information.py: a feature's Gaussian model at the true poses passes the
information-matrix equality when its pixel noise is right, and a wrong noise level is caught."""

from __future__ import annotations

import numpy as np


def test_the_equality_holds_with_the_right_noise_and_fails_with_the_wrong_one(load_script):
    module = load_script("feature_information")
    right = module.measure(0.35, 0.3, draws=200, n_points=80)
    assert right["features"] > 40
    np.testing.assert_allclose(right["ratio"], 1.0, atol=0.1)
    assert abs(right["nis_per_dof"] - 1.0) < 0.05
    wrong = module.measure(0.35, 0.3, draws=200, n_points=80, data_sigma=0.7)  # the model says half the noise
    assert abs(wrong["nis_per_dof"] - 4.0) < 0.3
    assert np.all(wrong["ratio"] > 2.5)


def test_pure_forward_motion_leaves_f_undetermined(load_script):
    module = load_script("feature_information")
    m = module.measure(0.5, 0.0, draws=50, n_points=60)
    assert np.isnan(m["ratio"][0]) and np.all(np.isfinite(m["ratio"][1:]))
