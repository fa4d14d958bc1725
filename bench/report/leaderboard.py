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
(what runs used, failed runs included); then the objective's paired verdict against the problem's
``leader`` (``bench.report.paired``: runs paired on instances, or on seeds for records without
them; the leader may be the reference calibration's row): ``p_holm_vs_leader`` (Holm-adjusted p,
or Nemenyi's, of the post-hoc test), ``p_holm_family`` (the size of that family),
``p_equal_vs_leader`` (posterior probability of practical equality within the ROPE),
``verdict`` ("leader", "better", "worse", "practically equal", "undecided", or "untestable"
when the optimiser has no complete block), ``n_needed`` (instances that would decide an
undecided comparison; inf beyond the cap) and ``alpha``.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from bench.errors import BenchError
from bench.report import resolution as res
from bench.report.paired import OBJECTIVE, REFERENCE, Paired, calibration_ranks, ranks_of
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
    instance = next((records[c] for c in INSTANCE_FIELDS if c in records.columns), None)
    if instance is not None:  # the pairing unit (bench.report.paired); integers, as the sweep numbers them
        runs["instance"] = pd.to_numeric(instance, errors="coerce").astype("Int64")
    runs["problem_name"], runs["optimizer_name"] = runs["problem"], runs["optimizer"]
    runs["problem"] = _labels(records, runs["problem_name"], PROBLEM_SETTINGS, runs.index, instances=instance)
    runs["optimizer"] = _labels(records, runs["problem"] + "\0" + runs["optimizer_name"], OPTIMIZER_SETTINGS,
                                runs.index, names=runs["optimizer_name"], instances=instance)
    _refuse_duplicate_seeds(runs)
    return runs.sort_values(["problem", "optimizer", "seed", "job_dir"], kind="stable").reset_index(drop=True)


# the record fields (flattened) that make two runs of one problem name different jobs, and their short labels
PROBLEM_SETTINGS = (("config.problem.params.", ""), ("budget.", "budget."))
OPTIMIZER_SETTINGS = (("config.optimizer.params.", ""),)
INSTANCE_FIELDS = ("instance", "config.instance")


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


def _labels(records: pd.DataFrame, groups: pd.Series, prefixes, index, names: pd.Series | None = None,
            instances: pd.Series | None = None) -> pd.Series:
    """``names`` (default: ``groups``) where a group holds one setting; ``name[key=value,...]`` (the
    keys that differ within the group) where it holds several. A setting that ``instances`` fixes
    (one value per instance, e.g. the data seed an instance draws) is part of the instance, not of
    the job's identity: it never splits a group."""
    settings = _settings(records, prefixes)
    names = groups if names is None else names
    out = names.copy()
    for _, idx in groups.groupby(groups).groups.items():
        distinct = sorted(set(settings[idx]))
        if len(distinct) < 2:
            continue
        parsed = {s: json.loads(s) for s in distinct}
        keys = sorted(k for k in set().union(*parsed.values())
                      if len({json.dumps(parsed[s].get(k), sort_keys=True) for s in distinct}) > 1
                      and not _fixed_by(instances, settings[idx], k))
        if not keys:  # every difference is one of the instances
            continue
        for i in idx:
            setting = parsed[settings[i]]
            shown = ",".join(f"{k}={json.dumps(setting.get(k), default=str)}" for k in keys)
            out[i] = f"{names[i]}[{shown}]"
    return out.reindex(index)


def _fixed_by(instances: pd.Series | None, settings: pd.Series, key: str) -> bool:
    """Whether setting ``key`` takes one value per instance among ``settings`` (records' JSON)."""
    if instances is None:
        return False
    values = settings.map(lambda s: json.dumps(json.loads(s).get(key), sort_keys=True))
    return bool((values.groupby(instances.reindex(settings.index)).nunique() <= 1).all())


def _refuse_duplicate_seeds(runs: pd.DataFrame) -> None:
    cols = ["problem", "optimizer", *(["instance"] if "instance" in runs.columns else []), "seed"]
    dup = runs[runs.duplicated(cols, keep=False)]
    if len(dup):
        first = dup.iloc[0]
        same = dup[(dup[cols] == first[cols]).all(axis=1)]
        where = f" of instance {first['instance']}" if "instance" in cols else ""
        raise LeaderboardError(
            f"seed {first['seed']}{where} of {first['problem']}/{first['optimizer']} is in {len(same)} records "
            f"({', '.join(same['job_dir'])}): the same job run more than once; report one of the folders "
            "so that no seed is counted twice")


def versus_leader(comparisons: pd.DataFrame, friedman: pd.DataFrame) -> pd.DataFrame:
    """Per (problem, optimizer) its comparison with the problem's leader, from the objective's
    paired verdicts (``bench.report.verdict``; a leader-family or all-pairs table, read from the
    optimiser's side): leader, p_holm_vs_leader, p_holm_family, p_equal_vs_leader,
    verdict, n_needed, alpha."""
    cols = ["problem", "optimizer", "leader", "p_holm_vs_leader", "p_holm_family", "p_equal_vs_leader",
            "verdict", "n_needed", "alpha"]
    if comparisons is None or comparisons.empty:
        return pd.DataFrame(columns=cols)
    leaders = friedman.set_index("problem")["leader"]
    c = comparisons.assign(leader=comparisons["problem"].map(leaders))
    flip = {"better": "worse", "worse": "better"}
    as_a = c[c["b"] == c["leader"]].rename(columns={"a": "optimizer"})
    as_b = c[c["a"] == c["leader"]].rename(columns={"b": "optimizer"})
    as_b = as_b.assign(verdict=as_b["verdict"].map(lambda v: flip.get(v, v)))
    both = pd.concat([as_a, as_b], ignore_index=True).rename(columns={
        "p_adjusted": "p_holm_vs_leader", "family_size": "p_holm_family", "p_equal": "p_equal_vs_leader"})
    return both[cols]


def leaderboard(runs: pd.DataFrame, summary: pd.DataFrame, comparisons: pd.DataFrame, friedman: pd.DataFrame,
                ert: pd.DataFrame) -> pd.DataFrame:
    """Assemble the leaderboard (columns in the module doc) from its pieces.

    runs: ``runs_table``; summary: ``bench.stats.summary``; comparisons, friedman: the objective's
    ``bench.report.verdict.verdicts`` tables (reference row included or not); ert:
    ``bench.targets.ert_table``. Sorted by problem, rank, optimizer.
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
    board = board.merge(versus_leader(comparisons, friedman), on=keys, how="left")
    leaders = friedman.set_index("problem")["leader"] if len(friedman) else pd.Series(dtype=object)
    board["leader"] = board["problem"].map(leaders)
    board["verdict"] = board["verdict"].fillna("untestable")
    # the leader by mean rank; when every run failed there is nothing to lead
    board.loc[(board["optimizer"] == board["leader"]) & board["best_f_median"].notna(), "verdict"] = "leader"
    if len(friedman):
        board["alpha"] = board["problem"].map(friedman.set_index("problem")["alpha"])
    board["p_holm_family"] = board.groupby("problem")["p_holm_family"].transform("max")
    return board.sort_values(["problem", "rank", "optimizer"], kind="stable").reset_index(drop=True)


# --- the page: the verdict box and the short leaderboard (bench.report.paired's verdicts) ----------

def _g(value) -> str:
    return "n/a" if value is None or (isinstance(value, float) and np.isnan(value)) else f"{value:.3g}"


def _needed(n) -> str:
    if n is None or np.isnan(n):
        return ""
    return f"more than {res.N_CAP}" if np.isinf(n) else f"about {int(n)}"


def _listing(rows: pd.DataFrame, leader_family: bool, with_p: bool) -> str:
    parts = []
    for r in rows.itertuples(index=False):
        who = r.a if leader_family else f"{r.a} vs {r.b}"
        if with_p:
            who += f" (p = {_g(r.p_adjusted)})"
        elif r.verdict == "undecided":
            need = _needed(r.n_needed)
            who += f" ({need} instances would decide it)" if need else " (not testable)"
        parts.append(who)
    return ", ".join(parts)


def _comparison_sentences(comp: pd.DataFrame, leader: str, rope, unit: str, leader_family: bool) -> list[str]:
    """Plain sentences of one problem's post-hoc table, grouped by verdict."""
    against = f" than the leader {leader}" if leader_family else ""
    lines = []
    if comp.empty:
        return ["No comparison: fewer than two rows with a shared instance."]
    for verdict, head in (("worse", f"Significantly worse{against} (Holm-adjusted p)"),
                          ("better", f"Significantly better{against} (Holm-adjusted p)"),
                          ("practically equal", f"Practically equal{' to ' + leader if leader_family else ''} "
                                                f"(posterior P(|difference| < ROPE = {_g(rope)} {unit}) >= 0.95)"),
                          ("undecided", "Undecided")):
        rows = comp[comp["verdict"] == verdict]
        if len(rows):
            lines.append(f"{head}: {_listing(rows, leader_family, verdict in ('worse', 'better'))}.")
    if leader_family:
        ties = [leader, *comp.loc[comp["verdict"] != "worse", "a"]]
        lines.insert(0, f"Tie with the leader (not shown worse): {', '.join(ties)}.")
    return lines


def _design_sentences(paired: Paired, problem: str, f: pd.Series) -> list[str]:
    """The design of one problem, and its floor when it cannot reach alpha (the first lines)."""
    s = paired.settings
    n, k = int(f["n_instances"]), int(f["n_optimizers"])
    floor = res.design_floor(n, k, s.family, s.alpha) if k >= 2 else None
    dropped = paired.dropped.get(OBJECTIVE, {}).get(problem, 0)
    lines = []
    if floor is not None and not floor.reachable:
        lines.append(f"{n} {paired.key}s cannot reach p < {s.alpha:g} with Holm over {floor.family_size} tests: the "
                     f"smallest reachable p is {floor.p_floor:.3g}; {floor.min_instances} {paired.key}s could.")
    lines.append(f"{n} {paired.key}s x {k} rows (the reference calibration included where known), paired on "
                 f"`{paired.key}`; Friedman p = {_g(f['p_value'])}; post-hoc: {s.test}, family `{s.family}`, "
                 f"alpha = {s.alpha:g}." + (f" {dropped} {paired.key}(s) left out: not every row ran them."
                                            if dropped else ""))
    return lines


def _median(runs: pd.DataFrame, problem: str, optimizer: str, column: str) -> float:
    rows = runs[(runs["problem"] == problem) & runs["valid"]]
    if optimizer == REFERENCE:
        ref = column.replace("m.", "ref.", 1) if column != OBJECTIVE else "f_reference"
        return float(rows[ref].median()) if ref in rows.columns else np.nan
    return float(rows.loc[rows["optimizer"] == optimizer, column].median())


def _calibration_sentences(paired: Paired, runs: pd.DataFrame, problem: str, leader: str) -> list[str]:
    """How the best calibrations compare with the reference and the truth; the two rankings."""
    errors = [q for q, v in paired.by_question.items() if q != OBJECTIVE and problem in set(v.ranks["problem"])]
    if not errors:
        return ["No calibration errors: the truth is unknown, only the objective is ranked."]
    parts = []
    for q in errors:
        vs = paired.vs_reference.get(q)
        row = (vs.comparisons[(vs.comparisons["problem"] == problem) & (vs.comparisons["a"] == leader)]
               if vs is not None and not vs.comparisons.empty else pd.DataFrame())
        text = f"{q} {_g(_median(runs, problem, leader, 'm.' + q))}"
        if f"ref.{q}" in runs.columns:
            text += f" (reference {_g(_median(runs, problem, REFERENCE, 'm.' + q))}"
            verdict = row["verdict"].iloc[0] if len(row) else ""
            text += (f"; {leader} {verdict} than the reference, p = {_g(row['p_adjusted'].iloc[0])})"
                     if verdict in ("better", "worse") else (f"; {verdict} against it)" if verdict else ")"))
        parts.append(text)
    who = "the reference calibration's" if leader == REFERENCE else f"{leader}'s"
    lines = [f"The objective's leader ({who} calibrations, median over instances) is this far from the truth: "
             + "; ".join(parts) + "."]
    ranks = calibration_ranks(paired, problem).sort_values(kind="stable")
    objective = ranks_of(paired.by_question[OBJECTIVE], problem)
    common = [o for o in objective.sort_values(kind="stable").index if o in ranks.index]
    order = [o for o in ranks.index if o in common]
    if common == order:
        lines.append(f"The two rankings agree: by objective and by calibration error, {', '.join(common)}.")
    elif common:
        lines.append(f"The two rankings disagree: by objective {', '.join(common)}; by calibration error (mean "
                     f"rank over {len(errors)} errors) {', '.join(order)}.")
    return lines


def verdict_box(paired: Paired, runs: pd.DataFrame) -> dict[str, list[str]]:
    """problem -> the verdict box's sentences, generated from the numbers (design and floor first)."""
    out = {}
    objective = paired.by_question.get(OBJECTIVE)
    units = runs.groupby("problem")["f_unit"].first() if "f_unit" in runs.columns else {}
    for f in objective.friedman.to_dict("records") if objective is not None else []:
        problem, leader = f["problem"], f["leader"]
        lines = ([paired.note[0].upper() + paired.note[1:] + "."] if paired.note else [])
        lines += _design_sentences(paired, problem, pd.Series(f))
        unit = str(units.get(problem, "")) if len(units) else ""
        u = f" {unit}" if unit else ""
        anchors = runs.loc[runs["problem"] == problem, ["f_reference", "f_truth"]].median()
        lines.append(f"Leader on the objective: {leader} (median f = {_g(_median(runs, problem, leader, OBJECTIVE))}"
                     f"{u}; at the reference calibration {_g(anchors['f_reference'])}{u}, at the truth "
                     f"{_g(anchors['f_truth'])}{u}).")
        comp = objective.comparisons
        comp = comp[comp["problem"] == problem] if not comp.empty else comp
        rope = comp["rope"].iloc[0] if len(comp) else np.nan
        lines += _comparison_sentences(comp, leader, rope, unit, paired.settings.family == "leader")
        vs = paired.vs_reference.get(OBJECTIVE)
        if vs is not None and not vs.comparisons.empty:
            ref = vs.comparisons[vs.comparisons["problem"] == problem]
            for verdict in ("better", "worse", "practically equal", "undecided"):
                names = ref.loc[ref["verdict"] == verdict, "a"].tolist()
                if names:
                    lines.append(f"On the objective, {verdict} than the reference calibration: {', '.join(names)}."
                                 .replace("practically equal than", "practically equal to")
                                 .replace("undecided than", "undecided against"))
        lines += _calibration_sentences(paired, runs, problem, leader)
        out[problem] = lines
    for problem in sorted(set(runs["problem"]) - set(out)):
        out[problem] = ([paired.note[0].upper() + paired.note[1:] + "."] if paired.note else []) + [
            f"No {paired.key} is shared by every row of this problem: no paired verdict (see runs.csv)."]
    return dict(sorted(out.items()))
