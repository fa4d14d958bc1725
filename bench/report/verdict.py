"""Verdicts of a paired benchmark: optimisers compared over problem instances that they share.

Input is a tidy frame with columns ``problem, optimizer, <key>, value`` (key "instance" unless
told): one run per optimiser and instance (a camera and its drives, a noise draw of a recording,
a shifted function), every optimiser on every instance of its problem, ``value`` lower is
better, NaN for a failed run. Per problem the runs form a complete block design, instances x
optimisers, and every comparison is paired. Choices, documented once here:

- **Failed runs.** A NaN is worse than every finite value of the problem: it is replaced by
  max + span (span = max - min of the finite values, 1 if zero) before ranking and before the
  paired differences, so a failure ranks last and counts as a large loss; failures of both
  runs of a pair tie. The counts are reported (``n_failed_a``, ``n_failed_b``).
- **Omnibus.** Friedman's test on the blocks (scipy; k >= 3 optimisers, else NaN) and the mean
  rank of each optimiser (ranks within an instance, ties averaged, 1 = best). The Friedman p is
  reported, not used as a gate: Holm already controls the family-wise error of the post-hoc
  family, and a gate would only cost power (Garcia & Herrera 2008).
- **Post-hoc.** Default: each optimiser against the *leader* (best mean rank, ties by mean
  value then name), k - 1 two-sided Wilcoxon signed-rank tests on the paired differences
  (``bench.report.stats.compare``), Holm over that family. ``family="all"``: all pairs.
  ``posthoc="nemenyi"``/``"conover"``: scikit-posthocs' Friedman post-hocs on the same blocks;
  Conover's raw p are Holm-corrected over the family, Nemenyi's p are used as the library
  gives them (already adjusted over all pairs: conservative for the leader family). Wilcoxon
  is the default because a mean-rank test's outcome for a pair depends on the other
  optimisers in the table (Benavoli, Corani & Mangili 2016).
- **Critical difference.** Nemenyi's CD = q_alpha sqrt(k (k + 1) / (6 n)), with q_alpha the
  studentized range quantile over sqrt(2) (Demsar 2006); drawn by scikit-posthocs'
  ``critical_difference_diagram`` (the CD bar by ``cd_diagram`` itself). Hand-written CD
  value: neither scikit-posthocs nor scipy returns it, and autorank would add a second copy
  of the whole analysis for one number.
- **Practical equivalence.** Bayesian signed-rank test (Benavoli et al. 2014, 2017; baycomp's
  ``SignedRankTest``) on the paired values with a region of practical equivalence ``rope`` in
  the objective's units: posterior probabilities that a is better (d = a - b below -rope),
  practically equal, or worse. Chosen over a TOST because it answers the three-way question
  in one model, without a normality assumption on the differences, and gives probabilities a
  reader can weigh; it samples, so its generator is seeded from (seed, problem, a, b) (crc32)
  and the same table gives the same verdict. ``rope=None`` skips it.
- **Verdict** of a against b: *better* / *worse* when the post-hoc test is significant after
  Holm (the direction is the sign of the signed-rank sum) and the posterior of practical
  equality is below ``DECISION``; *practically equal* when that posterior reaches
  ``DECISION`` (0.95); *undecided* otherwise. Resolution columns (``bench.report.resolution``:
  p floor over the non-zero differences, minimum detectable difference, instances needed) refer
  to the Wilcoxon test with Holm over the family, whatever ``posthoc_test``; instances needed is
  estimated for undecided comparisons only (NaN otherwise, inf beyond ``cap``).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy import stats as sps

from bench.report import resolution as res
from bench.report.stats import StatsError, compare, holm

POSTHOCS = ("wilcoxon", "nemenyi", "conover")
DECISION = 0.95
N_POSTERIOR = 5000
VERDICTS = ("better", "worse", "practically equal", "undecided")


class Verdicts(NamedTuple):
    """``friedman``: one row per problem; ``ranks``: per (problem, optimizer); ``comparisons``:
    one row per post-hoc comparison (a against b)."""

    friedman: pd.DataFrame
    ranks: pd.DataFrame
    comparisons: pd.DataFrame


def block_matrix(frame: pd.DataFrame, problem: str | None = None, key: str = "instance") -> pd.DataFrame:
    """The design of one problem as a frame instances (index, sorted) x optimizers (columns,
    sorted) of values; ``problem`` None: the frame must hold one problem. A missing or repeated
    (optimizer, key) cell is a StatsError naming the key."""
    missing = {"problem", "optimizer", key, "value"} - set(frame.columns)
    if missing:
        raise StatsError(f"the frame lacks the columns {sorted(missing)} (pairing key {key!r})")
    if problem is None:
        problems = frame["problem"].unique()
        if len(problems) != 1:
            raise StatsError(f"block_matrix needs one problem or a problem name, got {len(problems)}")
        problem = problems[0]
    rows = frame[frame["problem"] == problem]
    counts = rows.groupby(["optimizer", key]).size().unstack(fill_value=0)
    if (counts > 1).any().any():
        opt, inst = counts.stack().idxmax()
        raise StatsError(f"{key} {inst!r} appears {counts.loc[opt, inst]} times for {problem}/{opt}: "
                         f"one run per optimizer and {key}")
    if (counts == 0).any().any():
        opt, inst = (counts == 0).stack().idxmax()
        raise StatsError(f"{problem}/{opt} has no run on {key} {inst!r}: every optimizer must run "
                         f"every {key} (a complete block design)")
    block = rows.pivot(index=key, columns="optimizer", values="value").sort_index().sort_index(axis=1)
    block.columns.name = None
    return block.astype(float)


def impute_failures(block: pd.DataFrame) -> pd.DataFrame:
    """NaN (failed run) -> max + span of the finite values: worse than any finite value."""
    values = block.to_numpy(float)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return block.fillna(0.0)
    span = float(finite.max() - finite.min()) or 1.0
    return block.fillna(float(finite.max()) + span)


def mean_ranks(block: pd.DataFrame) -> pd.Series:
    """Mean rank per optimizer (1 = best, ties averaged within an instance), failures last."""
    ranks = sps.rankdata(impute_failures(block).to_numpy(float), axis=1)
    return pd.Series(ranks.mean(axis=0), index=block.columns, name="mean_rank")


def friedman(block: pd.DataFrame) -> tuple[float, float]:
    """Friedman chi-square statistic and p over the blocks; NaN with < 3 optimizers or < 2
    instances; (0, 1) when every instance ties all optimizers."""
    values = impute_failures(block).to_numpy(float)
    n, k = values.shape
    if k < 3 or n < 2:
        return np.nan, np.nan
    if np.all(values == values[:, :1]):
        return 0.0, 1.0
    result = sps.friedmanchisquare(*values.T)
    return float(result.statistic), float(result.pvalue)


def critical_difference(n_optimizers: int, n_instances: int, alpha: float = 0.05) -> float:
    """Nemenyi's critical difference of mean ranks (Demsar 2006): q_alpha sqrt(k (k+1) / (6 n))."""
    k, n = int(n_optimizers), int(n_instances)
    if k < 2 or n < 1:
        return np.nan
    q = sps.studentized_range.ppf(1 - alpha, k, np.inf) / np.sqrt(2)
    return float(q * np.sqrt(k * (k + 1) / (6.0 * n)))


