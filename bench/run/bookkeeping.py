"""What a job writes down: a batch's entry in the evaluation log, the counters and best point it
updates, and the fields of ``record.json``, built in one place for a job that ran (``run_job``) and
for one that failed before its run loop started (``record_failure``)."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

from bench.problems.base import Problem
from bench.provenance import provenance
from bench.run.identity import SCHEMA


def batch_entry(state: dict, X, f, metrics: dict, t_start: float, t_end: float) -> dict:
    """A batch's line of the evaluation log: its points, values, metrics, times and counts."""
    return {
        "batch": state["n_batches"],
        "n": len(X),
        "evals_total": state["n_evals"] + len(X),
        "t_start_s": t_start,
        "t_end_s": t_end,
        "eval_s": t_end - t_start,
        "X": np.asarray(X, float),
        "f": np.asarray(f, float),
        "metrics": {k: np.asarray(v, float).reshape(len(X)) for k, v in metrics.items()},
    }


def account(state: dict, entry: dict) -> None:
    """Update counters and the best point from one logged batch."""
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
        state["best_metrics"] = {k: float(np.asarray(v, float)[i]) for k, v in entry["metrics"].items()}


def _name(value):
    """The name of an identity entry, which holds a name or a config section with one."""
    return value.get("name") if isinstance(value, dict) else value


def job_record(identity: dict, job_key: str | None, config_hash_: str, code: dict | None, status: str,
                error: dict | None, budget, config: dict, problem_fields: dict, outcome: dict) -> dict:
    """The job's ``record.json``: its keys and identity, how it ended, its problem and what it found."""
    return {
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
