"""One job: (problem, optimiser, seed, budget) → evaluation log and final record.

The only code in the harness that talks to an optimiser. It owns the budgets: evaluations
(never over-spent: a last batch is trimmed, and a trimmed batch is not told back), wall
seconds (checked between batches; an evaluation is never interrupted), and the optimiser's
own stop. A job killed mid-run resumes from its log: the optimiser is rebuilt from its seed
and fed the logged tells, which must match what it asks again (determinism is checked, not
assumed).
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import traceback
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from bench.problems.base import Problem
from bench.provenance import provenance
from bench.records import EvalLog, read_eval_log, read_record, write_json_atomic, RECORD

log = logging.getLogger(__name__)

SCHEMA = 1


class RunError(RuntimeError):
    """A job cannot run or resume as configured; the message says why."""


@dataclass(frozen=True)
class Budget:
    """Evaluation budget (count) and wall-clock budget (seconds); None means unlimited."""

    evals: int | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        if self.evals is None and self.seconds is None:
            raise RunError("budget: set budget.evals or budget.seconds (both are null)")
        if self.evals is not None and (not isinstance(self.evals, (int, np.integer)) or self.evals < 1):
            raise RunError(f"budget.evals must be a positive integer, got {self.evals!r}")
        if self.seconds is not None and not (np.isfinite(self.seconds) and self.seconds > 0):
            raise RunError(f"budget.seconds must be a positive number, got {self.seconds!r}")


def job_key(identity: dict) -> str:
    """Short stable hash of what defines a job (problem, optimiser and params, seed, budget)."""
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class _Progress:
    """Logs a job's progress at most every ``every_s`` seconds (and at the end)."""

    def __init__(self, label: str, budget: Budget, every_s: float) -> None:
        self.label, self.budget, self.every_s = label, budget, every_s
        self._last, self._last_n = -np.inf, -1

    def __call__(self, n_evals: int, best_f: float, elapsed_s: float, force: bool = False) -> None:
        if (force and n_evals != self._last_n) or elapsed_s - self._last >= self.every_s:
            self._last, self._last_n = elapsed_s, n_evals
            of = f"/{self.budget.evals}" if self.budget.evals else ""
            log.info("%s: %d%s evals, best f %.6g, %.1f s", self.label, n_evals, of, best_f, elapsed_s)


def run_job(
    problem: Problem,
    make_optimizer: Callable[[], object],
    budget: Budget,
    job_dir: Path,
    identity: dict,
    config: dict | None = None,
    label: str = "job",
    progress_every_s: float = 5.0,
) -> dict:
    """Run (or resume, or skip when finished) one job in ``job_dir`` and return its final record.

    ``make_optimizer()`` builds the optimiser from its seed (called again on resume);
    ``identity`` (problem, optimiser, params, seed, budget) keys the job: a folder holding a
    different job is refused. Exceptions from the optimiser or the problem fail this job only:
    the record says ``status: failed`` with the error.
    """
    job_dir = Path(job_dir)
    key = job_key(identity)
    previous = read_record(job_dir)
    if previous is not None:
        if previous.get("job_key") != key:
            raise RunError(
                f"{job_dir} already holds a different job (job_key {previous.get('job_key')} != {key}); "
                "choose another hydra.sweep.dir"
            )
        if previous.get("status") == "ok":
            log.info("%s: already finished in %s, skipped", label, job_dir)
            return previous

    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    state = {"n_evals": 0, "n_batches": 0, "eval_s": 0.0, "best_f": np.inf, "best_x": None,
             "best_metrics": {}, "offset_s": 0.0}
    stop_reason, error = None, None
    clock0 = time.perf_counter()
    try:
        optimizer = make_optimizer()
        evals_log = EvalLog(job_dir)
        stop_reason = _replay(optimizer, problem, evals_log, budget, state)
        clock0 = time.perf_counter() - state["offset_s"]
        tick = _Progress(label, budget, progress_every_s)
        while stop_reason is None:
            stop_reason = _budget_stop(budget, state, time.perf_counter() - clock0) or _optimizer_stop(optimizer)
            if stop_reason is not None:
                break
            X = problem.space.check(optimizer.ask())
            trimmed = budget.evals is not None and state["n_evals"] + len(X) > budget.evals
            if trimmed:
                X = X[: budget.evals - state["n_evals"]]
            t_start = time.perf_counter() - clock0
            f, metrics = problem.evaluate(X)
            t_end = time.perf_counter() - clock0
            f = np.asarray(f, float)
            if f.shape != (len(X),):
                raise RunError(f"problem {problem.name!r} returned f of shape {f.shape} for {len(X)} points")
            entry = _entry(state, X, f, metrics, t_start, t_end)
            evals_log.append(entry)
            _account(state, entry)
            if trimmed:
                stop_reason = "budget_evals"
            else:
                optimizer.tell(X, f)
            tick(state["n_evals"], state["best_f"], t_end)
        tick(state["n_evals"], state["best_f"], time.perf_counter() - clock0, force=True)
        status = "ok"
    except RunError:
        raise
    except Exception as exc:  # noqa: BLE001 - a failing plugin fails its own job only; recorded below
        status, stop_reason = "failed", "error"
        error = {"type": type(exc).__name__, "message": str(exc), "traceback": traceback.format_exc()}
        log.error("%s failed: %s: %s", label, type(exc).__name__, exc)
    finally:
        if "evals_log" in locals():
            evals_log.close()

    record = {
        "schema": SCHEMA,
        "job_key": key,
        "status": status,
        "error": error,
        **{k: identity[k] for k in ("problem", "optimizer", "seed") if k in identity},
        "budget": {"evals": budget.evals, "seconds": budget.seconds},
        "config": config or {},
        "space": {
            "names": list(problem.space.names),
            "units": list(problem.space.units),
            "lower": problem.space.lower,
            "upper": problem.space.upper,
            "reference": problem.space.reference,
        },
        "truth_x": problem.truth,
        "f_truth": getattr(problem, "f_truth", None),
        "f_reference": getattr(problem, "f_reference", None),
        "problem_identity": problem.identity,
        "best_x": state["best_x"],
        "best_f": None if not np.isfinite(state["best_f"]) else state["best_f"],
        "best_metrics": state["best_metrics"],
        "n_evals": state["n_evals"],
        "n_batches": state["n_batches"],
        "wall_s": time.perf_counter() - clock0,
        "eval_s": state["eval_s"],
        "stop_reason": stop_reason,
        "started_utc": started,
        "ended_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        **provenance(),
    }
    write_json_atomic(job_dir / RECORD, record)
    return read_record(job_dir)