def leader_of(block: pd.DataFrame) -> str:
    """The optimiser with the best mean rank; ties by mean (imputed) value, then by name."""
    order = pd.DataFrame({"rank": mean_ranks(block), "mean": impute_failures(block).mean()})
    return str(order.sort_values(["rank", "mean"], kind="stable").index[0])


def _pairs(block: pd.DataFrame, family: str, against: str | None = None) -> list[tuple[str, str]]:
    if family not in res.FAMILIES:
        raise StatsError(f"family must be one of {res.FAMILIES}, got {family!r}")
    ranks = mean_ranks(block).sort_values(kind="stable")
    names = [str(n) for n in ranks.index]
    if family == "leader" or against is not None:  # a fixed control (e.g. the reference) instead of the leader
        leader = leader_of(block) if against is None else against
        return [(a, leader) for a in names if a != leader]
    return [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))]


def _library_p(block: pd.DataFrame, posthoc: str) -> pd.DataFrame:
    import scikit_posthocs as sp

    values = impute_failures(block).to_numpy(float)
    if np.all(values == values[:, :1]):
        return pd.DataFrame(1.0, index=block.columns, columns=block.columns)
    with np.errstate(invalid="ignore", divide="ignore"):
        if posthoc == "nemenyi":
            p = sp.posthoc_nemenyi_friedman(values)
        else:
            p = sp.posthoc_conover_friedman(values, p_adjust=None)
    return pd.DataFrame(p.to_numpy(float), index=block.columns, columns=block.columns)


