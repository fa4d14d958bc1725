"""studies/identifiability/minimiser_scatter.py: the K-drive minimiser's scatter from curvature and gradient noise."""

from __future__ import annotations

import numpy as np


def test_the_design_gives_a_quadratics_gradient_and_hessian_exactly(load_script):
    module = load_script("minimiser_scatter")
    rng = np.random.default_rng(0)
    n = 4
    B = rng.standard_normal((n, n))
    H, g, h = B @ B.T - 2 * np.eye(n), rng.standard_normal(n), np.array([1.0, 0.3, 0.03, 3.0])
    X = module.design(n, h)
    assert X.shape == (1 + 2 * n + 2 * n * (n - 1), n)
    f = 5.0 + X @ g + 0.5 * np.einsum("pi,ij,pj->p", X, H, X)
    g_est, H_est = module.derivatives(f, h)
    np.testing.assert_allclose(g_est, g, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(H_est, H, rtol=1e-9, atol=1e-8)


def test_a_configurations_space_is_an_affine_subspace_with_its_tie_and_frozen_rows(load_script):
    module = load_script("minimiser_scatter")
    full = module.Synthetic(drives=[module.DRIVE], holdout=None, data_seed=0, space="local")
    A, c = module.subspace(full, True, ["dy", "dz"], 0)
    names = list(full.space.names)
    assert A.shape == (10, 7)
    np.testing.assert_allclose(A[names.index("fy")], A[names.index("fx")])  # fy = fx
    assert not A[names.index("dy")].any() and not A[names.index("dz")].any()  # frozen
    sub = module.Synthetic(drives=[module.DRIVE], holdout=None, data_seed=0, space="local", tie_focal=True,
                           fixed=["dy", "dz"])
    y = sub.truth + np.array([2.0, -1.0, 1.5, 0.2, -0.1, 0.3, 0.02])
    x = full.calibration_space.encode(sub.calibration_space.decode(y[None]))[0]
    np.testing.assert_allclose(A @ y + c, x, atol=1e-9)


def test_without_noise_or_tilt_the_free_minimiser_is_the_truth_and_a_frozen_one_is_not(load_script):
    module = load_script("minimiser_scatter")
    rng = np.random.default_rng(1)
    h = np.array([module.STEP[k] for k in ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz")])
    H = np.tile(np.diag(1.0 / h**2), (3, 1, 1))  # well curved in every variable
    g = 1e-12 * rng.standard_normal((3, 10))  # no tilt, next to no noise
    pred = module.predict(g, H, 1, {"10 free": (False, []), "7 free": (True, ["dy", "dz"])}, [0], 4, rng)
    for k in module.ERRORS:
        assert np.all(pred["10 free"][k] < 1e-6), k
    assert np.all(pred["7 free"]["translation_error_cm"] > 1.0)  # the reference's dy, dz error stays
