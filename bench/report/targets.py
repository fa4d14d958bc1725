"""Fixed targets in the problem's own terms, runtimes to reach them, ERT and runtime ECDFs.

Definitions follow COCO (Hansen et al., "COCO: performance assessment", 2021) and IOHprofiler:

- A run *hits* a target at the first batch end where its incumbent (best-so-far point) meets
  the target; its runtime is the cumulative evaluation count (or ``t_end_s``) at that batch end.
  A batch is charged whole, because the optimiser receives its values together.
- **ERT** (expected running time) = (sum over successful runs of their runtime + sum over
  unsuccessful runs of everything they spent) / number of successful runs; ``inf`` when no run
  succeeds. Failed jobs (status "failed") count as runs: a hit inside their partial log is a
  hit, otherwise they are unsuccessful with what they spent.
- **ECDF**: at budget b, the fraction of (run, target) pairs whose runtime is <= b, over all
  runs (unsuccessful and failed ones included) and all targets of the problem.

Targets (``problem_targets``):

- objective, with ``f_truth`` = objective at the true calibration (record field) > 0:
  ``f <= f_truth * (1 + p)`` for p in 1%, 5%, 10%;
- objective, with ``f_truth`` <= 0 (analytic problems: f_truth = 0, where a relative band is
  empty): ``f <= f_truth + p * (f_reference - f_truth)``, i.e. the gap between the reference
  point and the truth closed to within p;
- objective, truth unknown: the same two rules around ``f_best``, the best final f of any run of
  the problem in the records at hand (COCO's "best known" target; it depends on the records);
- when neither the anchor (> 0) nor ``f_reference`` above it gives a scale: the absolute
  tolerance ``f <= anchor + p`` in objective units;
- calibration metrics at the incumbent, when logged: ``rotation_error_deg`` below 0.5 and 0.1,
  ``focal_error_px`` below 1.

The main target (ERT in the leaderboard) is the objective target at p = 5%.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from bench.errors import BenchError

OBJECTIVE_LEVELS = (0.01, 0.05, 0.10)
MAIN_LEVEL = 0.05
METRIC_TARGETS = (("rotation_error_deg", 0.5), ("rotation_error_deg", 0.1), ("focal_error_px", 1.0))
AXES = ("evals", "seconds")


class TargetsError(BenchError):
    """Inputs to the fixed-target computations are inconsistent; the message says which."""


@dataclass(frozen=True)
class Target:
    """One fixed target of a problem.

    name: short label (e.g. ``f_truth+5%``); column: trace column it is checked on (``best_f``
    or ``inc.<metric>``); threshold: in that column's units; strict: hit when value < threshold
    (else <=); description: the formula in words; main: the leaderboard's ERT target.
    """

    name: str
    column: str
    threshold: float
    strict: bool
    description: str
    main: bool = False

    def met(self, values: np.ndarray) -> np.ndarray:
        values = np.asarray(values, float)
        return values < self.threshold if self.strict else values <= self.threshold


def _consensus(values: pd.Series) -> float:
    """The one finite value a field takes across a problem's records (median if they differ)."""
    finite = pd.to_numeric(values, errors="coerce").dropna()
    finite = finite[np.isfinite(finite)]
    return float(finite.median()) if len(finite) else np.nan


def objective_targets(f_truth: float, f_reference: float, f_best: float) -> list[Target]:
    """The objective targets for a problem with these anchors (NaN = unknown); see module doc."""
    anchor, label = (f_truth, "f_truth") if np.isfinite(f_truth) else (f_best, "f_best")
    if not np.isfinite(anchor):
        return []
    targets = []
    for p in OBJECTIVE_LEVELS:
        pct = f"{100 * p:g}%"
        if anchor > 0:
            name, thr, desc = f"{label}+{pct}", anchor * (1 + p), f"f <= {label} * (1 + {p:g})"
        elif np.isfinite(f_reference) and f_reference > anchor:
            name, thr = f"{label}+{pct}gap", anchor + p * (f_reference - anchor)
            desc = f"f <= {label} + {p:g} * (f_reference - {label})"
        else:
            name, thr, desc = f"{label}+{p:g}abs", anchor + p, f"f <= {label} + {p:g} (absolute)"
        targets.append(Target(name, "best_f", float(thr), False, desc, main=(p == MAIN_LEVEL)))
    return targets


def problem_targets(runs: pd.DataFrame, traces: pd.DataFrame) -> dict[str, list[Target]]:
    """Targets of each problem in ``runs`` (columns problem, f_truth, f_reference, best_f, valid).

    Metric targets appear only for metrics the problem's traces log (``inc.<metric>`` columns
    with at least one value).
    """
    out = {}
    for problem, group in runs.groupby("problem", sort=True):
        f_best = group.loc[group["valid"], "best_f"].min() if group["valid"].any() else np.nan
        targets = objective_targets(_consensus(group["f_truth"]), _consensus(group["f_reference"]),
                                    float(f_best))
        logged = traces[traces["problem"] == problem]
        for metric, threshold in METRIC_TARGETS:
            col = f"inc.{metric}"
            if col in logged.columns and logged[col].notna().any():
                targets.append(Target(f"{metric}<{threshold:g}", col, threshold, True,
                                      f"{metric} at the incumbent < {threshold:g}"))
        out[problem] = targets
    return out


