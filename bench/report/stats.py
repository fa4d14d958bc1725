"""Statistics on the final best objective of runs: tests, Holm correction, effect sizes, CIs, ranks.

Input everywhere is a tidy frame of runs with columns ``problem, optimizer, seed, valid, best_f``
(``bench.leaderboard.runs_table``). Only valid runs (status "ok" with a best f) enter a test;
failed runs are counted by the leaderboard, never tested.

Choices, documented once here:

- **Test.** Two-sided Mann–Whitney U (scipy, exact for small untied samples, normal
  approximation otherwise) on the final best f. The seed drives only the optimiser's RNG and
  the objective is deterministic, so two optimisers' runs with the same seed share nothing and
  are independent samples. With ``pairing="seed"`` (for problems whose instance depends on the
  seed) the Wilcoxon signed-rank test is used on the seed-matched differences whenever the two
  optimisers have the same set of valid seeds; zero differences are dropped (scipy's "wilcox").
- **Degenerate samples.** Fewer than 2 valid runs on either side: no test is possible, the
  p-value is NaN (and stays NaN after correction). All values identical on both sides (or all
  paired differences zero): p = 1 — there is no difference to detect.
- **Multiple comparisons.** Holm's step-down correction over one family per problem: the tests
  with a finite p-value among all pairs of optimisers of the problem (``family_size`` of them).
  ``versus_leader`` takes its adjusted p from that same family, so the leaderboard's verdict and
  the pairwise table agree for every pair with the leader (a smaller family, leader comparisons
  only, would be more powerful but would contradict the pairwise table).
- **Grouping.** ``problem`` and ``optimizer`` are the labels of ``bench.leaderboard.runs_table``,
  one per job identity (settings that differ are in the label); a seed twice in one group is an
  error (``StatsError``), never counted twice.
- **Effect size.** Vargha–Delaney A12(a, b) = P(f_a < f_b) + ½ P(f_a = f_b): the probability
  that a run of a ends lower (better) than a run of b; 0.5 is no effect. Magnitude labels use
  Vargha & Delaney's thresholds on |A12 - 0.5|: 0.06 small, 0.14 medium, 0.21 large.
- **Confidence interval of a median.** Percentile bootstrap (``scipy.stats.bootstrap``) with a
  generator seeded from (seed, problem, optimizer), so a group's interval does not depend on
  which other groups are present; BCa is avoided because it is undefined for the all-equal
  samples that converged optimisers produce. Fewer than 2 runs: NaN.
- **Ranks.** Per problem by median best f (lower is better), ties averaged, optimisers without
  a valid run ranked last; the overall rank is the mean of the per-problem ranks.
"""

from __future__ import annotations

import itertools
import zlib

import numpy as np
import pandas as pd
from scipy import stats as sps

from bench.errors import BenchError

MIN_RUNS = 2
A12_THRESHOLDS = ((0.21, "large"), (0.14, "medium"), (0.06, "small"))


class StatsError(BenchError):
    """Bad input to a statistic (wrong shape, unknown option); the message says what."""


def holm(p_values: np.ndarray) -> np.ndarray:
    """Holm step-down adjusted p-values, (m,) -> (m,); NaN entries are left out of the family.

    Hand-written: scipy offers only false-discovery-rate control (``false_discovery_control``).
    """
    p = np.asarray(p_values, float)
    out = np.full(p.shape, np.nan)
    finite = np.flatnonzero(~np.isnan(p))
    if finite.size == 0:
        return out
    order = finite[np.argsort(p[finite], kind="stable")]
    m = order.size
    scaled = (m - np.arange(m)) * p[order]
    out[order] = np.minimum(1.0, np.maximum.accumulate(scaled))
    return out


def a12(a: np.ndarray, b: np.ndarray) -> float:
    """Vargha–Delaney A12 = P(a < b) + ½ P(a = b) for minimisation; NaN if a sample is empty.

    Hand-written (a broadcast comparison): scipy has no A12. a: (n,), b: (m,).
    """
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    if a.size == 0 or b.size == 0:
        return np.nan
    less = np.sum(a[:, None] < b[None, :])
    equal = np.sum(a[:, None] == b[None, :])
    return float((less + 0.5 * equal) / (a.size * b.size))


def a12_magnitude(value: float) -> str:
    """'negligible' / 'small' / 'medium' / 'large' for an A12 value; '' for NaN."""
    if not np.isfinite(value):
        return ""
    for threshold, label in A12_THRESHOLDS:
        if abs(value - 0.5) >= threshold:
            return label
    return "negligible"


