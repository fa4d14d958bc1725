"""Statistics: hand-computed cases, agreement with scipy, and the degenerate inputs."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from bench.report.stats import (
    StatsError,
    average_ranks,
    compare,
    holm,
    median_ci,
    ranks,
    summary,
)


def runs_frame(samples: dict[tuple[str, str], list[float]], failed: dict | None = None) -> pd.DataFrame:
    """Tidy runs from {(problem, optimizer): [best_f per seed 0..]}; failed adds invalid runs."""
    rows = [(p, o, s, True, f) for (p, o), fs in samples.items() for s, f in enumerate(fs)]
    for (p, o), n in (failed or {}).items():
        rows += [(p, o, 100 + s, False, np.nan) for s in range(n)]
    return pd.DataFrame(rows, columns=["problem", "optimizer", "seed", "valid", "best_f"])


def test_holm_matches_hand_computation_and_skips_nan():
    # sorted p: 0.01*3 = 0.03, 0.03*2 = 0.06, 0.04*1 = 0.04 -> monotone max 0.06
    adjusted = holm(np.array([0.01, 0.04, 0.03, np.nan]))
    np.testing.assert_allclose(adjusted[:3], [0.03, 0.06, 0.06])
    assert np.isnan(adjusted[3])


def test_holm_is_monotone_capped_and_not_below_raw():
    p = np.random.default_rng(3).uniform(0, 0.5, 20)
    adjusted = holm(p)
    order = np.argsort(p)
    assert np.all(np.diff(adjusted[order]) >= 0)
    assert np.all(adjusted >= p) and np.all(adjusted <= 1)


def test_mann_whitney_exact_hand_case():
    # fully separated 3 vs 3: the only as-extreme arrangements are the 2 of C(6,3) = 20
    test, u, p = compare([1, 2, 3], [4, 5, 6])
    assert (test, u, p) == ("mannwhitneyu", 0.0, pytest.approx(0.1))


def test_mann_whitney_with_ties_matches_scipy():
    a, b = [1, 2, 2, 3], [2, 5, 6]
    _, u, p = compare(a, b)
    ref = sps.mannwhitneyu(a, b, alternative="two-sided")
    assert u == ref.statistic and p == pytest.approx(ref.pvalue)


def test_all_equal_samples_give_p_one_and_single_seed_gives_nan():
    assert compare([2.0, 2.0, 2.0], [2.0, 2.0])[2] == 1.0
    assert compare([1.0, 1.0], [1.0, 1.0], paired=True)[2] == 1.0
    assert np.isnan(compare([1.0], [2.0, 3.0, 4.0])[2])
    assert np.isnan(compare([1.0], [2.0], paired=True)[2])


def test_wilcoxon_hand_case_drops_zero_differences():
    # differences 0, -1, -2, -4: the zero is dropped; 3 negatives: exact p = 2 * (1/2)^3
    test, _, p = compare([1, 2, 3, 4], [1, 3, 5, 8], paired=True)
    assert test == "wilcoxon" and p == pytest.approx(0.25)
    with pytest.raises(StatsError):
        compare([1, 2], [1, 2, 3], paired=True)


def test_median_ci_is_seeded_contains_median_and_handles_degenerate_samples():
    x = np.random.default_rng(5).normal(size=15)
    lo1, hi1 = median_ci(x, np.random.default_rng(1))
    lo2, hi2 = median_ci(x, np.random.default_rng(1))
    assert (lo1, hi1) == (lo2, hi2) and lo1 <= np.median(x) <= hi1
    assert median_ci([3.0, 3.0, 3.0], np.random.default_rng(0)) == (3.0, 3.0)
    assert all(np.isnan(median_ci([1.0], np.random.default_rng(0))))


def test_summary_interval_does_not_depend_on_other_groups():
    base = runs_frame({("p", "a"): [1, 5, 2, 8, 3]})
    more = runs_frame({("p", "a"): [1, 5, 2, 8, 3], ("p", "z"): [0, 1, 2], ("o", "a"): [4, 4]})
    def row(t):
        return t[(t["problem"] == "p") & (t["optimizer"] == "a")].iloc[0]
    assert row(summary(base)).equals(row(summary(more)))
    s = row(summary(base))
    assert (s["median"], s["q25"], s["q75"], s["n_valid"]) == (3, 2, 5, 5)


def test_ranks_average_ties_and_put_optimisers_without_runs_last():
    runs = runs_frame({("p", "a"): [1, 1], ("p", "b"): [1, 1], ("p", "c"): [2, 2],
                       ("q", "a"): [5, 5], ("q", "b"): [1, 1]}, failed={("p", "d"): 2})
    r = ranks(summary(runs)).set_index(["problem", "optimizer"])["rank"]
    assert r[("p", "a")] == r[("p", "b")] == 1.5 and r[("p", "c")] == 3 and r[("p", "d")] == 4
    avg = average_ranks(ranks(summary(runs))).set_index("optimizer")
    assert avg.loc["a", "average_rank"] == pytest.approx((1.5 + 2) / 2)
    assert avg.loc["b", "average_rank"] == pytest.approx((1.5 + 1) / 2)
    assert avg.loc["d", "n_problems"] == 1
    assert list(avg.index[:2]) == ["b", "a"]


def test_a_seed_twice_in_one_group_is_refused():
    runs = runs_frame({("p", "a"): [1.0, 2.0]})
    runs.loc[1, "seed"] = 0
    with pytest.raises(StatsError, match="seed 0 of p/a appears 2 times"):
        summary(runs)


def test_confidence_outside_zero_one_is_refused():
    runs = runs_frame({("p", "a"): [1.0, 2.0], ("p", "b"): [3.0, 4.0]})
    with pytest.raises(StatsError, match="confidence must be in"):
        summary(runs, confidence=1.5)