def hitting_times(runs: pd.DataFrame, traces: pd.DataFrame,
                  targets: dict[str, list[Target]]) -> pd.DataFrame:
    """One row per (run, target): when each run first met each target of its problem.

    runs: one row per job (job_dir, problem, optimizer, seed, status, n_evals, wall_s);
    traces: ``bench.curves.run_traces``. Returns columns ``problem, optimizer, seed, job_dir,
    status, target, hit, evals, seconds`` (runtime to the hit, NaN when not hit) and
    ``spent_evals, spent_seconds`` (what the whole run used: the last logged evaluation count,
    the record's ``wall_s`` when present, else the last batch end).
    """
    by_job = dict(tuple(traces.groupby("job_dir", sort=False))) if len(traces) else {}
    rows = []
    for run in runs.itertuples(index=False):
        trace = by_job.get(run.job_dir)
        evals = trace["evals"].to_numpy(float) if trace is not None else np.zeros(0)
        secs = trace["seconds"].to_numpy(float) if trace is not None else np.zeros(0)
        spent_evals = evals[-1] if len(evals) else float(np.nan_to_num(run.n_evals))
        spent_s = float(run.wall_s) if np.isfinite(run.wall_s) else (secs[-1] if len(secs) else 0.0)
        for target in targets.get(run.problem, []):
            met = (target.met(trace[target.column].to_numpy(float))
                   if trace is not None and target.column in trace.columns else np.zeros(0, bool))
            first = int(np.argmax(met)) if met.any() else -1
            rows.append((run.problem, run.optimizer, run.seed, run.job_dir, run.status, target.name,
                         first >= 0, evals[first] if first >= 0 else np.nan,
                         secs[first] if first >= 0 else np.nan, spent_evals, spent_s))
    cols = ["problem", "optimizer", "seed", "job_dir", "status", "target", "hit", "evals", "seconds",
            "spent_evals", "spent_seconds"]
    return pd.DataFrame(rows, columns=cols).astype({"hit": bool})


def ert(hit: np.ndarray, runtime: np.ndarray, spent: np.ndarray) -> float:
    """COCO's expected running time of one (algorithm, target) from its runs.

    hit: (n_runs,) bool; runtime: (n_runs,) runtime to the hit (ignored where not hit);
    spent: (n_runs,) what each run used in all. ``inf`` when no run hit; NaN with no runs.
    """
    hit = np.asarray(hit, bool)
    if hit.size == 0:
        return np.nan
    if not hit.any():
        return np.inf
    return float(np.sum(np.where(hit, runtime, spent)) / hit.sum())


def ert_table(hits: pd.DataFrame, targets: dict[str, list[Target]]) -> pd.DataFrame:
    """ERT in evaluations and seconds per (problem, optimizer, target), with success counts.

    Columns: ``problem, optimizer, target, description, threshold, main, n_runs, n_hit,
    success_rate, ert_evals, ert_seconds``; targets in their definition order.
    """
    rows = []
    for (problem, optimizer), group in hits.groupby(["problem", "optimizer"], sort=True):
        for target in targets.get(problem, []):
            g = group[group["target"] == target.name]
            hit = g["hit"].to_numpy(bool)
            rows.append((problem, optimizer, target.name, target.description, target.threshold,
                         target.main, len(g), int(hit.sum()), hit.mean() if len(g) else np.nan,
                         ert(hit, g["evals"].to_numpy(float), g["spent_evals"].to_numpy(float)),
                         ert(hit, g["seconds"].to_numpy(float), g["spent_seconds"].to_numpy(float))))
    cols = ["problem", "optimizer", "target", "description", "threshold", "main", "n_runs", "n_hit",
            "success_rate", "ert_evals", "ert_seconds"]
    return pd.DataFrame(rows, columns=cols)


def ecdf(hits: pd.DataFrame, axis: str = "evals") -> pd.DataFrame:
    """Runtime ECDF per (problem, optimizer): fraction of (run, target) pairs hit by each budget.

    axis: "evals" or "seconds". Budgets are the group's distinct hit runtimes plus its largest
    spent budget (where the curve ends). Columns ``problem, optimizer, axis, budget, fraction,
    n_pairs``; the curve is a right-continuous step function of the budget.
    """
    if axis not in AXES:
        raise TargetsError(f"axis must be one of {AXES}, got {axis!r}")
    rows = []
    for (problem, optimizer), g in hits.groupby(["problem", "optimizer"], sort=True):
        runtime = np.where(g["hit"].to_numpy(bool), g[axis].to_numpy(float), np.inf)
        spent = g[f"spent_{axis}"].to_numpy(float)
        budgets = np.unique(np.append(runtime[np.isfinite(runtime)], np.nanmax(spent) if len(spent) else 0.0))
        fraction = np.searchsorted(np.sort(runtime), budgets, side="right") / len(runtime)
        rows.append(pd.DataFrame({"problem": problem, "optimizer": optimizer, "axis": axis,
                                  "budget": budgets, "fraction": fraction, "n_pairs": len(runtime)}))
    cols = ["problem", "optimizer", "axis", "budget", "fraction", "n_pairs"]
    return pd.concat(rows, ignore_index=True)[cols] if rows else pd.DataFrame(columns=cols)


def targets_table(targets: dict[str, list[Target]]) -> pd.DataFrame:
    """The targets of every problem as a table (problem, target, column, threshold, strict, main, description)."""
    rows = [(p, t.name, t.column, t.threshold, t.strict, t.main, t.description)
            for p, ts in sorted(targets.items()) for t in ts]
    return pd.DataFrame(rows, columns=["problem", "target", "column", "threshold", "strict", "main",
                                       "description"])
