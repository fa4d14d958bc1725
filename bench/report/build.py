"""The benchmark report: every table, statistic and figure, rebuilt from run records.

Usage::

    python -m bench.report DIR... [--out OUT] [--test wilcoxon|nemenyi|conover] [--family leader|all]
        [--rope X | --rope PROBLEM=X,...] [--alpha 0.05] [--key instance] [--no-tables] [--recompute]

finds every job folder (one holding ``record.json``) under the DIRs and writes into OUT
(default: the first DIR's ``report/``):

- ``report.html`` and ``report.md`` open with the **verdict box**: plain sentences generated from
  the paired verdicts (``bench.report.paired``, ``bench.report.leaderboard.verdict_box``): the
  design and, when it cannot reach alpha, its floor; the leader and who ties with it; who is
  significantly worse or better (Holm-adjusted p); who is practically equal (ROPE); what is
  undecided and how many instances would decide it; how the optimisers and the best
  calibrations compare with the reference calibration and the truth; where the objective's and
  the calibration error's rankings disagree. The verdict settings are the sweep's (``verdict:``
  in its config) unless the options above override them;
- ``leaderboard.csv`` — one row per (problem, optimizer), see ``bench.report.leaderboard`` (the
  page shows ten of its columns: ``bench.report.paired.PAGE_COLUMNS``);
- ``verdicts.csv`` — every paired comparison of every question (the objective ``best_f`` and each
  calibration error), ``family`` "posthoc" (against the leader, or all pairs) or "vs_reference";
  ``friedman.csv`` — the omnibus test, leader, CD and design floor per question and problem;
- ``runs.csv`` — one row per job (with ``ref.<error>``, the reference's errors on its instance);
  ``ranks.csv`` (average rank by median over problems);
- ``targets.csv``, ``ert.csv``, ``ecdf.csv`` — fixed targets, ERT and runtime ECDFs, see
  ``bench.targets``; ``curves.csv`` — anytime curves, see ``bench.curves``;
- ``figures/``: per problem ``cd_`` (critical-difference diagram), ``final_`` (final values per
  optimiser and the reference), ``anytime_``, ``scatter_`` (objective against calibration error,
  where the truth is known) and ``ecdf_<problem>.png`` (150 dpi; PDF beside all but ``cd_``);
- ``tables/`` — the paper's Tables 1–3 and figures (``bench.report.paper.tables``), when the records hold a
  VIO problem (``--no-tables`` skips them). What they need from the filter is computed once
  and stored in ``DIR/artifacts/`` (``bench.report.paper.artifacts``); later reports read it back and never
  re-run the VIO unless ``--recompute`` is given;
- ``report.html`` — the whole report as one self-contained page (``bench.report.html``):
  every figure embedded, sortable tables, the provenance of the records;
- ``report.md`` — the same as a Markdown document linking the files;
- ``evaluations.parquet`` — every evaluation of every job, one row each (job identity, batch,
  evaluation index, f, the variables by name, the log's times, the metrics), see
  ``bench.report.evaluations``; ``pandas.read_parquet`` reads it in one call;
- ``iohprofiler/`` — the runs in the IOHprofiler format that IOHanalyzer loads (one function per
  problem setting, one algorithm per optimiser, one run per job), written by ``ioh``'s logger,
  see ``bench.report.evaluations``.

Same records, same options → byte-identical CSV, Markdown, HTML, PNG, Parquet and IOHprofiler files: nothing written
depends on the time, the machine or where the folders are (job folders are named relative to
the DIR they were found in; the provenance shown is the records'). Progress goes to stderr,
the path of report.md to stdout. Bad input (a missing DIR, no records, a corrupt record or
log, an unknown test or family, a negative ROPE or one for an unknown problem, ``--alpha``
outside (0, 1), a pairing key the records lack) ends with one message on stderr naming the key
and exit code 2, before any output.
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from bench.errors import BenchError
from bench.records import find_job_dirs, read_record
from bench.report.curves import anytime_curves, run_traces
from bench.report.figures import anytime_figure, ecdf_figure, final_values_figure, objective_error_figure
from bench.report.leaderboard import leaderboard, runs_table, verdict_box
from bench.report.paired import (
    INSTANCE_SEED,
    OBJECTIVE,
    REFERENCE,
    VerdictSettings,
    add_reference_errors,
    check_settings,
    page_leaderboard,
    paired_verdicts,
    pairing_key,
    sweep_settings,
    tidy,
)
from bench.report.stats import average_ranks, ranks, summary
from bench.report.targets import ecdf, ert_table, hitting_times, problem_targets, targets_table
from bench.report.verdict import cd_diagram

FLOAT_FORMAT = "%.8g"
MD_FLOAT = ".4g"


class ReportError(BenchError):
    """The report cannot be built from the given folders; the message says why."""


def load_job_records(roots: list[Path]) -> pd.DataFrame:
    """Every job record under ``roots`` as one flattened row (``bench.records.load_records``),
    with ``job`` = the job folder relative to the root it was found in (for stable output)."""
    resolved = [Path(r).resolve() for r in roots]
    rows = []
    for job_dir in find_job_dirs(roots):
        try:
            record = read_record(job_dir)
        except TypeError:  # valid JSON that is not an object: read_record cannot label it
            raise ReportError(f"{job_dir}/record.json: not a JSON object") from None
        root = next(r for r in resolved if job_dir == r or r in job_dir.parents)
        rel = job_dir.relative_to(root).as_posix()
        record["job"] = root.name if rel == "." else f"{root.name}/{rel}"
        rows.append(record)
    if not rows:
        raise ReportError(f"no job records (record.json) found under {', '.join(map(str, roots))}")
    return pd.json_normalize(rows, sep=".")


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "problem"


def _write_csv(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False, float_format=FLOAT_FORMAT, lineterminator="\n")
    return path


def _md_table(frame: pd.DataFrame) -> str:
    if frame.empty:
        return "_(none)_"
    return frame.to_markdown(index=False, floatfmt=MD_FLOAT)


def _paper_tables(dirs: list[Path], out: Path, recompute: bool, log) -> tuple[list[Path], str]:
    """The paper's Tables 1–3 and figures: (files written, note for the report when none were)."""
    from bench.report.paper.tables import TablesError, build_tables  # imports the VIO stack only when needed

    try:
        return [Path(p) for p in build_tables(dirs, out / "tables", recompute=recompute, log=log)], ""
    except TablesError as err:
        log(f"report: the paper's tables were not built: {err}")
        return [], f"Not built: {err}."


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _settings(roots: list[Path], records: pd.DataFrame, runs: pd.DataFrame,
              overrides: dict) -> tuple[VerdictSettings, pd.DataFrame]:
    """The sweep's verdict settings with the command line's overrides, checked against the
    records, and ``runs`` with the pairing key's column when it is another record field."""
    problems = sorted(set(runs["problem"]) | set(runs["problem_name"]))
    settings = check_settings({**sweep_settings(roots, records), **overrides}, problems)
    if settings.key not in runs.columns and settings.key in records.columns:
        runs = runs.assign(**{settings.key: runs["job_dir"].map(
            dict(zip(records["job_dir"].astype(str), records[settings.key])))})
    if pairing_key(runs, settings)[0] == INSTANCE_SEED:  # a key the records lack: SettingsError before any work
        runs = runs.assign(**{INSTANCE_SEED: runs["instance"].astype(str) + "/" + runs["seed"].astype(str)})
    return settings, runs


