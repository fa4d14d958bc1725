"""Synthetic job folders in the run loop's on-disk format (``evals.jsonl`` + ``record.json``), for tests.

``write_job`` writes what ``bench.run`` would have written for a job whose batches returned the
given objective values, so that the aggregation code can be tested on cases small enough to
compute by hand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.records import RECORD, EvalLog, write_json_atomic


def write_job(
    root: Path,
    problem: str,
    optimizer: str,
    seed: int,
    f_batches: list[list[float]],
    *,
    t_batches: list[float] | None = None,
    metrics_batches: list[dict[str, list[float]]] | None = None,
    status: str = "ok",
    f_truth: float | None = None,
    f_reference: float | None = None,
    budget_evals: int | None = None,
    wall_s: float | None = None,
    error: dict | None = None,
    name: str | None = None,
    problem_params: dict | None = None,
    optimizer_params: dict | None = None,
    f_unit: str | None = None,
    instance: int | None = None,
    reference_metrics: dict | None = None,
) -> Path:
    """Write one job folder under ``root`` and return its path.

    f_batches: objective values of each evaluated batch, in order (a batch may hold any number).
    t_batches: ``t_end_s`` of each batch (seconds since job start); default 1 s per batch.
    metrics_batches: per batch, ``{metric name: values}`` aligned with that batch's f values.
    status: "ok" or "failed"; a failed job's ``error`` defaults to a RuntimeError entry.
    problem_params / optimizer_params: the config's ``params`` sections (they and the budget are
    the job identity the leaderboard groups by); f_unit: the record's unit of f; instance: the
    pairing unit the run belongs to (a record field ``instance``; None: an older record without
    it); reference_metrics: the reference calibration's errors on that instance.
    The point X of each evaluation is ``[f, seed]`` (2-D space named a, b): content is irrelevant here.
    """
    default = f"{problem}/{optimizer}/" + (f"seed{seed}" if instance is None else f"instance{instance}")
    job = Path(root) / (name or default)
    log = EvalLog(job)
    t_batches = t_batches if t_batches is not None else [float(i + 1) for i in range(len(f_batches))]
    evals_total = 0
    all_f, all_m = [], {}
    for i, f in enumerate(f_batches):
        f = [float(v) for v in f]
        metrics = (metrics_batches or [{}] * len(f_batches))[i]
        evals_total += len(f)
        t_end = float(t_batches[i])
        t_start = float(t_batches[i - 1]) if i else 0.0
        log.append({"batch": i, "n": len(f), "evals_total": evals_total, "t_start_s": t_start,
                    "t_end_s": t_end, "eval_s": t_end - t_start, "X": [[v, float(seed)] for v in f],
                    "f": f, "metrics": metrics})
        all_f.extend(f)
        for key, values in metrics.items():
            all_m.setdefault(key, []).extend(values)
    log.close()
    if all_f:
        best = int(np.nanargmin(all_f))
        best_f, best_x = all_f[best], [all_f[best], float(seed)]
        best_metrics = {k: v[best] for k, v in all_m.items()}
    else:
        best_f, best_x, best_metrics = None, None, {}
    if status == "failed" and error is None:
        error = {"type": "RuntimeError", "message": "synthetic failure", "traceback": "..."}
    record = {
        "schema": 2, "job_key": f"{problem}/{optimizer}/{seed}", "status": status, "error": error,
        "problem": problem, "optimizer": optimizer, "f_unit": f_unit,
        "seed": seed, "budget": {"evals": budget_evals, "seconds": None},
        "config": {"problem": {"name": problem, "params": problem_params or {}},
                   "optimizer": {"name": optimizer, "params": optimizer_params or {}}, "seed": seed},
        "space": {"names": ["a", "b"], "units": ["", ""], "lower": [-1e9, -1e9], "upper": [1e9, 1e9],
                  "reference": [0.0, 0.0]},
        "truth_x": None, "f_truth": f_truth, "f_reference": f_reference,
        "best_x": best_x, "best_f": best_f, "best_metrics": best_metrics,
        "n_evals": evals_total, "n_batches": len(f_batches),
        "wall_s": wall_s if wall_s is not None else (float(t_batches[-1]) if f_batches else 0.0),
        "eval_s": None, "stop_reason": "budget" if status == "ok" else "error",
        "versions": {"numpy": "x"}, "git_commit": "0" * 40, "machine": "test",
        "started_utc": "2026-01-01T00:00:00Z", "ended_utc": "2026-01-01T00:01:00Z",
    }
    if instance is not None:
        record["instance"] = instance
    if reference_metrics is not None:
        record["reference_metrics"] = reference_metrics
    write_json_atomic(job / RECORD, record)
    return job
