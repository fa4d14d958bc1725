"""Statistics: hand-computed cases, agreement with scipy, and the degenerate inputs."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from bench.report.stats import (
    StatsError,
    a12,
    a12_magnitude,
    average_ranks,
    compare,
    holm,
    median_ci,
    pairwise,
    ranks,
    summary,
    versus_leader,
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


def test_a12_hand_case():
    # pairs (a<b): 1<2, 1<4, 2<4, 3<4 -> 4; ties: 2=2 -> 0.5; total 6 pairs
    assert a12([1, 2, 3], [2, 4]) == pytest.approx(4.5 / 6)


def test_a12_equals_normalised_mann_whitney_u_and_is_complementary():
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, 5, 9).astype(float), rng.integers(0, 5, 7).astype(float)  # many ties
    u_b = sps.mannwhitneyu(b, a).statistic  # counts b > a plus half the ties
    assert a12(a, b) == pytest.approx(u_b / (a.size * b.size))
    assert a12(a, b) + a12(b, a) == pytest.approx(1.0)


def test_a12_magnitude_thresholds():
    assert [a12_magnitude(v) for v in (0.5, 0.57, 0.36, 0.75, 0.0)] == \
        ["negligible", "small", "medium", "large", "large"]
    assert a12_magnitude(np.nan) == ""


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


def test_pairwise_excludes_failed_runs_and_corrects_within_problem():
    runs = runs_frame({("p", "a"): [1, 2, 3], ("p", "b"): [4, 5, 6], ("p", "c"): [7, 8, 9],
                       ("q", "a"): [1, 2, 3], ("q", "b"): [4, 5, 6]}, failed={("p", "a"): 2})
    table = pairwise(runs)
    ab = table[(table["problem"] == "p") & (table["a"] == "a") & (table["b"] == "b")].iloc[0]
    assert ab["n_a"] == 3 and ab["p_value"] == pytest.approx(0.1) and ab["a12"] == 1.0
    # three pairs in problem p, each p = 0.1 -> Holm 0.3; one pair in q -> unchanged
    np.testing.assert_allclose(table.loc[table["problem"] == "p", "p_holm"], 0.3)
    assert table.loc[table["problem"] == "q", "p_holm"].iloc[0] == pytest.approx(0.1)
    assert set(table["significant"]) == {"no"}


def test_pairing_by_seed_uses_wilcoxon_only_when_seed_sets_match():
    runs = runs_frame({("p", "a"): [1, 2, 3, 4], ("p", "b"): [1, 3, 5, 8]})
    assert pairwise(runs, pairing="seed")["test"].iloc[0] == "wilcoxon"
    uneven = runs[~((runs["optimizer"] == "b") & (runs["seed"] == 3))]
    assert pairwise(uneven, pairing="seed")["test"].iloc[0] == "mannwhitneyu"
    with pytest.raises(StatsError):
        pairwise(runs, pairing="bogus")


def test_untestable_pair_is_reported_not_dropped():
    runs = runs_frame({("p", "a"): [1.0], ("p", "b"): [2.0, 3.0]}, failed={("p", "c"): 3})
    table = pairwise(runs)
    assert len(table) == 3
    assert set(table["significant"]) == {"n/a"} and table["p_holm"].isna().all()


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


def test_versus_leader_compares_everyone_with_the_lowest_median():
    runs = runs_frame({("p", "a"): [5, 6, 7, 8, 9], ("p", "b"): [0, 1, 2, 3, 4], ("p", "c"): [1, 2, 3, 4, 5]})
    table = versus_leader(runs, summary(runs))
    assert set(table["b"]) == {"b"} and list(table["a"]) == ["a", "c"]
    raw = table.set_index("a")["p_value"]
    assert raw["a"] == pytest.approx(sps.mannwhitneyu([5, 6, 7, 8, 9], [0, 1, 2, 3, 4]).pvalue)
    # Holm over the problem's family of all pairs (a-b, a-c, b-c), as in the pairwise table
    pairs = pairwise(runs)
    family = holm(pairs["p_value"].to_numpy())
    by_pair = {frozenset((a, b)): p for a, b, p in zip(pairs["a"], pairs["b"], family)}
    np.testing.assert_allclose(table["p_holm"], [by_pair[frozenset(("a", "b"))], by_pair[frozenset(("c", "b"))]])
    assert (table["family_size"] == 3).all()


def test_leaderboard_and_pairwise_significance_agree_pair_by_pair():
    # the leaderboard used Holm over the k-1 leader comparisons, the pairwise table over all pairs:
    # the same pair could be "significant" in one and not in the other
    rng = np.random.default_rng(1)
    runs = runs_frame({("p", o): list(rng.normal(mu, 1.0, 8)) for o, mu in
                       zip("abcde", (0.0, 0.9, 1.1, 1.3, 3.0))})
    vs = versus_leader(runs, summary(runs))
    pairs = pairwise(runs).set_index(["a", "b"])
    for row in vs.itertuples(index=False):
        pair = pairs.loc[tuple(sorted((row.a, row.b)))]
        assert (row.p_holm, row.significant) == (pair["p_holm"], pair["significant"])


def test_a_seed_twice_in_one_group_is_refused():
    runs = runs_frame({("p", "a"): [1.0, 2.0]})
    runs.loc[1, "seed"] = 0
    with pytest.raises(StatsError, match="seed 0 of p/a appears 2 times"):
        summary(runs)


def test_alpha_and_confidence_outside_zero_one_are_refused():
    runs = runs_frame({("p", "a"): [1.0, 2.0], ("p", "b"): [3.0, 4.0]})
    with pytest.raises(StatsError, match="alpha must be in"):
        pairwise(runs, alpha=2)
    with pytest.raises(StatsError, match="confidence must be in"):
        summary(runs, confidence=1.5)