def _verdict_tables(paired) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(verdicts.csv: every comparison of every question; friedman.csv: the omnibus per question)."""
    comps, omni = [], []
    for family, tables in (("posthoc", paired.by_question), ("vs_reference", paired.vs_reference)):
        for question, v in tables.items():
            if not v.comparisons.empty:
                comps.append(v.comparisons.assign(question=question, family=family))
            if family == "posthoc":
                omni.append(v.friedman.assign(question=question))
    comparisons = pd.concat(comps, ignore_index=True) if comps else pd.DataFrame(columns=["question", "family"])
    friedman = pd.concat(omni, ignore_index=True) if omni else pd.DataFrame(columns=["question"])
    first = ["question", "family"]
    return (comparisons[first + [c for c in comparisons.columns if c not in first]],
            friedman[["question"] + [c for c in friedman.columns if c != "question"]])


def _figures(runs, curves, ecdfs, paired, out: Path) -> dict[str, dict[str, Path]]:
    """Per problem: its anytime, ECDF, critical-difference, final-value and objective-vs-error figures."""
    figures, used = {}, set()
    objective = paired.by_question.get(OBJECTIVE)
    frame = (tidy(runs, paired.key, OBJECTIVE, "f_reference")[0] if objective is not None
             else pd.DataFrame(columns=["problem", "optimizer", "value"]))
    errors = [q for q in paired.by_question if q != OBJECTIVE]
    for problem in sorted(runs["problem"].unique()):
        slug = _slug(problem)
        while slug in used:  # distinct problems whose names reduce to the same file name
            slug += "_"
        used.add(slug)
        anchors = runs.loc[runs["problem"] == problem, ["f_truth", "f_reference"]].median()
        levels = {"f at truth": anchors["f_truth"], "f at reference": anchors["f_reference"]}
        unit = runs.loc[runs["problem"] == problem, "f_unit"].iloc[0]
        fig = {"anytime": anytime_figure(curves, problem, out / "figures" / f"anytime_{slug}.png", levels),
               "ecdf": ecdf_figure(ecdfs, problem, out / "figures" / f"ecdf_{slug}.png"),
               "final": final_values_figure(frame, problem, out / "figures" / f"final_{slug}.png", unit, REFERENCE)}
        if objective is not None and problem in set(objective.friedman["problem"]):
            row = objective.friedman.set_index("problem").loc[problem]
            ranks = objective.ranks[objective.ranks["problem"] == problem].set_index("optimizer")["mean_rank"]
            if len(ranks) >= 2 and np.isfinite(row["cd"]):
                fig["cd"] = cd_diagram(ranks, float(row["cd"]), out / "figures" / f"cd_{slug}.png")
        if errors:
            fig["scatter"] = objective_error_figure(runs, problem, errors, out / "figures" / f"scatter_{slug}.png")
        figures[problem] = fig
    return figures


def build_report(dirs, out=None, *, verdict: dict | None = None, seed: int = 0, paper_tables: bool = True,
                 recompute: bool = False, log: Callable[[str], None] | None = _stderr) -> Path:
    """Build the whole report from the job folders under ``dirs``; return the path of report.md.

    dirs: folders (or job folders) to search; out: output folder (default ``dirs[0]/report``);
    verdict: overrides of the sweep's verdict settings (test, family, rope, alpha, key; see
    ``bench.report.paired``); seed: for the bootstrap intervals and the Bayesian test's sampling;
    paper_tables: also build the paper's Tables 1–3 and figures through
    ``bench.report.paper.tables``; recompute: re-run the VIO for them even when stored artifacts match;
    log: where progress lines go (default stderr; None for silence).
    Raises ReportError / RecordError / LeaderboardError / SettingsError on bad input.
    """
    log = log or (lambda message: None)
    overrides = {k: v for k, v in (verdict or {}).items() if v is not None}
    check_settings(overrides)  # bad options stop here, before the records are read
    roots = [Path(d) for d in dirs]
    if not roots:
        raise ReportError("no input folder given")
    out = Path(out) if out is not None else roots[0] / "report"
    started = time.perf_counter()
    records = load_job_records(roots)  # bad input stops here, before any output
    runs = add_reference_errors(runs_table(records), records)
    settings, runs = _settings(roots, records, runs, overrides)
    log(f"report: {len(runs)} job records under {', '.join(map(str, roots))}; paired verdicts, leaderboard, "
        "targets and curves")
    job_label = dict(zip(records["job_dir"].astype(str), records["job"]))
    traces = run_traces(runs)
    curves = pd.concat([anytime_curves(traces, axis) for axis in ("evals", "seconds")], ignore_index=True)
    targets = problem_targets(runs, traces)
    hits = hitting_times(runs, traces, targets)
    ert = ert_table(hits, targets)
    ecdfs = pd.concat([ecdf(hits, axis) for axis in ("evals", "seconds")], ignore_index=True)
    summ = summary(runs, seed=seed)
    paired = paired_verdicts(runs, settings, seed=seed)
    comparisons, friedman = _verdict_tables(paired)
    objective = paired.by_question.get(OBJECTIVE)
    board = leaderboard(runs, summ, objective.comparisons if objective else pd.DataFrame(),
                        objective.friedman if objective else pd.DataFrame(), ert)
    avg = average_ranks(ranks(summ))

    out.mkdir(parents=True, exist_ok=True)
    runs_out = runs.assign(job_dir=runs["job_dir"].map(job_label)).rename(columns={"job_dir": "job"})
    for name, frame in [("leaderboard", board), ("runs", runs_out), ("verdicts", comparisons),
                        ("friedman", friedman), ("ranks", avg), ("targets", targets_table(targets)),
                        ("ert", ert), ("ecdf", ecdfs), ("curves", curves)]:
        _write_csv(frame, out / f"{name}.csv")
    log("report: evaluations.parquet and the IOHprofiler export")
    from bench.report.evaluations import write_evaluations, write_iohprofiler

    write_evaluations(records, runs, out / "evaluations.parquet")
    write_iohprofiler(runs, out / "iohprofiler")
    log("report: drawing the figures")
    figures = _figures(runs, curves, ecdfs, paired, out)
    if paper_tables:
        log("report: the paper's tables and figures")
    tables = (_paper_tables(roots, out, recompute, log) if paper_tables
              else ([], "Not built: disabled for this report."))
    box = verdict_box(paired, runs)
    pages = {p: page_leaderboard(paired, runs, p) for p in sorted(runs["problem"].unique())}
    text = _markdown(runs_out, box, pages, avg, comparisons, ert, targets_table(targets), figures, tables, out)
    path = out / "report.md"
    path.write_text(text)
    log("report: writing report.html")
    from bench.report.html import build_page

    (out / "report.html").write_text(build_page(
        roots=roots, records=records, runs=runs_out, box=box, pages=pages, board=board, avg=avg,
        comparisons=comparisons, ert=ert, targets=targets_table(targets), figures=figures, tables=tables,
        definitions=_DEFINITIONS))
    log(f"report: done in {time.perf_counter() - started:.1f} s -> {out}")
    return path


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


VERDICT_COLUMNS = ["a", "b", "n", "p_adjusted", "p_equal", "rope", "hl_shift", "verdict", "p_floor", "mdd",
                   "n_needed"]


def _md_figure(path: Path | None, caption: str, out: Path) -> list[str]:
    return [f"![{caption}]({path.relative_to(out).as_posix()})", ""] if path is not None else []


def _markdown(runs, box, pages, avg, comparisons, ert, targets, figures, tables, out) -> str:
    from bench.report.html import calibration_table

    n_failed = int((~runs["valid"]).sum())
    lines = ["# Benchmark report", "", "## Verdict", ""]
    for problem, sentences in box.items():
        lines += [f"**{problem}**", ""] + [f"- {s}" for s in sentences] + [""]
    lines += [
        f"Built from {_count(len(runs), 'job record')}: {_count(runs['problem'].nunique(), 'problem')}, "
        f"{_count(runs['optimizer'].nunique(), 'optimiser')}, {n_failed} failed or without result. "
        "Rebuild with `python -m bench.report DIR... --out OUT`; every number below is computed "
        "from the records and is in the CSV files next to this report.",
        "",
        "Files: [leaderboard.csv](leaderboard.csv) (every column) · [verdicts.csv](verdicts.csv) · "
        "[friedman.csv](friedman.csv) · [runs.csv](runs.csv) · "
        "[ranks.csv](ranks.csv) · [targets.csv](targets.csv) · "
        "[ert.csv](ert.csv) · [ecdf.csv](ecdf.csv) · [curves.csv](curves.csv) · "
        "[evaluations.parquet](evaluations.parquet) (every evaluation) · "
        "[iohprofiler/](iohprofiler/) (for IOHanalyzer)",
        "",
    ]
    for problem in sorted(runs["problem"].unique()):
        fig = figures[problem]
        comp = comparisons[comparisons["problem"] == problem] if len(comparisons) else comparisons
        lines += [f"## Problem `{problem}`", "", "### Leaderboard", "", _md_table(pages[problem]), ""]
        lines += _md_figure(fig.get("cd"), f"critical-difference diagram for {problem}", out)
        lines += _md_figure(fig.get("final"), f"final values for {problem}", out)
        lines += _md_figure(fig["anytime"], f"anytime curves for {problem}", out)
        cal = calibration_table(runs, problem)
        if not cal.empty:
            lines += ["### Calibration errors (median of the final best points; the reference as a row)", "",
                      _md_table(cal), ""]
        lines += _md_figure(fig.get("scatter"), f"objective against calibration error for {problem}", out)
        lines += ["### Paired comparisons (every question)", "",
                  _md_table(comp[["question", "family", *VERDICT_COLUMNS]] if len(comp) else comp), "",
                  "### Fixed targets and expected running time (ERT)", "",
                  _md_table(targets[targets["problem"] == problem].drop(columns="problem")), "",
                  _md_table(ert[ert["problem"] == problem][["optimizer", "target", "n_runs", "n_hit",
                                                            "ert_evals", "ert_seconds"]]), ""]
        lines += _md_figure(fig["ecdf"], f"runtime ECDF for {problem}", out)
    lines += ["## Average rank over problems", "",
              "Rank within a problem by median final best f (1 = best, ties averaged); mean over the problems "
              "an optimiser ran.", "", _md_table(avg), ""]
    lines += _paper_tables_markdown(tables, out)
    failed = runs[~runs["valid"]][["job", "problem", "optimizer", "seed", "status", "error_type",
                                   "error_message"]]
    lines += ["## Failed runs", "",
              "Counted in `n_failed`, ranked last in the paired verdicts, excluded from medians, included in ERT "
              "and ECDF as unsuccessful with what they spent.", "", _md_table(failed), ""]
    lines += [_DEFINITIONS]
    return "\n".join(lines).rstrip() + "\n"


def _paper_tables_markdown(tables: tuple[list[Path], str], out: Path) -> list[str]:
    """The report's section listing the paper's tables, each Markdown table inline."""
    lines = ["## Paper tables (Tables 1–3)", ""]
    paths, note = tables
    if note:
        lines += [f"_{note}_", ""]
    for path in paths:
        rel = path.relative_to(out).as_posix()
        lines += [f"- [{rel}]({rel})"]
        if path.suffix == ".md":
            lines += ["", path.read_text().rstrip(), ""]
    return lines + [""]

_DEFINITIONS = """## Definitions