def compare(a: np.ndarray, b: np.ndarray, paired: bool = False) -> tuple[str, float, float]:
    """Two-sided test of a difference between two samples of final f: (test, statistic, p).

    paired=False: Mann–Whitney U (statistic U of a). paired=True: Wilcoxon signed-rank on
    a - b (a and b aligned by seed; statistic as scipy reports it). See the module doc for the
    degenerate cases (NaN with < 2 runs, p = 1 when nothing differs).
    """
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    if paired:
        if a.size != b.size:
            raise StatsError(f"paired samples differ in length: {a.size} vs {b.size}")
        if a.size < MIN_RUNS:
            return "wilcoxon", np.nan, np.nan
        d = a - b
        if np.all(d == 0):
            return "wilcoxon", 0.0, 1.0
        res = sps.wilcoxon(d, alternative="two-sided")
        return "wilcoxon", float(res.statistic), float(res.pvalue)
    if a.size < MIN_RUNS or b.size < MIN_RUNS:
        return "mannwhitneyu", np.nan, np.nan
    if np.all(np.concatenate([a, b]) == a[0]):
        return "mannwhitneyu", a.size * b.size / 2.0, 1.0
    res = sps.mannwhitneyu(a, b, alternative="two-sided")
    return "mannwhitneyu", float(res.statistic), float(res.pvalue)


def _group_rng(seed: int, *names: str) -> np.random.Generator:
    # crc32, not hash(): Python's str hash is salted per process and would break reproducibility.
    return np.random.default_rng([seed, *(zlib.crc32(n.encode()) for n in names)])


def median_ci(x: np.ndarray, rng: np.random.Generator, confidence: float = 0.95,
              n_resamples: int = 2000) -> tuple[float, float]:
    """Percentile-bootstrap confidence interval of the median of x (n,); (NaN, NaN) if n < 2."""
    x = np.asarray(x, float).ravel()
    if x.size < MIN_RUNS:
        return np.nan, np.nan
    if np.all(x == x[0]):
        return float(x[0]), float(x[0])
    res = sps.bootstrap((x,), np.median, confidence_level=confidence, n_resamples=n_resamples,
                        method="percentile", rng=rng)
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def _valid(runs: pd.DataFrame) -> pd.DataFrame:
    missing = {"problem", "optimizer", "seed", "valid", "best_f"} - set(runs.columns)
    if missing:
        raise StatsError(f"runs table lacks the columns {sorted(missing)}")
    dup = runs.duplicated(["problem", "optimizer", "seed"], keep=False)
    if dup.any():
        first = runs[dup].iloc[0]
        raise StatsError(f"seed {first['seed']} of {first['problem']}/{first['optimizer']} appears "
                         f"{int(dup.sum())} times: one run per seed and job identity")
    return runs[runs["valid"]]


def summary(runs: pd.DataFrame, seed: int = 0, confidence: float = 0.95) -> pd.DataFrame:
    """Per (problem, optimizer) over valid runs: n_valid, median, q25, q75, iqr, the bootstrap CI
    of the median (``median_ci_low``, ``median_ci_high``) and its level (``ci_level``). Groups
    with no valid run appear with n_valid 0 and NaN statistics."""
    if not 0 < confidence < 1:
        raise StatsError(f"confidence must be in (0, 1), got {confidence!r}")
    rows = []
    valid = _valid(runs)
    for (problem, optimizer), _ in runs.groupby(["problem", "optimizer"], sort=True):
        f = valid.loc[(valid["problem"] == problem) & (valid["optimizer"] == optimizer), "best_f"]
        f = f.to_numpy(float)
        q25, med, q75 = np.quantile(f, [0.25, 0.5, 0.75]) if f.size else (np.nan,) * 3
        lo, hi = median_ci(f, _group_rng(seed, problem, optimizer), confidence)
        rows.append((problem, optimizer, f.size, med, q25, q75, q75 - q25, lo, hi))
    out = pd.DataFrame(rows, columns=["problem", "optimizer", "n_valid", "median", "q25", "q75",
                                      "iqr", "median_ci_low", "median_ci_high"])
    out["ci_level"] = confidence
    return out


def _samples(valid: pd.DataFrame, problem: str, optimizer: str) -> pd.Series:
    g = valid[(valid["problem"] == problem) & (valid["optimizer"] == optimizer)]
    return g.set_index("seed")["best_f"].sort_index()


def _test_pair(fa: pd.Series, fb: pd.Series, pairing: str) -> tuple[str, float, float]:
    if pairing not in ("none", "seed"):
        raise StatsError(f"pairing must be 'none' or 'seed', got {pairing!r}")
    paired = (pairing == "seed" and fa.index.is_unique and fb.index.is_unique
              and list(fa.index) == list(fb.index))
    return compare(fa.to_numpy(float), fb.to_numpy(float), paired=paired)


def _pair_row(problem, a, b, fa, fb, pairing):
    test, stat, p = _test_pair(fa, fb, pairing)
    effect = a12(fa.to_numpy(float), fb.to_numpy(float))
    return {"problem": problem, "a": a, "b": b, "n_a": len(fa), "n_b": len(fb),
            "median_a": fa.median() if len(fa) else np.nan, "median_b": fb.median() if len(fb) else np.nan,
            "test": test, "statistic": stat, "p_value": p, "a12": effect,
            "a12_magnitude": a12_magnitude(effect)}


