"""Statistics on the final best objective of runs: the two-sample tests, Holm correction, CIs, ranks.

Input of ``summary`` is a tidy frame of runs with columns ``problem, optimizer, seed, valid,
best_f`` (``bench.leaderboard.runs_table``); only valid runs (status "ok" with a best f) enter it.

Choices, documented once here:

- **Tests** (``compare``): the Wilcoxon signed-rank test on paired samples, the building block
  of the paired verdicts (``bench.report.verdict``, which the report uses: runs paired on shared
  instances); Mann–Whitney U on unpaired samples. Fewer than 2 runs on a side: p = NaN. All
  values identical on both sides (or all paired differences zero): p = 1.
- **Multiple comparisons.** Holm's step-down correction (``holm``).
- **Grouping.** ``problem`` and ``optimizer`` are the labels of ``bench.leaderboard.runs_table``,
  one per job identity (settings that differ are in the label); a seed twice in one group is an
  error (``StatsError``), never counted twice.
- **Confidence interval of a median.** Percentile bootstrap (``scipy.stats.bootstrap``) with a
  generator seeded from (seed, problem, optimizer), so a group's interval does not depend on
  which other groups are present; BCa is avoided because it is undefined for the all-equal
  samples that converged optimisers produce. Fewer than 2 runs: NaN.
- **Ranks.** Per problem by median best f (lower is better), ties averaged, optimisers without
  a valid run ranked last; the overall rank is the mean of the per-problem ranks.
"""

from __future__ import annotations

import zlib

import numpy as np
import pandas as pd
from scipy import stats as sps

from bench.errors import BenchError

MIN_RUNS = 2


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


def compare(a: np.ndarray, b: np.ndarray, paired: bool = False) -> tuple[str, float, float]:
    """Two-sided test of a difference between two samples of final f: (test, statistic, p).

    paired=False: Mann–Whitney U (statistic U of a). paired=True: Wilcoxon signed-rank on
    a - b (a and b aligned by instance; statistic as scipy reports it). See the module doc for the
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