def posthoc(block: pd.DataFrame, family: str = "leader", test: str = "wilcoxon",
            against: str | None = None) -> pd.DataFrame:
    """Post-hoc comparisons of one problem's block: columns a, b, n, statistic, p_value (raw),
    p_adjusted (Holm over the family; Nemenyi's own adjustment for "nemenyi"), family_size;
    ``against``: compare every other optimiser with this column instead of the leader."""
    if test not in POSTHOCS:
        raise StatsError(f"posthoc must be one of {POSTHOCS}, got {test!r}")
    pairs = _pairs(block, family, against)
    values = impute_failures(block)
    library = _library_p(block, test) if test != "wilcoxon" else None
    rows = []
    for a, b in pairs:
        _, stat, p = compare(values[a].to_numpy(), values[b].to_numpy(), paired=True)
        if library is not None:
            stat, p = np.nan, float(library.loc[a, b])
        rows.append({"a": a, "b": b, "n": len(block), "statistic": stat, "p_value": p})
    table = pd.DataFrame(rows, columns=["a", "b", "n", "statistic", "p_value"])
    raw = table["p_value"].to_numpy(float)
    table["p_adjusted"] = raw if test == "nemenyi" else holm(raw)
    table["family_size"] = len(pairs)
    return table


def _direction(d: np.ndarray) -> int:
    # sign of the signed-rank sum: -1 when a's values are lower (a better), as the test sees it
    nz = d[d != 0]
    if nz.size == 0:
        return 0
    ranks = sps.rankdata(np.abs(nz))
    return int(np.sign(np.sum(ranks * np.sign(nz))))


def equivalence(a: np.ndarray, b: np.ndarray, rope: float, seed: int = 0) -> tuple[float, float, float]:
    """Bayesian signed-rank posterior (p_better, p_equal, p_worse) of a against b (lower is
    better) with a ROPE in the values' units; seeded (baycomp's ``random_state``)."""
    from baycomp import SignedRankTest

    if rope < 0:
        raise StatsError(f"rope must be >= 0, got {rope!r}")
    a, b = np.asarray(a, float), np.asarray(b, float)
    # baycomp reads higher as better; its (left, [rope,] right) are P(a > b), [P(equal)], P(b > a)
    probs = SignedRankTest.probs(a, b, rope=rope, nsamples=N_POSTERIOR, random_state=seed)
    if len(probs) == 2:
        return float(probs[1]), 0.0, float(probs[0])
    return float(probs[2]), float(probs[1]), float(probs[0])


def _verdict(p_adjusted: float, alpha: float, direction: int, p_equal: float) -> str:
    if np.isfinite(p_equal) and p_equal >= DECISION:
        return "practically equal"
    if np.isfinite(p_adjusted) and p_adjusted < alpha and direction != 0:
        return "better" if direction < 0 else "worse"
    return "undecided"


