"""What a job writes down: a batch's entry in the evaluation log, the counters and best point it
updates, and the fields of ``record.json``, built in one place for a job that ran (``run_job``) and
for one that failed before its run loop started (``record_failure``)."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

from bench.problems.base import Problem
from bench.provenance import provenance
from bench.records import dense_metrics
from bench.run.identity import SCHEMA

#: which evaluations' metrics a log keeps (the top-level ``log_metrics`` setting)
LOG_METRICS = ("improvements", "all")


def improving_points(f, best_before: float, first: bool) -> np.ndarray:
    """Indices (ascending, ints) of a batch's points that can ever be an incumbent: each point whose f
    (n,) is below ``best_before`` (the job's best finite f so far) and every earlier f of the batch
    (strictly: ties keep the earlier point; NaN never improves), and the job's first point when
    ``first`` (the incumbent before anything improved). Both incumbents count: the record's, among
    finite values (:func:`account`), and the trace's, where -inf may lead
    (bench.report.curves.incumbent_index)."""
    f = np.asarray(f, float)
    finite = np.where(np.isfinite(f), f, np.inf)
    before_finite = np.minimum.accumulate(np.concatenate([[best_before], finite]))[:-1]
    before_any = np.fmin.accumulate(np.concatenate([[best_before], f]))[:-1]
    improved = (finite < before_finite) | (f < before_any)
    if first and len(f):
        improved[0] = True
    return np.flatnonzero(improved)


def batch_entry(state: dict, X, f, metrics: dict, t_start: float, t_end: float,
                log_metrics: str = "improvements") -> dict:
    """A batch's line of the evaluation log: its points, values, metrics, times and counts.

    With ``log_metrics="improvements"`` the metrics are kept only at :func:`improving_points`,
    listed in ``metrics_at`` when that is not every point (bench.records: a reader sees NaN at the
    others). The report reads metrics at incumbents only, and an evaluation's 14 metrics cost as
    much log as its 10 variables and f (results/README.md, "Size")."""
    f = np.asarray(f, float)
    entry = {
        "batch": state["n_batches"],
        "n": len(X),
        "evals_total": state["n_evals"] + len(X),
        "t_start_s": t_start,
        "t_end_s": t_end,
        "eval_s": t_end - t_start,
        "X": np.asarray(X, float),
        "f": f,
        "metrics": {k: np.asarray(v, float).reshape(len(X)) for k, v in metrics.items()},
    }
    if log_metrics == "improvements":
        at = improving_points(f, state["best_f"], state["n_evals"] == 0)
        if len(at) < len(f):
            entry["metrics_at"] = at.tolist()
            entry["metrics"] = {k: v[at] for k, v in entry["metrics"].items()} if len(at) else {}
    return entry


def account(state: dict, entry: dict) -> None:
    """Update counters and the best point from one batch (as logged: its metrics may be kept at its
    improving points only, which include the best one)."""
    f = np.asarray(entry["f"], float)
    state["n_evals"] += len(f)
    state["n_batches"] += 1
    state["eval_s"] += entry["eval_s"]
    state["offset_s"] = entry["t_end_s"]
    finite = np.where(np.isfinite(f), f, np.inf)
    i = int(np.argmin(finite))
    if finite[i] < state["best_f"]:
        state["best_f"] = float(finite[i])
        state["best_x"] = np.asarray(entry["X"], float)[i]
        state["best_metrics"] = {k: float(v[i]) for k, v in dense_metrics(entry).items()}


def _name(value):
    """The name of an identity entry, which holds a name or a config section with one."""
    return value.get("name") if isinstance(value, dict) else value


def job_record(identity: dict, job_key: str | None, config_hash_: str, code: dict | None, status: str,
                error: dict | None, budget, config: dict, problem_fields: dict, outcome: dict) -> dict:
    """The job's ``record.json``: its keys and identity, how it ended, its problem and what it found;
    a problem's ``filter_threads`` and ``filter_kernel`` go to ``machine`` (its timings depend on them, its
    results do not)."""
    problem_fields = dict(problem_fields)
    threads = problem_fields.pop("filter_threads", None)
    kernel = problem_fields.pop("filter_kernel", None)
    record = {
        "schema": SCHEMA,
        "job_key": job_key,
        "config_hash": config_hash_,
        "identity": identity,
        **({} if code is None else {"code_version": code}),
        "status": status,
        "error": error,
        "problem": _name(identity.get("problem")),
        "optimizer": _name(identity.get("optimizer")),
        "instance": identity.get("instance"),
        "seed": identity.get("seed"),
        "budget": budget,
        "config": config,
        **problem_fields,
        **outcome,
        **provenance(),
    }
    if threads is not None:  # a copy: provenance() is computed once per process
        record["machine"] = {**record["machine"], "filter_threads": threads}
    if kernel is not None:
        record["machine"] = {**record["machine"], "filter_kernel": kernel}
    return record


def _filter_kernel() -> dict:
    """A VIO problem's machine.filter_kernel: the lock-step block setting (avio.filter.batch.set_block,
    "auto" for its default rule) and whether the C kernel is available (else numba's per-filter one)."""
    from avio.filter.batch import block_setting
    from avio.filter.lanes import native

    return {"block": block_setting(), "native": native.unavailable() is None}


def problem_fields(problem: Problem) -> dict:
    """What the record says of the problem: its space, unit of f, truth, reference f and data identity."""
    return {
        "space": {
            "names": list(problem.space.names),
            "units": list(problem.space.units),
            "lower": problem.space.lower,
            "upper": problem.space.upper,
            "reference": problem.space.reference,
        },
        "f_unit": getattr(problem, "f_unit", None),
        "truth_x": problem.truth,
        "f_truth": getattr(problem, "f_truth", None),
        "f_reference": getattr(problem, "f_reference", None),
        "problem_identity": problem.identity,
        **({"filter_threads": problem.filter_threads} if hasattr(problem, "filter_threads") else {}),
        **({"filter_kernel": _filter_kernel()} if hasattr(problem, "filter_threads") else {}),
    }


def outcome(state: dict, wall_s: float, stop_reason: str | None, started: str) -> dict:
    """What the record says the job found and spent, and when it ran."""
    return {
        "best_x": state["best_x"],
        "best_f": None if not np.isfinite(state["best_f"]) else state["best_f"],
        "best_metrics": state["best_metrics"],
        "n_evals": state["n_evals"],
        "n_batches": state["n_batches"],
        "wall_s": wall_s,
        "eval_s": state["eval_s"],
        "stop_reason": stop_reason,
        "started_utc": started,
        "ended_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
