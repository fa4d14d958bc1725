"""studies/objective/score_lags.py: the lag bands add up to the drive's gradient covariance, the
window sums equal the brute-force lag sums, and a planted correlation is found at its lag."""

from __future__ import annotations

import numpy as np


def test_window_sums_equal_the_lag_sums_and_the_bands_add_up_to_the_total(load_script):
    module = load_script("score_lags")
    rng = np.random.default_rng(0)
    D, N, p = 40, 30, 3
    g = rng.standard_normal((D, N, p)).cumsum(axis=1) * 0.3 + rng.standard_normal((D, N, p))
    c = g - g.mean(axis=0)
    for lo, hi in ((0, 0), (1, 2), (3, 10), (11, 29)):
        brute = np.zeros((p, p))
        for lag in range(lo, hi + 1):
            C = sum(np.einsum("di,dj->ij", c[:, k], c[:, k + lag]) for k in range(N - lag)) / (D - 1)
            brute += C if lag == 0 else C + C.T
        np.testing.assert_allclose(module.band_term(c, lo, hi), brute, atol=1e-10)
    H = np.repeat((np.eye(p) * N)[None], D, axis=0)
    s = module.split(g, H)
    assert abs(sum(s["trace"]) - s["total"]) < 1e-9 * abs(s["total"])
    np.testing.assert_allclose(np.sum(s["diag"], axis=0), s["total_diag"], rtol=1e-9)


def test_a_planted_lag_one_correlation_is_found_in_its_band_and_nowhere_else(load_script):
    module = load_script("score_lags")
    rng = np.random.default_rng(1)
    D, N, p = 3000, 40, 2
    e = rng.standard_normal((D, N + 1, p))
    white = e[:, 1:]
    ma1 = e[:, 1:] + e[:, :-1]  # Cov(g_k, g_k+1) = 1 per component, Var = 2
    H = np.repeat((np.eye(p) * N)[None], D, axis=0)
    s_white = module.split(white, H)
    assert abs(s_white["total"] - 1.0) < 0.05 and all(abs(t) < 0.05 for t in s_white["trace"][1:])
    s_ma = module.split(ma1, H)
    lag0, lag12 = s_ma["trace"][0], s_ma["trace"][1]
    assert abs(lag0 - 2.0) < 0.1 and abs(lag12 - 2.0 * (N - 1) / N) < 0.1
    assert all(abs(t) < 0.1 for t in s_ma["trace"][2:])


def test_the_free_variables_tie_fx_and_fy(load_script):
    module = load_script("score_lags")
    rng = np.random.default_rng(2)
    g8, H8 = rng.standard_normal((5, 4, 8)), rng.standard_normal((5, 8, 8))
    g7, H7 = module.free7(g8, H8)
    np.testing.assert_allclose(g7[..., 0], g8[..., 0] + g8[..., 1])
    np.testing.assert_allclose(g7[..., 1:], g8[..., 2:])
    np.testing.assert_allclose(H7[:, 0, 0], H8[:, 0, 0] + H8[:, 1, 1] + H8[:, 0, 1] + H8[:, 1, 0])
    assert module.free7(g7, H7)[0] is g7


def test_paired_ratios_find_a_halved_scatter_and_no_change_where_there_is_none(load_script):
    module = load_script("score_lags")
    rng = np.random.default_rng(3)
    D, N = 400, 5
    H = np.repeat((np.eye(8) * N)[None], D, axis=0)
    g = rng.standard_normal((D, N, 8))
    a = {"g": g, "H": H}
    b = {"g": g.copy(), "H": H}
    b["g"][:, :, 2] = np.sqrt(0.5) * rng.standard_normal((D, N))  # cx: half the variance; the rest identical
    lines = module.paired(a, b, np.random.default_rng(0), n=200)
    rows = {line.split(" | ")[0].strip("| "): line for line in lines[3:]}
    assert lines[0] == f"drives typical in both: {D} of {D}"
    assert rows["rz"].endswith("| 1.00 [1.00–1.00] |")
    ratio = float(rows["cx"].split(" | ")[3].split(" [")[0])
    lo, hi = (float(x) for x in rows["cx"].split("[")[1].rstrip("] |").split("–"))
    assert 0.35 < ratio < 0.65 and lo < 0.5 < hi < 0.8