def _check_alpha(alpha: float) -> None:
    if not 0 < alpha < 1:
        raise StatsError(f"alpha must be in (0, 1), got {alpha!r}")


def _finish(rows: list[dict], alpha: float, columns: list[str]) -> pd.DataFrame:
    table = pd.DataFrame(rows, columns=columns[:-4])
    table["p_holm"] = np.nan
    table["family_size"] = 0
    for _, idx in table.groupby("problem", sort=False).groups.items():
        table.loc[idx, "p_holm"] = holm(table.loc[idx, "p_value"].to_numpy(float))
        table.loc[idx, "family_size"] = int(table.loc[idx, "p_value"].notna().sum())
    table["significant"] = _significance(table["p_holm"], alpha)
    table["alpha"] = alpha
    return table[columns]


def _significance(p_holm: pd.Series, alpha: float) -> np.ndarray:
    return np.where(p_holm.isna(), "n/a", np.where(p_holm < alpha, "yes", "no"))


_PAIR_COLUMNS = ["problem", "a", "b", "n_a", "n_b", "median_a", "median_b", "test", "statistic",
                 "p_value", "a12", "a12_magnitude", "p_holm", "family_size", "significant", "alpha"]


def pairwise(runs: pd.DataFrame, pairing: str = "none", alpha: float = 0.05) -> pd.DataFrame:
    """Every pair (a, b) of optimisers within each problem, a < b by name: sizes, medians, test,
    statistic, raw and Holm-adjusted p (family: the problem's pairs), significance at ``alpha``
    ("yes"/"no"/"n/a" when untestable), A12(a, b) and its magnitude."""
    _check_alpha(alpha)
    valid = _valid(runs)
    rows = []
    for problem, group in runs.groupby("problem", sort=True):
        for a, b in itertools.combinations(sorted(group["optimizer"].unique()), 2):
            rows.append(_pair_row(problem, a, b, _samples(valid, problem, a),
                                  _samples(valid, problem, b), pairing))
    return _finish(rows, alpha, _PAIR_COLUMNS)


def leaders(summary_table: pd.DataFrame) -> pd.Series:
    """The leader of each problem: lowest median best f, ties broken by optimizer name."""
    ranked = summary_table.dropna(subset=["median"]).sort_values(["problem", "median", "optimizer"])
    return ranked.groupby("problem", sort=True)["optimizer"].first()


def versus_leader(runs: pd.DataFrame, summary_table: pd.DataFrame, pairing: str = "none",
                  alpha: float = 0.05) -> pd.DataFrame:
    """Each optimiser (a) against its problem's leader (b), with Holm's correction over the family
    of all the problem's pairs (``pairwise``'s ``p_holm`` for that pair; see the module doc).

    Same columns as ``pairwise``; the leader itself has no row.
    """
    _check_alpha(alpha)
    valid = _valid(runs)
    lead = leaders(summary_table)
    pairs = pairwise(runs, pairing, alpha)
    adjusted = {(r.problem, frozenset((r.a, r.b))): (r.p_holm, r.family_size)
                for r in pairs.itertuples(index=False)}
    rows = []
    for problem, group in runs.groupby("problem", sort=True):
        if problem not in lead.index:
            continue
        leader = lead[problem]
        for a in sorted(set(group["optimizer"]) - {leader}):
            rows.append(_pair_row(problem, a, leader, _samples(valid, problem, a),
                                  _samples(valid, problem, leader), pairing))
    table = pd.DataFrame(rows, columns=_PAIR_COLUMNS[:-4])
    found = [adjusted[(r.problem, frozenset((r.a, r.b)))] for r in table.itertuples(index=False)]
    table["p_holm"] = [p for p, _ in found] if found else np.nan
    table["family_size"] = [n for _, n in found] if found else 0
    table["significant"] = _significance(table["p_holm"], alpha)
    table["alpha"] = alpha
    return table[_PAIR_COLUMNS]


def ranks(summary_table: pd.DataFrame) -> pd.DataFrame:
    """Rank of each optimiser within its problem by median best f (columns problem, optimizer, rank)."""
    out = summary_table[["problem", "optimizer", "median"]].copy()
    out["rank"] = out.groupby("problem")["median"].rank(method="average", na_option="bottom")
    return out[["problem", "optimizer", "rank"]]


def average_ranks(rank_table: pd.DataFrame) -> pd.DataFrame:
    """Mean per-problem rank of each optimiser over the problems it ran: columns optimizer,
    average_rank, n_problems, then one ``rank.<problem>`` column per problem; best first."""
    wide = rank_table.pivot(index="optimizer", columns="problem", values="rank")
    out = pd.DataFrame({"average_rank": wide.mean(axis=1), "n_problems": wide.notna().sum(axis=1)})
    out = out.join(wide.add_prefix("rank."))
    out = out.reset_index().sort_values(["average_rank", "optimizer"], kind="stable")
    out.columns.name = None
    return out.reset_index(drop=True)
