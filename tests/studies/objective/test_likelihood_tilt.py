"""studies/objective/likelihood_tilt.py: the likelihood's slope at the truth, split into its parts."""

from __future__ import annotations

import numpy as np


def test_the_joint_slope_is_its_two_parts_and_on_perfect_data_only_log_det_moves(load_script):
    module = load_script("likelihood_tilt")
    r = module.slopes("none", 1, "fy", 0.5, None, seeds=[0])
    assert np.allclose(r["joint"], r["joint_nis"] + r["joint_ldS"], rtol=1e-9, atol=1e-15)
    assert r["used"][0] == 0  # the step changes no decision of the update on perfect data
    assert abs(r["joint_nis"][0]) < 1e-2 * abs(r["joint_ldS"][0])  # no residuals to speak of
    assert np.isfinite(r["composite"][0])


def test_imu_scale_multiplies_every_density(load_script):
    module = load_script("likelihood_tilt")
    base, twice = module.ImuNoise(), module.scaled_imu_noise(2.0)
    for name in ("accel_noise", "gyro_noise", "accel_bias_walk", "gyro_bias_walk"):
        assert getattr(twice, name) == 2.0 * getattr(base, name)
