"""studies/objective/information_equality.py: the information-matrix ratio of a correct model is 1,
of an overdispersed one its dispersion; atypical drives are told apart."""

from __future__ import annotations

import numpy as np


def test_the_ratio_is_one_for_a_correct_model_and_the_dispersion_for_an_overdispersed_one(load_script):
    module = load_script("information_equality")
    rng = np.random.default_rng(0)
    p, D = 3, 4000
    B = rng.standard_normal((p, p))
    H = B @ B.T + np.eye(p)  # each drive's Hessian: the Fisher information
    g = rng.multivariate_normal(np.zeros(p), H, size=D)  # score covariance = information
    Hs = np.repeat(H[None], D, axis=0)
    ratio, top = module.equality(g, Hs)
    assert abs(ratio - 1.0) < 0.05 and abs(top - 1.0) < 0.1
    ratio3, _ = module.equality(np.sqrt(3.0) * g, Hs)
    assert abs(ratio3 - 3.0) < 0.15


def test_drives_with_wild_curvatures_are_not_typical(load_script):
    module = load_script("information_equality")
    rng = np.random.default_rng(1)
    H = np.repeat(np.eye(2)[None], 30, axis=0) * rng.uniform(0.9, 1.1, (30, 1, 1))
    H[3, 0, 0] = 40.0
    H[7, 1, 1] = -5.0
    keep = module.typical(H)
    assert not keep[3] and not keep[7] and keep.sum() == 28


def test_a_tilt_hidden_by_a_few_rough_drives_is_found_and_no_tilt_is_not_declared(load_script):
    # the corrected likelihood's fy (docs/decisions.md): every typical drive leans one way, a few
    # drives' scores are 100x the others' and swamp the t over all drives
    module = load_script("information_equality")
    rng = np.random.default_rng(2)
    D = 100
    lean = 0.09 + 0.06 * rng.standard_normal(D)
    lean[[5, 40]] = [-45.0, 30.0]  # two rough drives
    null = 0.06 * rng.standard_normal(D)
    null[[5, 40]] = [-45.0, 30.0]
    keep = np.ones(D, bool)
    keep[[5, 40]] = False
    s = module.tilt(np.stack([lean, null], axis=1), keep)
    assert abs(s["t_all"][0]) < 3  # the plain t misses it
    assert s["t_typical"][0] > 8 and s["p_wilcoxon"][0] < 1e-6  # both robust tests find it
    assert abs(s["t_typical"][1]) < 3 and s["p_wilcoxon"][1] > 0.01  # and neither invents one
    line = module.tilt_line(np.stack([lean, null], axis=1), keep, ("fy", "cx"))
    assert line.startswith("mean drive score at the truth") and "fy " in line and "cx " in line


def test_profile_follows_one_drive_along_one_variable(load_script):
    module = load_script("information_equality")
    lines = module.profile(0, 0, "fx", n=3, worst=2)
    assert lines[0].startswith("paper_540m, camera 0, fresh drive 0") and len(lines) == 4
    total = [float(v) for v in lines[1].removeprefix("total: ").split(", ")]
    # the truth's own terms are the reference; a 1.5 px step moves a smooth drive's NLL by nats, not 10^5
    assert total[1] == 0.0 and all(0.0 < abs(v) < 20.0 for v in (total[0], total[2]))


def test_profile_refuses_an_unknown_variable(load_script, capsys):
    module = load_script("information_equality")
    try:
        module.main(["--profile", "0", "0", "zz"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "VAR must be one of fx" in capsys.readouterr().err


def test_the_corrected_pixels_likelihood_stays_smooth_where_the_uncapped_step_broke_it(load_script):
    # camera 2, fresh drive 1: with the first-order step uncapped (before Eq. 35b) this drive's NLL
    # rose by 6e5 nats at cy + 1.5 px (frame 49); capped, it moves by nats, as with the measured pixels
    module = load_script("information_equality")
    lines = module.profile(2, 1, "cy", filter_options={"jacobian_pixels": "corrected"}, n=3, worst=1)
    total = [float(v) for v in lines[1].removeprefix("total: ").split(", ")]
    assert max(abs(v) for v in total) < 20.0


def test_the_flat_citys_seven_free_variables_hold_dy_dz_at_the_truth_when_they_are_measured_too(load_script):
    module = load_script("information_equality")
    eight = module.free_map(module.DRIVE, module.rig_vars(module.DRIVE))
    ten = module.free_map(module.DRIVE, module.rig_vars(module.DRIVE, all_ten=True))
    assert module.rig_vars(module.DRIVE, all_ten=True) == module.VARS10 and ten.shape == (10, 7)
    np.testing.assert_array_equal(ten[:8], eight)  # the 7 free variables' rows unchanged
    np.testing.assert_array_equal(ten[8:], 0.0)  # dy, dz held at the truth
    np.testing.assert_array_equal(module.free_map("full3d_540m", module.VARS10), np.eye(10))