def _resolve(row: dict, d: np.ndarray, m: int, alpha: float, seed: int, cap: int) -> dict:
    n_nonzero = int(np.count_nonzero(d))
    row["p_floor"] = res.wilcoxon_floor(n_nonzero, m)
    row["mdd"] = res.min_detectable_difference(d, m, alpha)
    row["n_needed"] = (res.instances_needed(d, m, alpha, cap=cap, seed=seed)
                       if row["verdict"] == "undecided" else np.nan)
    return row


def _seed(seed: int, *names: str) -> int:
    # crc32, not hash(): Python's str hash is salted per process and would break reproducibility
    return zlib.crc32("/".join([str(seed), *names]).encode())


def compare_block(block: pd.DataFrame, rope: float | None = 0.0, family: str = "leader",
                  posthoc_test: str = "wilcoxon", alpha: float = 0.05, seed: int = 0,
                  cap: int = res.N_CAP, problem: str = "", against: str | None = None) -> pd.DataFrame:
    """Verdicts of one problem's block (see the module doc): the ``posthoc`` columns plus
    mean_rank_a/b, n_failed_a/b, hl_shift (Hodges-Lehmann estimate of a - b), p_better,
    p_equal, p_worse, rope, verdict, and resolution p_floor, mdd, n_needed."""
    if not 0 < alpha < 1:
        raise StatsError(f"alpha must be in (0, 1), got {alpha!r}")
    if rope is not None and not (np.isfinite(rope) and rope >= 0):
        raise StatsError(f"rope must be a finite number >= 0 (or None), got {rope!r}")
    table = posthoc(block, family, posthoc_test, against)
    values, ranks = impute_failures(block), mean_ranks(block)
    rows = []
    for row in table.to_dict("records"):
        a, b = row["a"], row["b"]
        d = values[a].to_numpy() - values[b].to_numpy()
        walsh = (d[:, None] + d[None, :])[np.triu_indices(d.size)] / 2
        p_better, p_equal, p_worse = (equivalence(values[a], values[b], rope, _seed(seed, problem, a, b))
                                      if rope is not None else (np.nan,) * 3)
        row.update(mean_rank_a=ranks[a], mean_rank_b=ranks[b], n_failed_a=int(block[a].isna().sum()),
                   n_failed_b=int(block[b].isna().sum()), hl_shift=float(np.median(walsh)),
                   p_better=p_better, p_equal=p_equal, p_worse=p_worse, rope=rope,
                   verdict=_verdict(row["p_adjusted"], alpha, _direction(d), p_equal))
        rows.append(_resolve(row, d, row["family_size"], alpha, _seed(seed, problem, a, b), cap))
    out = pd.DataFrame(rows, columns=[*table.columns, "mean_rank_a", "mean_rank_b", "n_failed_a", "n_failed_b",
                                      "hl_shift", "p_better", "p_equal", "p_worse", "rope", "verdict",
                                      "p_floor", "mdd", "n_needed"])
    out["significant"] = out["p_adjusted"] < alpha
    out["alpha"] = alpha
    return out


def _rope_for(rope: float | Mapping[str, float] | None, problems: list[str]) -> dict:
    if not isinstance(rope, Mapping):
        return dict.fromkeys(problems, rope)
    unknown = sorted(set(rope) - set(problems))
    if unknown:
        raise StatsError(f"rope names unknown problems {unknown}; problems are {problems}")
    lacking = sorted(set(problems) - set(rope))
    if lacking:
        raise StatsError(f"rope has no value for the problems {lacking}")
    return dict(rope)