- **best f**: the lowest objective value a run evaluated (its record's `best_f`). A run is
  *valid* when its status is "ok" and it has a best f; others count as failed.
- **Verdicts** (``bench.report.paired``, ``bench.report.verdict``): runs are paired on the sweep's
  instances (records without an instance: on seeds, said in the verdict box's first line); per
  question and problem, Friedman over all rows (optimisers and the reference calibration), then
  the post-hoc family (default: each against the leader, the best mean rank; Wilcoxon
  signed-rank with Holm) and a Bayesian signed-rank test with a ROPE. A verdict is *better* /
  *worse* (Holm-adjusted p < alpha), *practically equal* (posterior of the ROPE >= 0.95) or
  *undecided*, with the number of instances that would decide it. Failed runs rank last.
- **Floor**: n instances with Holm over m tests cannot give p below m·2/2^n (exact signed-rank
  test); the verdict box says so when that is not below alpha.
- **Reference row**: f at the reference calibration (the records' ``f_reference``) and its
  errors against the truth on each instance, tested like an optimiser, and as the control of
  its own family ("vs reference" in the leaderboard and ``verdicts.csv``).
- **Calibration rank**: the mean over the calibration errors of each row's mean rank per error.
- **Median CI**: 95 % percentile bootstrap (2000 resamples, seeded).
- **Targets**: objective within 1 %, 5 %, 10 % of `f_truth` (f <= f_truth·(1+p)); with
  `f_truth` = 0 the gap from the reference point closed to within p (f <= p·f_reference);
  with no truth, the same around the best f found by any run; calibration metrics of the
  incumbent: rotation error below 0.5° and 0.1°, focal error below 1 px. A run hits a target
  at the end of the first batch whose incumbent meets it. The main target (leaderboard ERT)
  is the 5 % objective target.
- **ERT** (COCO): evaluations (or seconds) spent by all runs — successful ones until their
  hit, unsuccessful and failed ones in full — divided by the number of successful runs;
  infinite when none succeeds.
- **ECDF**: fraction of (run, target) pairs of a problem hit within a budget, over all runs.
- **Anytime curves**: best-so-far f at batch ends; median and inter-quartile band over runs;
  a run that stopped keeps its final value.
- **Tables 2–3 rows**: per optimiser and state, the run (seed) whose RMSE of that state is the
  median over its seeds (the lower middle one for an even count), with that run's mean, std and
  drift: every number of a row comes from one run. The paper's values stand beside ours only on
  the drives that stand for the paper's (a simulated or replayed ~540 m / ~928 m drive), and
  the captions say what is real and what is simulated.
- **Drift** (KITTI odometry devkit): over segments starting every 10 frames, `t_rel` = mean
  translation error / length (%) and `r_rel` = mean rotation error / length (deg/100 m) over
  segments of 100–800 m shorter than the drive; `drift_m_per_m` the same per metre (on drives
  of 100 m or less over 10 m, or up to 10 m over 1 m, segments); `max_jump_m` the largest
  one-frame position jump error.
- **Filter artifacts**: what the tables and figures need from the VIO is computed by the first
  report of a sweep and stored in `<sweep>/artifacts/` (CSV, JSON, npz; no pickle), keyed by
  the problem config and the runs' best points; `--recompute` re-runs it.
"""