def _entry(state: dict, X, f, metrics: dict, t_start: float, t_end: float) -> dict:
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


def _account(state: dict, entry: dict) -> None:
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


def _replay(optimizer, problem: Problem, evals_log: EvalLog, budget: Budget, state: dict) -> str | None:
    """Feed a killed job's logged batches back to a fresh optimiser; the stop reason if it had ended.

    A torn last line (the kill hit mid-write) is dropped from the log first.
    """
    entries = read_eval_log(evals_log.path.parent)
    evals_log.truncate_to(len(entries))
    for i, entry in enumerate(entries):
        X_logged = np.asarray(entry["X"], float)
        X_asked = np.asarray(optimizer.ask(), float)
        if X_asked[: len(X_logged)].shape != X_logged.shape or not np.array_equal(X_asked[: len(X_logged)], X_logged):
            raise RunError(
                f"{evals_log.path}: batch {i} differs from what the optimiser asks again; the log was written "
                "by another configuration or a non-deterministic optimiser, so it cannot be resumed"
            )
        _account(state, entry)
        if len(X_logged) < len(X_asked):  # the trimmed last batch of a finished evaluation budget
            return "budget_evals"
        optimizer.tell(X_logged, np.asarray(entry["f"], float))
    if entries:
        log.info("resumed %s after %d logged batches (%d evals)", evals_log.path.parent, len(entries), state["n_evals"])
    return None


def _budget_stop(budget: Budget, state: dict, elapsed_s: float) -> str | None:
    if budget.evals is not None and state["n_evals"] >= budget.evals:
        return "budget_evals"
    if budget.seconds is not None and elapsed_s >= budget.seconds:
        return "budget_seconds"
    return None


def _optimizer_stop(optimizer) -> str | None:
    reason = optimizer.stop
    return None if reason is None else f"optimizer: {reason}"


def record_failure(job_dir: Path, identity: dict, config: dict, exc: BaseException) -> dict:
    """Write the record of a job that failed before its run loop started (e.g. its problem did not build)."""
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    record = {
        "schema": SCHEMA,
        "job_key": job_key(identity),
        "status": "failed",
        "error": {"type": type(exc).__name__, "message": str(exc), "traceback": traceback.format_exc()},
        **{k: identity[k] for k in ("problem", "optimizer", "seed") if k in identity},
        "budget": identity.get("budget"),
        "config": config,
        "space": None, "truth_x": None, "f_truth": None, "f_reference": None, "problem_identity": None,
        "best_x": None, "best_f": None, "best_metrics": {},
        "n_evals": 0, "n_batches": 0, "wall_s": 0.0, "eval_s": 0.0,
        "stop_reason": "error", "started_utc": now, "ended_utc": now,
        **provenance(),
    }
    write_json_atomic(Path(job_dir) / RECORD, record)
    return read_record(job_dir)