def verdicts(frame: pd.DataFrame, key: str = "instance", rope: float | Mapping[str, float] | None = 0.0,
             family: str = "leader", posthoc_test: str = "wilcoxon", alpha: float = 0.05, seed: int = 0,
             cap: int = res.N_CAP, against: str | None = None) -> Verdicts:
    """Friedman, mean ranks, CD and post-hoc verdicts of every problem of a tidy frame
    (``problem, optimizer, <key>, value``); ``rope``: one value or one per problem; ``against``:
    every optimiser against this row (k - 1 tests, Holm) instead of the leader, in the problems
    that have it."""
    if "problem" not in frame.columns:
        raise StatsError(f"the frame lacks the columns ['problem'] (pairing key {key!r})")
    problems = sorted(str(p) for p in frame["problem"].unique())
    ropes = _rope_for(rope, problems)
    omnibus, rank_rows, tables = [], [], []
    for problem in problems:
        block = block_matrix(frame, problem, key)
        stat, p = friedman(block)
        n, k = block.shape
        floor = res.design_floor(n, k, family, alpha) if k >= 2 else None
        omnibus.append({"problem": problem, "n_instances": n, "n_optimizers": k, "statistic": stat,
                        "p_value": p, "leader": leader_of(block), "cd": critical_difference(k, n, alpha),
                        "p_floor": floor.p_floor if floor else np.nan,
                        "reachable": bool(floor and floor.reachable), "alpha": alpha})
        for optimizer, r in mean_ranks(block).items():
            rank_rows.append({"problem": problem, "optimizer": optimizer, "mean_rank": r,
                              "n_failed": int(block[optimizer].isna().sum())})
        if k >= 2 and (against is None or against in block.columns):
            table = compare_block(block, ropes[problem], family, posthoc_test, alpha, seed, cap, problem, against)
            tables.append(table.assign(problem=problem))
    comparisons = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()
    if not comparisons.empty:
        comparisons = comparisons[["problem", *[c for c in comparisons.columns if c != "problem"]]]
    return Verdicts(pd.DataFrame(omnibus), pd.DataFrame(rank_rows), comparisons)


def cd_diagram(ranks: pd.Series | Mapping[str, float], cd: float, path: str | Path) -> Path:
    """Critical-difference diagram (Demsar 2006) of mean ranks to ``path`` (.png): the CD bar,
    and a crossbar joining optimisers whose mean ranks differ by less than ``cd``. Drawn by
    scikit-posthocs, saved without metadata that varies (``figures.save_figure``)."""
    import scikit_posthocs as sp
    from matplotlib.figure import Figure
    from matplotlib.transforms import blended_transform_factory

    from bench.report.figures import save_figure

    # rounded: mean ranks summed in another order (records read in another order) differ in the last
    # bits, which moves tied labels by a pixel and breaks the byte-identical rebuild
    ranks = pd.Series(ranks, dtype=float).round(9).sort_index()
    gap = np.abs(ranks.to_numpy()[:, None] - ranks.to_numpy()[None, :])
    # the diagram takes a p-matrix: 0 (different) where the rank gap exceeds the CD, else 1
    sig = pd.DataFrame(np.where(gap > cd, 0.0, 1.0), index=ranks.index, columns=ranks.index)
    fig = Figure(figsize=(6.0, 1.4 + 0.25 * len(ranks)))
    fig.subplots_adjust(left=0.2, right=0.8, top=0.62, bottom=0.04)  # room for the CD bar and the labels
    ax = fig.add_subplot()
    drawn = sp.critical_difference_diagram(ranks, sig, ax=ax, alpha=0.05)
    # the library draws each crossbar through a set's members in hash order, which varies between
    # processes (PYTHONHASHSEED) and moves anti-aliased pixels: redraw each through them in rank order
    for bar in (line for group in drawn["crossbars"] for line in group):
        bar.set_data(np.sort(bar.get_xdata()), bar.get_ydata())
    # the CD bar drawn here, not by the library, whose bar sits on the rank tick labels
    where = blended_transform_factory(ax.transData, ax.transAxes)
    x0 = float(ranks.min())
    ax.plot([x0, x0 + cd], [1.4, 1.4], color="k", lw=2, transform=where, clip_on=False)
    ax.text(x0 + cd / 2, 1.5, f"CD = {cd:.3g}", ha="center", va="bottom", fontsize=9, transform=where)
    return save_figure(fig, Path(path), pdf=False)
