"""The leaderboard: one row per (problem, optimizer) over its seeds, ranked within each problem.

Columns (``leaderboard``):
``problem, optimizer, rank`` (by median best f, ties averaged), ``n_runs`` (jobs, failed
included), ``n_failed`` (status not "ok", or no best f), ``best_f_median, best_f_q25,
best_f_q75, best_f_iqr, best_f_median_ci_low, best_f_median_ci_high`` (valid runs only),
``<metric>_median`` for every calibration metric of the records' ``best_metrics`` (``diverged``
is a 0/1 flag: its column is the rate ``diverged_rate``), ``main_target, ert_main_evals,
ert_main_seconds`` (COCO ERT of the problem's main target, see ``bench.targets``),
``evals_median, seconds_median`` (what runs used, failed runs included), and
``p_vs_leader`` (Holm-adjusted p of the test against the problem's leader) with
``vs_leader``: "leader", "yes" (significantly worse at alpha), "no", or "n/a" (untestable).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bench.stats import ranks

REQUIRED = ("problem", "optimizer", "seed", "status")
RATE_METRICS = ("diverged",)


class LeaderboardError(ValueError):
    """A record lacks a field the leaderboard needs; the message names the job folder."""


def _column(records: pd.DataFrame, name: str) -> pd.Series:
    if name in records.columns:
        return records[name]
    return pd.Series(np.nan, index=records.index)


def runs_table(records: pd.DataFrame) -> pd.DataFrame:
    """One tidy row per job from ``bench.records.load_records``.

    Columns: job_dir, problem, optimizer, seed, status, valid (status "ok" and a best f that is
    not NaN), best_f, n_evals, wall_s, f_truth, f_reference, error_type, error_message, and
    ``m.<metric>`` for each ``best_metrics.<metric>`` field. Sorted by problem, optimizer, seed.
    """
    if records.empty:
        raise LeaderboardError("no job records to tabulate")
    for name in REQUIRED:
        missing = records[name].isna() if name in records.columns else pd.Series(True, index=records.index)
        if missing.any():
            job = records.loc[missing, "job_dir"].iloc[0]
            raise LeaderboardError(f"{job}/record.json: missing the field {name!r}")
    seeds = pd.to_numeric(records["seed"], errors="coerce")
    bad_seed = seeds.isna() | (seeds != seeds.round())
    if bad_seed.any():
        job = records.loc[bad_seed, "job_dir"].iloc[0]
        raise LeaderboardError(f"{job}/record.json: seed {records.loc[bad_seed, 'seed'].iloc[0]!r} is not an integer")
    numeric = lambda name: pd.to_numeric(_column(records, name), errors="coerce").astype(float)  # noqa: E731
    runs = pd.DataFrame({
        "job_dir": records["job_dir"].astype(str),
        "problem": records["problem"].astype(str),
        "optimizer": records["optimizer"].astype(str),
        "seed": seeds.astype(int),
        "status": records["status"].astype(str),
        "best_f": numeric("best_f"),
        "n_evals": numeric("n_evals"),
        "wall_s": numeric("wall_s"),
        "f_truth": numeric("f_truth"),
        "f_reference": numeric("f_reference"),
        "error_type": _column(records, "error.type").astype(object).fillna("").astype(str),
        "error_message": _column(records, "error.message").astype(object).fillna("").astype(str),
    })
    runs.insert(5, "valid", (runs["status"] == "ok") & runs["best_f"].notna())
    for col in sorted(c for c in records.columns if c.startswith("best_metrics.")):
        runs["m." + col[len("best_metrics."):]] = pd.to_numeric(records[col], errors="coerce").astype(float)
    return runs.sort_values(["problem", "optimizer", "seed", "job_dir"], kind="stable").reset_index(drop=True)


def leaderboard(runs: pd.DataFrame, summary: pd.DataFrame, vs_leader: pd.DataFrame,
                ert: pd.DataFrame) -> pd.DataFrame:
    """Assemble the leaderboard (columns in the module doc) from its pieces.

    runs: ``runs_table``; summary: ``bench.stats.summary``; vs_leader: ``bench.stats.versus_leader``;
    ert: ``bench.targets.ert_table``. Sorted by problem, rank, optimizer.
    """
    keys = ["problem", "optimizer"]
    grouped = runs.groupby(keys, sort=True)
    board = pd.DataFrame({"n_runs": grouped.size(), "n_failed": grouped["valid"].apply(lambda v: int((~v).sum()))})
    board = board.reset_index()
    stats = summary.rename(columns={c: f"best_f_{c}" for c in summary.columns if c not in keys})
    board = board.merge(stats.drop(columns="best_f_n_valid"), on=keys, how="left")
    board = board.merge(ranks(summary), on=keys, how="left")
    board.insert(2, "rank", board.pop("rank"))
    valid = runs[runs["valid"]]
    for col in [c for c in runs.columns if c.startswith("m.")]:
        name = col[2:]
        how, suffix = ("mean", "rate") if name in RATE_METRICS else ("median", "median")
        board = board.merge(valid.groupby(keys)[col].agg(how).rename(f"{name}_{suffix}").reset_index(),
                            on=keys, how="left")
    main = ert[ert["main"].astype(bool)][keys + ["target", "ert_evals", "ert_seconds"]].rename(
        columns={"target": "main_target", "ert_evals": "ert_main_evals", "ert_seconds": "ert_main_seconds"})
    board = board.merge(main, on=keys, how="left")
    used = grouped.agg(evals_median=("n_evals", "median"), seconds_median=("wall_s", "median")).reset_index()
    board = board.merge(used, on=keys, how="left")
    test = vs_leader[["problem", "a", "p_holm", "significant"]].rename(
        columns={"a": "optimizer", "p_holm": "p_vs_leader", "significant": "vs_leader"})
    board = board.merge(test, on=keys, how="left")
    leader_rows = board["vs_leader"].isna() & board["best_f_median"].notna()
    first = board[leader_rows].sort_values(["problem", "best_f_median", "optimizer"]).groupby("problem").head(1)
    board.loc[first.index, "vs_leader"] = "leader"
    board["vs_leader"] = board["vs_leader"].fillna("n/a")
    return board.sort_values(["problem", "rank", "optimizer"], kind="stable").reset_index(drop=True)
