"""studies/identifiability/cramer_rao.py: the Cramér–Rao bound from per-drive Hessians, on a
linear-Gaussian toy whose bound is known, sigma^2 (B^T B)^-1, and which least squares attains."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest


def _toy(rng, n_obs=40, p=3, sigma=0.5):
    B = rng.standard_normal((n_obs, p))
    x_true = np.array([1.0, -2.0, 0.5])
    return B, x_true, sigma


def test_the_bound_of_a_linear_gaussian_model_is_its_known_one_and_least_squares_attains_it(load_script):
    module = load_script("cramer_rao")
    design = load_script("minimiser_scatter")
    rng = np.random.default_rng(0)
    B, x_true, sigma = _toy(rng)
    h = np.array([0.1, 0.2, 0.05])
    offsets = design.design(3, h)
    hessians, scores, estimates = [], [], []
    for _ in range(300):  # "drives": fresh noise draws, the NLL's Hessian by the study's finite differences
        y = B @ x_true + sigma * rng.standard_normal(len(B))
        nll = np.array([0.5 * np.sum((y - B @ (x_true + d)) ** 2) / sigma**2 for d in offsets])
        g, H = design.derivatives(nll, h)
        hessians.append(H)
        scores.append(g)
        estimates.append(np.linalg.lstsq(B, y, rcond=None)[0])
    known = sigma**2 * np.linalg.inv(B.T @ B)
    info = module.fisher_information(np.array(hessians))
    np.testing.assert_allclose(module.bound_covariance(info, 1), known, rtol=1e-6)
    np.testing.assert_allclose(module.bound_covariance(info, 4), known / 4, rtol=1e-6)
    # a correct model: the scores' outer product estimates the same information (within sampling)
    opg = module.outer_product_information(np.array(scores))
    np.testing.assert_allclose(np.sqrt(np.diag(module.bound_covariance(opg, 1))), np.sqrt(np.diag(known)), rtol=0.12)
    scatter = np.cov(np.array(estimates).T)  # the efficient estimator's covariance: the bound, within sampling
    np.testing.assert_allclose(np.sqrt(np.diag(scatter)), np.sqrt(np.diag(known)), rtol=0.12)


def test_a_tied_configuration_and_an_unidentifiable_direction(load_script):
    module = load_script("cramer_rao")
    info = np.diag([4.0, 1.0, 0.0])
    A = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # first two tied, third free
    with pytest.raises(np.linalg.LinAlgError, match="not identifiable"):
        module.bound_covariance(info, 1, A)
    tied = module.bound_covariance(np.diag([4.0, 1.0, 2.0]), 2, A)
    np.testing.assert_allclose(tied, np.diag([1 / 10.0, 1 / 4.0]))


def test_error_bounds_are_the_medians_of_the_errors_of_efficient_draws(load_script):
    module = load_script("cramer_rao")
    from avio.reference import kitti_2011_10_03_calibration

    truth = kitti_2011_10_03_calibration()

    def decode(dy):  # dy (draws, 1): focal length offsets in px, fx = fy
        return replace(truth.repeat(len(dy)), fx_px=truth.fx_px[0] + dy[:, 0], fy_px=truth.fy_px[0] + dy[:, 0])

    out = module.error_bounds(np.array([[4.0]]), decode, truth, np.random.default_rng(1), draws=20000)
    assert out["focal_error_px"] == pytest.approx(2.0 * 0.6745, rel=0.03)  # median |N(0, 2^2)|
    assert out["rotation_error_deg"] == 0.0 and out["translation_error_cm"] == 0.0



def _saved(H, g, rig="paper_540m", variables=("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx")):
    return {"rig": np.array(rig), "vars": np.array(variables), "innovation_nll_joint_H": H, "innovation_nll_joint_g": g}


def test_a_configurations_bound_maps_its_free_variables_and_reports_only_errors_it_estimates(load_script, monkeypatch):
    module = load_script("cramer_rao")
    seen = {}

    def fake_medians(cov, A, measured, rig, seeds, rng):  # the drawn errors need the simulator: checked above
        seen.update(cov=cov, A=A, rig=rig)
        return {k: 1.0 for k in module.ERRORS}

    monkeypatch.setattr(module, "median_error_bounds", fake_medians)
    info = np.diag([4.0, 2.0, 1.0, 1.0, 9.0, 9.0, 16.0, 25.0])
    H = np.repeat(info[None], 3, axis=0)
    g = np.zeros((3, 8))
    # the flat city's 7 free: fy tied to fx, dy and dz fixed
    out = module.configuration_bound(_saved(H, g), 4, fixed=("dy", "dz"), tie_focal=True)
    assert out["information"] == "hessian" and seen["rig"] == "paper_540m"
    np.testing.assert_allclose(seen["cov"][0, 0], 1 / (4 * 6.0))  # f = fx = fy: 4 + 2 per drive, 4 drives
    np.testing.assert_allclose(np.diag(seen["cov"])[1:], 1 / (4 * info.diagonal()[2:]))
    assert out["rotation_error_deg"] == 1.0 and out["focal_error_px"] == 1.0
    assert out["translation_error_cm"] is None  # dy, dz fixed: the lever arm's error is not an estimate's
    # the principal point frozen too (5 free): its error is the frozen value's
    five = module.configuration_bound(_saved(H, g), 4, fixed=("cx", "cy", "dy", "dz"), tie_focal=True)
    assert five["principal_point_error_px"] is None and seen["cov"].shape == (5, 5)
    # dy, dz free on a file that did not measure them: no bound
    assert module.configuration_bound(_saved(H, g), 4) is None
    # the time offset free and not measured: none either
    ten = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz")
    H10 = np.repeat(np.eye(10)[None], 3, axis=0)
    assert module.configuration_bound(_saved(H10, np.zeros((3, 10)), "full3d_540m", ten), 1, with_time_offset=True) is None


def test_an_indefinite_mean_hessian_falls_back_to_the_scores_outer_product(load_script, monkeypatch):
    module = load_script("cramer_rao")
    seen = {}
    monkeypatch.setattr(module, "median_error_bounds",
                        lambda cov, *a: seen.update(cov=cov) or {k: 1.0 for k in module.ERRORS})
    ten = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz")
    H = np.repeat(np.diag([-1.0] + [1.0] * 9)[None], 4, axis=0)
    g = np.random.default_rng(0).standard_normal((4000, 10))
    H = np.repeat(H[:1], 4000, axis=0)
    out = module.configuration_bound(_saved(H, g, "full3d_540m", ten), 4)
    assert out["information"] == "opg" and out["translation_error_cm"] == 1.0
    np.testing.assert_allclose(seen["cov"], np.linalg.inv(4 * g.T @ g / len(g)))


def test_the_frozen_limit_needs_all_ten_variables_measured(load_script):
    module = load_script("cramer_rao")  # the limit itself is minimiser_scatter.predict's (test_minimiser_scatter.py)
    H = np.repeat(np.eye(8)[None], 3, axis=0)
    with pytest.raises(ValueError, match="--all-ten"):
        module.frozen_errors(_saved(H, np.zeros((3, 8))), ("dy", "dz"), True, [0])


def test_each_sets_bound_is_its_summed_curvature_inverted_and_an_indefinite_set_has_none(load_script):
    module = load_script("cramer_rao")
    H = np.array([np.diag([1.0, 2.0]), np.diag([3.0, 4.0]), np.diag([-10.0, 1.0])])  # the third: negative curvature
    covs, m = module.set_bounds(H, np.eye(2), 2, 200, np.random.default_rng(0))
    assert 0 < m < 200  # every set holding the third drive is indefinite along the first variable
    np.testing.assert_allclose(covs[0], np.diag([1 / 4.0, 1 / 6.0]))  # only {1, 2} is positive definite
    assert np.allclose(covs, covs[0])


def test_a_drives_noise_realisations_are_averaged_into_its_information_before_sets_are_drawn(load_script):
    module = load_script("cramer_rao")
    # two trajectories, two noise realisations each: the first's average diag(2, 2), the second's diag(4, 4)
    H = np.array([np.diag([3.0, 1.0]), np.diag([1.0, 3.0]), np.diag([4.0, 4.0]), np.diag([4.0, 4.0])])
    covs, m = module.set_bounds(H, np.eye(2), 2, 20, np.random.default_rng(0), trajectory=np.array([7, 7, 9, 9]))
    assert m == 20
    np.testing.assert_allclose(covs, np.repeat(np.diag([1 / 6.0, 1 / 6.0])[None], 20, axis=0))
