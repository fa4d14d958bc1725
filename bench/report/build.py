"""The benchmark report: every table, statistic and figure, rebuilt from run records.

Usage::

    python -m bench.report DIR... [--out OUT] [--pairing none|seed] [--alpha 0.05] [--no-tables] [--recompute]

finds every job folder (one holding ``record.json``) under the DIRs and writes into OUT
(default: the first DIR's ``report/``):

- ``leaderboard.csv`` — one row per (problem, optimizer), see ``bench.leaderboard``;
- ``runs.csv`` — one row per job; ``pairwise.csv``, ``versus_leader.csv``, ``ranks.csv``
  (average rank over problems) — see ``bench.stats``;
- ``targets.csv``, ``ert.csv``, ``ecdf.csv`` — fixed targets, ERT and runtime ECDFs, see
  ``bench.targets``; ``curves.csv`` — anytime curves, see ``bench.curves``;
- ``figures/anytime_<problem>.png``, ``figures/ecdf_<problem>.png`` (150 dpi, PDF beside);
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
log, ``--alpha`` outside (0, 1)) ends with one message on stderr and exit code 2.
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path
from typing import Callable

import pandas as pd

from bench.errors import BenchError
from bench.records import find_job_dirs, read_record
from bench.report.curves import anytime_curves, run_traces
from bench.report.figures import anytime_figure, ecdf_figure
from bench.report.leaderboard import leaderboard, runs_table
from bench.report.stats import average_ranks, pairwise, ranks, summary, versus_leader
from bench.report.targets import ecdf, ert_table, hitting_times, problem_targets, targets_table

FLOAT_FORMAT = "%.8g"
MD_FLOAT = ".4g"
LEADERBOARD_MD_COLUMNS = ["rank", "optimizer", "n_runs", "n_failed", "best_f_median", "best_f_iqr",
                          "best_f_median_ci_low", "best_f_median_ci_high", "ert_main_evals",
                          "evals_median", "seconds_median", "f_unit", "p_holm_vs_leader", "verdict"]


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


def check_alpha(alpha) -> float:
    """``alpha`` as a float in (0, 1), else ReportError naming the option."""
    try:
        value = float(alpha)
    except (TypeError, ValueError):
        raise ReportError(f"--alpha must be a number in (0, 1), got {alpha!r}") from None
    if not 0.0 < value < 1.0:
        raise ReportError(f"--alpha must be in (0, 1), got {alpha!r}")
    return value


def build_report(dirs, out=None, *, pairing: str = "none", alpha: float = 0.05, seed: int = 0,
                 paper_tables: bool = True, recompute: bool = False,
                 log: Callable[[str], None] | None = _stderr) -> Path:
    """Build the whole report from the job folders under ``dirs``; return the path of report.md.

    dirs: folders (or job folders) to search; out: output folder (default ``dirs[0]/report``);
    pairing: "none" (Mann–Whitney) or "seed" (Wilcoxon where seeds match), see ``bench.stats``;
    alpha: significance level after Holm correction, in (0, 1); seed: for the bootstrap
    intervals; paper_tables: also build the paper's Tables 1–3 and figures through
    ``bench.report.paper.tables``; recompute: re-run the VIO for them even when stored artifacts match;
    log: where progress lines go (default stderr; None for silence).
    Raises ReportError / RecordError / LeaderboardError on bad input.
    """
    log = log or (lambda message: None)
    alpha = check_alpha(alpha)
    roots = [Path(d) for d in dirs]
    if not roots:
        raise ReportError("no input folder given")
    out = Path(out) if out is not None else roots[0] / "report"
    started = time.perf_counter()
    records = load_job_records(roots)  # bad input stops here, before any output
    runs = runs_table(records)
    log(f"report: {len(runs)} job records under {', '.join(map(str, roots))}; leaderboard, statistics, "
        "targets and curves")
    job_label = dict(zip(records["job_dir"].astype(str), records["job"]))
    traces = run_traces(runs)
    curves = pd.concat([anytime_curves(traces, axis) for axis in ("evals", "seconds")], ignore_index=True)
    targets = problem_targets(runs, traces)
    hits = hitting_times(runs, traces, targets)
    ert = ert_table(hits, targets)
    ecdfs = pd.concat([ecdf(hits, axis) for axis in ("evals", "seconds")], ignore_index=True)
    summ = summary(runs, seed=seed)
    vs = versus_leader(runs, summ, pairing, alpha)
    pairs = pairwise(runs, pairing, alpha)
    avg = average_ranks(ranks(summ))
    board = leaderboard(runs, summ, vs, ert)

    out.mkdir(parents=True, exist_ok=True)
    runs_out = runs.assign(job_dir=runs["job_dir"].map(job_label)).rename(columns={"job_dir": "job"})
    for name, frame in [("leaderboard", board), ("runs", runs_out), ("pairwise", pairs),
                        ("versus_leader", vs), ("ranks", avg), ("targets", targets_table(targets)),
                        ("ert", ert), ("ecdf", ecdfs), ("curves", curves)]:
        _write_csv(frame, out / f"{name}.csv")
    log("report: evaluations.parquet and the IOHprofiler export")
    from bench.report.evaluations import write_evaluations, write_iohprofiler

    write_evaluations(records, runs, out / "evaluations.parquet")
    write_iohprofiler(runs, out / "iohprofiler")
    log("report: drawing the anytime and ECDF figures")
    figures, used = {}, set()
    for problem in sorted(runs["problem"].unique()):
        slug = _slug(problem)
        while slug in used:  # distinct problems whose names reduce to the same file name
            slug += "_"
        used.add(slug)
        anchors = runs.loc[runs["problem"] == problem, ["f_truth", "f_reference"]].median()
        levels = {"f at truth": anchors["f_truth"], "f at reference": anchors["f_reference"]}
        figures[problem] = (anytime_figure(curves, problem, out / "figures" / f"anytime_{slug}.png", levels),
                            ecdf_figure(ecdfs, problem, out / "figures" / f"ecdf_{slug}.png"))
    if paper_tables:
        log("report: the paper's tables and figures")
    tables = (_paper_tables(roots, out, recompute, log) if paper_tables
              else ([], "Not built: disabled for this report."))
    text = _markdown(runs_out, board, avg, pairs, ert, targets_table(targets), figures, tables, out,
                     pairing, alpha)
    path = out / "report.md"
    path.write_text(text)
    log("report: writing report.html")
    from bench.report.html import build_page

    (out / "report.html").write_text(build_page(
        roots=roots, records=records, runs=runs_out, board=board, avg=avg, pairs=pairs, vs=vs, ert=ert,
        targets=targets_table(targets), figures=figures, tables=tables, out=out, pairing=pairing, alpha=alpha,
        definitions=_DEFINITIONS))
    log(f"report: done in {time.perf_counter() - started:.1f} s -> {out}")
    return path


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _markdown(runs, board, avg, pairs, ert, targets, figures, tables, out, pairing, alpha) -> str:
    n_failed = int((~runs["valid"]).sum())
    test = "Mann–Whitney U" if pairing == "none" else "Wilcoxon signed-rank where seeds match, else Mann–Whitney U"
    lines = [
        "# Benchmark report",
        "",
        f"Built from {_count(len(runs), 'job record')}: {_count(runs['problem'].nunique(), 'problem')}, "
        f"{_count(runs['optimizer'].nunique(), 'optimiser')}, {n_failed} failed or without result. "
        "Rebuild with `python -m bench.report DIR... --out OUT`; every number below is computed "
        "from the records and is in the CSV files next to this report.",
        "",
        "Files: [leaderboard.csv](leaderboard.csv) · [runs.csv](runs.csv) · [pairwise.csv](pairwise.csv) · "
        "[versus_leader.csv](versus_leader.csv) · [ranks.csv](ranks.csv) · [targets.csv](targets.csv) · "
        "[ert.csv](ert.csv) · [ecdf.csv](ecdf.csv) · [curves.csv](curves.csv) · "
        "[evaluations.parquet](evaluations.parquet) (every evaluation) · "
        "[iohprofiler/](iohprofiler/) (for IOHanalyzer)",
        "",
        "## Average rank over problems",
        "",
        "Rank within a problem by median final best f (1 = best, ties averaged); mean over the problems "
        "an optimiser ran.",
        "",
        _md_table(avg),
        "",
    ]
    extra_metrics = [c for c in board.columns if c.endswith(("_median", "_rate"))
                     and not c.startswith(("best_f_", "evals_", "seconds_"))]
    for problem in sorted(runs["problem"].unique()):
        b = board[board["problem"] == problem]
        anytime, ecdf_png = figures[problem]
        lines += [
            f"## Problem `{problem}`",
            "",
            f"### Leaderboard (significance: {test}, Holm-corrected against the leader, alpha = {alpha:g})",
            "",
            _md_table(b[[c for c in LEADERBOARD_MD_COLUMNS if c in b.columns]]),
            "",
        ]
        metrics = [c for c in extra_metrics if b[c].notna().any()]
        if metrics:
            lines += ["Calibration metrics of the final best point (median over valid runs):", "",
                      _md_table(b[["optimizer", *metrics]]), ""]
        lines += [
            "### Pairwise comparisons",
            "",
            "A12 = P(f_a < f_b) + ½P(f_a = f_b), the chance that a run of a ends better than one of b; "
            "p_holm corrected over all pairs of this problem.",
            "",
            _md_table(pairs[pairs["problem"] == problem].drop(columns="problem")),
            "",
            "### Fixed targets and expected running time (ERT)",
            "",
            _md_table(targets[targets["problem"] == problem].drop(columns="problem")),
            "",
            _md_table(ert[ert["problem"] == problem][["optimizer", "target", "n_runs", "n_hit",
                                                      "ert_evals", "ert_seconds"]]),
            "",
            f"![runtime ECDF for {problem}]({ecdf_png.relative_to(out).as_posix()})",
            "",
            "### Anytime performance",
            "",
            f"![anytime curves for {problem}]({anytime.relative_to(out).as_posix()})",
            "",
        ]
    lines += _paper_tables_markdown(tables, out)
    failed = runs[~runs["valid"]][["job", "problem", "optimizer", "seed", "status", "error_type",
                                   "error_message"]]
    lines += ["## Failed runs", "",
              "Counted in `n_failed`, excluded from tests and medians, included in ERT and ECDF "
              "as unsuccessful with what they spent.", "", _md_table(failed), ""]
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
- **Tests**: two-sided Mann–Whitney U on the final best f of valid runs (runs of different
  optimisers share no randomness: the seed drives only the optimiser). With `--pairing seed`,
  Wilcoxon signed-rank on seed-matched differences where both optimisers have the same seeds.
  Fewer than 2 valid runs on a side: no test (p = NaN, "n/a"). All values equal: p = 1.
  Holm's step-down correction within each problem. Few seeds cannot show significance: the
  smallest two-sided Mann–Whitney p is 2/C(n+m, n), 0.1 for 3 vs 3 runs, 0.0079 for 5 vs 5.
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

