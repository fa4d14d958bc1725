"""The leaderboard: one row per (problem setting, optimizer setting) over its seeds, ranked within each problem.

**Grouping by job identity.** A row pools only runs of the same job but for the seed: same
problem and problem parameters (data seed included), same budget, same optimiser parameters.
``runs_table`` gives every run a ``problem`` and ``optimizer`` label; when the records of one
problem name differ in a setting, each setting becomes its own problem, labelled with what
differs (``sphere[budget.evals=500]``, ``synthetic[data_seed=1]``), and likewise optimisers
(``pso[pop_size=10]``); the plain names stay in ``problem_name``/``optimizer_name``. Two records
of the same labelled job and seed are refused (``LeaderboardError`` naming both folders): a
seed is never counted twice.

Columns (``leaderboard``), the same for every problem:
``problem, optimizer, rank`` (by median best f, ties averaged), ``n_runs`` (jobs, failed
included), ``n_failed`` (status not "ok", or no best f), ``best_f_median, best_f_q25,
best_f_q75, best_f_iqr, best_f_median_ci_low, best_f_median_ci_high`` (valid runs only),
``ci_level`` (of that bootstrap interval, e.g. 0.95), ``f_unit`` (the unit of f and of every
``best_f_*`` column and of the main target's threshold: "m" for the VIO position RMSE, "" when
the problem's f has no unit or its records do not say),
``<metric>_median`` for every calibration metric of the records' ``best_metrics`` (``diverged``
is a 0/1 flag: its column is the rate ``diverged_rate``), ``main_target,
main_target_threshold, ert_main_evals, ert_main_seconds`` (COCO ERT of the problem's main
target, see ``bench.targets``; the threshold in f's unit), ``evals_median, seconds_median``
(what runs used, failed runs included), ``p_holm_vs_leader`` (Holm-adjusted p of the test
against the problem's leader; the Holm family is all optimiser pairs of the problem, as in the
pairwise table, so the two tables agree pair by pair) with ``p_holm_family`` (how many tests
that family has), ``alpha`` and ``verdict``: "leader", "worse" (significantly worse at alpha
after correction), "not different", or "untestable" (fewer than 2 valid runs on a side).
``p_vs_leader`` and ``vs_leader`` ("leader"/"yes"/"no"/"n/a") are the same test under their
earlier names.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from bench.errors import BenchError
from bench.report.stats import ranks

REQUIRED = ("problem", "optimizer", "seed", "status")
RATE_METRICS = ("diverged",)


class LeaderboardError(BenchError):
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
    def numeric(name):
        return pd.to_numeric(_column(records, name), errors="coerce").astype(float)
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
    runs["f_unit"] = _column(records, "f_unit").astype(object).where(lambda v: v.notna(), "").astype(str)
    for col in sorted(c for c in records.columns if c.startswith("best_metrics.")):
        runs["m." + col[len("best_metrics."):]] = pd.to_numeric(records[col], errors="coerce").astype(float)
    runs["problem_name"], runs["optimizer_name"] = runs["problem"], runs["optimizer"]
    runs["problem"] = _labels(records, runs["problem_name"], PROBLEM_SETTINGS, runs.index)
    runs["optimizer"] = _labels(records, runs["problem"] + "\0" + runs["optimizer_name"], OPTIMIZER_SETTINGS,
                                runs.index, names=runs["optimizer_name"])
    _refuse_duplicate_seeds(runs)
    return runs.sort_values(["problem", "optimizer", "seed", "job_dir"], kind="stable").reset_index(drop=True)


# the record fields (flattened) that make two runs of one problem name different jobs, and their short labels
PROBLEM_SETTINGS = (("config.problem.params.", ""), ("budget.", "budget."))
OPTIMIZER_SETTINGS = (("config.optimizer.params.", ""),)


def _settings(records: pd.DataFrame, prefixes) -> pd.Series:
    """Per record, its settings under ``prefixes`` as a canonical JSON string (absent keys omitted)."""
    cols = [(c, short + c[len(p):]) for p, short in prefixes for c in records.columns if c.startswith(p)]

    def one(row) -> str:
        values = {}
        for col, label in cols:
            v = row[col]
            if isinstance(v, float) and np.isnan(v):
                continue
            values[label] = v.tolist() if isinstance(v, np.ndarray) else v
        return json.dumps(values, sort_keys=True, default=str)

    return records.apply(one, axis=1) if cols else pd.Series("{}", index=records.index)


def _labels(records: pd.DataFrame, groups: pd.Series, prefixes, index, names: pd.Series | None = None) -> pd.Series:
    """``names`` (default: ``groups``) where a group holds one setting; ``name[key=value,...]`` (the
    keys that differ within the group) where it holds several."""
    settings = _settings(records, prefixes)
    names = groups if names is None else names
    out = names.copy()
    for _, idx in groups.groupby(groups).groups.items():
        distinct = sorted(set(settings[idx]))
        if len(distinct) < 2:
            continue
        parsed = {s: json.loads(s) for s in distinct}
        keys = sorted(k for k in set().union(*parsed.values())
                      if len({json.dumps(parsed[s].get(k), sort_keys=True) for s in distinct}) > 1)
        for i in idx:
            setting = parsed[settings[i]]
            shown = ",".join(f"{k}={json.dumps(setting.get(k), default=str)}" for k in keys)
            out[i] = f"{names[i]}[{shown}]"
    return out.reindex(index)


def _refuse_duplicate_seeds(runs: pd.DataFrame) -> None:
    dup = runs[runs.duplicated(["problem", "optimizer", "seed"], keep=False)]
    if len(dup):
        first = dup.iloc[0]
        same = dup[(dup["problem"] == first["problem"]) & (dup["optimizer"] == first["optimizer"])
                   & (dup["seed"] == first["seed"])]
        raise LeaderboardError(
            f"seed {first['seed']} of {first['problem']}/{first['optimizer']} is in {len(same)} records "
            f"({', '.join(same['job_dir'])}): the same job run more than once; report one of the folders "
            "so that no seed is counted twice")


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
    units = (runs.groupby("problem")["f_unit"].agg(lambda u: ",".join(sorted(set(u) - {""})))
             if "f_unit" in runs.columns else pd.Series(dtype=str))
    board["f_unit"] = board["problem"].map(units).fillna("")
    extra = [c for c in ("ci_level",) if c in summary.columns]
    stats = summary.rename(columns={c: f"best_f_{c}" for c in summary.columns if c not in keys + extra})
    board = board.merge(stats.drop(columns="best_f_n_valid"), on=keys, how="left")
    unit = board.pop("f_unit")
    board.insert(board.columns.get_loc("best_f_median_ci_high") + 1 + len(extra), "f_unit", unit)
    board = board.merge(ranks(summary), on=keys, how="left")
    board.insert(2, "rank", board.pop("rank"))
    valid = runs[runs["valid"]]
    for col in [c for c in runs.columns if c.startswith("m.")]:
        name = col[2:]
        how, suffix = ("mean", "rate") if name in RATE_METRICS else ("median", "median")
        board = board.merge(valid.groupby(keys)[col].agg(how).rename(f"{name}_{suffix}").reset_index(),
                            on=keys, how="left")
    main = ert[ert["main"].astype(bool)][keys + ["target", "threshold", "ert_evals", "ert_seconds"]].rename(
        columns={"target": "main_target", "threshold": "main_target_threshold", "ert_evals": "ert_main_evals",
                 "ert_seconds": "ert_main_seconds"})
    board = board.merge(main, on=keys, how="left")
    used = grouped.agg(evals_median=("n_evals", "median"), seconds_median=("wall_s", "median")).reset_index()
    board = board.merge(used, on=keys, how="left")
    cols = ["problem", "a", "p_holm", "significant", "median_a", "median_b"] + \
        [c for c in ("family_size", "alpha") if c in vs_leader.columns]
    test = vs_leader[cols].rename(columns={"a": "optimizer", "p_holm": "p_vs_leader", "significant": "vs_leader",
                                           "family_size": "p_holm_family"})
    board = board.merge(test, on=keys, how="left")
    leader_rows = board["vs_leader"].isna() & board["best_f_median"].notna()
    first = board[leader_rows].sort_values(["problem", "best_f_median", "optimizer"]).groupby("problem").head(1)
    board.loc[first.index, "vs_leader"] = "leader"
    board["vs_leader"] = board["vs_leader"].fillna("n/a")
    board["p_holm_vs_leader"] = board["p_vs_leader"]
    worse = (board["vs_leader"] == "yes") & (board["median_a"] > board["median_b"])
    board["verdict"] = np.select(
        [board["vs_leader"] == "leader", worse, board["vs_leader"] == "yes", board["vs_leader"] == "no"],
        ["leader", "worse", "different", "not different"], default="untestable")
    board = board.drop(columns=["median_a", "median_b"])
    if "p_holm_family" not in board.columns:
        board["p_holm_family"] = np.nan
    if "alpha" not in board.columns:
        board["alpha"] = np.nan
    fam = board.groupby("problem")["p_holm_family"].transform("max")
    board["p_holm_family"] = fam.fillna(0).astype(int)
    board["alpha"] = board.groupby("problem")["alpha"].transform("max")
    board["vs_leader"] = board.pop("vs_leader")  # kept the last column, as before
    return board.sort_values(["problem", "rank", "optimizer"], kind="stable").reset_index(drop=True)
