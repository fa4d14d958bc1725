"""studies/objective/likelihood_tilt.py: the likelihood's slope at the truth, split into its parts (and, with
--terms, each update's score into its terms)."""

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


def test_the_terms_add_up_to_the_kernels_score_and_the_blocks_to_the_pose_errors_share(load_script):
    module = load_script("likelihood_tilt")
    t = module.drive_terms(0, 0, "fy", {}, {}, every=40)
    assert t is not None and t["check"] < 1e-8
    # A + B + C is the total derivative to first order in the step (cross terms are O(h^2))
    parts = t["A"] + t["B"] + t["C"]
    scale = abs(t["A"]) + abs(t["B"]) + abs(t["C"])
    assert abs(parts - t["kernel_total"]) < 0.05 * scale
    assert abs(t["C_direct"] + t["C_reach"] - t["C"]) < 0.05 * scale
    # the residuals are linear enough in the pose error that its blocks' shares add up
    blocks = sum(t[f"C_direct_error_{b}"] - t["C_direct_true_poses"] for b in module.BLOCKS)
    assert np.isclose(blocks, t["C_direct"] - t["C_direct_true_poses"], rtol=0.2, atol=0.02 * scale)


def test_an_extrinsic_moves_the_poses_only_and_the_prediction_is_the_filters_own(load_script):
    module = load_script("likelihood_tilt")
    t = module.drive_terms(0, 0, "rx", {}, {}, every=40)
    assert t["check"] < 1e-8 and t["C_direct"] == 0.0
    assert abs(t["C_reach"] - t["C"]) < 0.05 * (abs(t["A"]) + abs(t["B"]) + abs(t["C"]))
    p = module.drive_terms(0, 0, "fy", {}, {}, every=40, predict=True)
    # tr(M^T S^-1 J Sigma) > 0 along fy: fy scales the pixels a pose error moves (J grows with fy)
    assert p["C_direct_predicted"] > 0 and np.isfinite(p["adjustment"]) and p["adjustment"] < 0
