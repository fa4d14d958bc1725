"""One job: (problem, optimiser, seed, budget) → evaluation log and final record.

The only code in the harness that talks to an optimiser. It owns the budgets: evaluations
(never over-spent: a last batch is trimmed, and a trimmed batch is not told back), wall
seconds (checked between batches; an evaluation is never interrupted), and the optimiser's
own stop.

Trust rules (issue 14):

- **Identity.** Before the first batch, ``job.json`` records the job's identity: the hash of its
  resolved config, the config itself, the problem's data identity and the code version (a
  hash of the source files that decide asks and values). A job folder is only resumed or
  skipped by the same identity; anything else is refused (``RunError``) with nothing on disk
  changed.
- **One writer.** The job holds ``FolderLock`` on its folder for its whole life; a second process
  fails fast with a message naming the holder.
- **Replay checked, then trusted.** A killed job is resumed by rebuilding the optimiser from its
  seed and feeding it the logged tells, which must match what it asks again, with the budget and
  the optimiser's stop applied to every replayed batch (a log longer than the job allows is
  refused). All of it is checked in memory first; only then is a torn last line (a kill mid-write)
  cut off, which is the only change ever made to existing lines.
- **Failures stay in the job.** Any error inside the job (optimiser, problem, log, I/O, a full
  disk, a corrupt record) ends it with ``status: failed`` and the error in its record; an error
  while closing the log never hides the first one. When the record itself cannot be written the
  caller gets ``JobFolderError`` to report.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from bench.errors import BenchError
from bench.problems.base import Problem
from bench.provenance import provenance
from bench.records import (
    JOB_FILE,
    RECORD,
    EvalLog,
    FolderLock,
    LockError,
    RecordError,
    read_job_file,
    read_record,
    scan_eval_log,
    write_json_atomic,
)
from bench.run.identity import SCHEMA, config_hash, header_mismatch, job_header

log = logging.getLogger(__name__)


class RunError(BenchError):
    """A job cannot run or resume as configured; nothing on disk was changed; the message says why."""


class JobFolderError(RunError):
    """The job ran (or failed) but its folder cannot be written; the message names the folder and the error."""


@dataclass(frozen=True)
class Budget:
    """Evaluation budget (count) and wall-clock budget (seconds); None means unlimited."""

    evals: int | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        if self.evals is None and self.seconds is None:
            raise RunError("budget: set budget.evals or budget.seconds (both are null)")
        if self.evals is not None and (isinstance(self.evals, (bool, np.bool_))
                                       or not isinstance(self.evals, (int, np.integer)) or self.evals < 1):
            raise RunError(f"budget.evals must be a positive integer or null, got {self.evals!r}")
        if self.seconds is not None and (isinstance(self.seconds, (bool, np.bool_))
                                         or not isinstance(self.seconds, (int, float, np.number))
                                         or not (math.isfinite(self.seconds) and self.seconds > 0)):
            raise RunError(f"budget.seconds must be a positive number or null, got {self.seconds!r}")


class _Progress:
    """A tqdm bar per job on stderr: evaluations (of the budget), best f, rate and ETA.

    A timer redraws it every ``every_s`` seconds even while one batch runs long, so no phase
    of the run loop is silent for longer than that.
    """

    def __init__(self, label: str, budget: Budget, every_s: float, enabled: bool, initial: int = 0) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=budget.evals, initial=initial, desc=label, unit="eval", file=sys.stderr,
                        disable=not enabled, dynamic_ncols=True, mininterval=min(every_s, 1.0), leave=True)
        self._stop = threading.Event()
        self._every_s = every_s
        self._best_f = None
        if enabled:
            threading.Thread(target=self._redraw, daemon=True, name="bench-progress").start()

    def _redraw(self) -> None:
        while not self._stop.wait(self._every_s):
            self.bar.refresh()

    def update(self, n: int, best_f: float) -> None:
        if best_f != self._best_f:  # formatting the postfix costs ~50 us: only when it changes
            self._best_f = best_f
            self.bar.set_postfix_str(f"best f {best_f:.6g}", refresh=False)
        self.bar.update(n)

    def close(self) -> None:
        self._stop.set()
        self.bar.close()


def run_job(
    problem: Problem,
    make_optimizer: Callable[[], object],
    budget: Budget,
    job_dir: Path,
    identity: dict,
    config: dict | None = None,
    label: str = "job",
    progress_every_s: float = 5.0,
    optimizer_class: type | None = None,
    progress: bool = True,
) -> dict:
    """Run (or resume, or skip when finished) one job in ``job_dir`` and return its final record.

    ``make_optimizer()`` builds the optimiser from its seed (called again on resume);
    ``identity`` (the resolved job config: problem, optimiser, params, seed, budget) keys the job
    with the problem's data identity and the code version (``job_header``). Raises ``RunError``
    when the folder holds another job, is locked by another process, or its log does not replay
    (nothing changed), and ``JobFolderError`` when the record cannot be written; every other error
    fails this job only: the record says ``status: failed`` with the error.
    """
    job_dir = Path(job_dir)
    lock = _lock_job(job_dir)
    try:
        return _run_locked(problem, make_optimizer, budget, job_dir, identity, config, label,
                           progress_every_s, optimizer_class, progress)
    finally:
        lock.release()


def _previous_record(job_dir: Path, header: dict) -> tuple[dict | None, str | None]:
    """(the finished record to return, or None to run; why the old record.json is unreadable, or None)."""
    try:
        previous = read_record(job_dir)
        if previous is not None and not {"job_key", "status"} <= set(previous):
            raise RecordError(f"{job_dir / RECORD}: corrupt record (missing job_key or status)")
    except RecordError as err:
        return None, str(err)  # set aside, and the job failed with it, once its log is known to be ours
    if previous is None or previous.get("status") != "ok":
        return None, None  # never finished, or failed: run (resuming its log) again
    if previous.get("job_key") != header["job_key"]:
        try:
            on_disk = read_job_file(job_dir)
        except RecordError:
            on_disk = None
        why = (header_mismatch(on_disk, header) if on_disk is not None else None) or (
            f"job_key {previous.get('job_key')} != {header['job_key']}")
        raise RunError(f"{job_dir} already holds a different job, finished ({why}); choose another hydra.sweep.dir")
    return previous, None


def _run_locked(problem, make_optimizer, budget, job_dir, identity, config, label, progress_every_s,
                optimizer_class, progress) -> dict:
    header = job_header(identity, problem, optimizer_class)
    try:
        previous, corrupt_note = _previous_record(job_dir, header)
    except OSError as err:
        raise JobFolderError(f"{job_dir}: cannot read or set aside its record ({err})") from None
    if previous is not None:
        log.info("%s: already finished in %s, skipped", label, job_dir)
        return previous
    try:
        on_disk = read_job_file(job_dir)
    except RecordError as err:
        raise RunError(f"{err}: the log's identity cannot be checked, so it is not resumed") from None
    evals_path = job_dir / "evals.jsonl"
    if on_disk is not None:
        why = header_mismatch(on_disk, header)
        if why:
            raise RunError(f"{job_dir} holds a log of another job: {why}; resuming would mix results "
                           "(choose another hydra.sweep.dir, or restore the settings)")
    elif evals_path.exists() and evals_path.stat().st_size:
        raise RunError(f"{evals_path}: an evaluation log without {JOB_FILE} (written by an older version or "
                       "another tool) cannot be checked, so it is not resumed; move it away")

    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    state = {"n_evals": 0, "n_batches": 0, "eval_s": 0.0, "best_f": np.inf, "best_x": None,
             "best_metrics": {}, "offset_s": 0.0}
    stop_reason, error, status = None, None, "ok"
    clock0 = time.perf_counter()
    evals_log, bar = None, None
    try:
        if corrupt_note:
            kept = job_dir / f"{RECORD}.corrupt"
            os.replace(job_dir / RECORD, kept)
            raise RecordError(f"the previous record was unreadable ({corrupt_note}; kept as {kept.name}); run "
                              "the job again to resume from its log")
        optimizer = make_optimizer()
        entries, complete_bytes, file_bytes = scan_eval_log(job_dir)
        if entries:
            print(f"{label}: resuming: replaying {len(entries)} logged batches through the optimiser",
                  file=sys.stderr, flush=True)
        stop_reason = _replay(optimizer, entries, evals_path, budget, state,  # RunError: nothing changed
                              tell_every_s=max(0.5, min(float(progress_every_s), 5.0)), label=label)
        evals_log = EvalLog(job_dir)
        if file_bytes > complete_bytes:
            log.warning("%s: dropping a torn last line of %s (%d bytes)", label, evals_path, file_bytes - complete_bytes)
            evals_log.truncate_bytes(complete_bytes)
        if on_disk is None:
            write_json_atomic(job_dir / JOB_FILE, header)
        if entries:
            log.info("%s: resumed after %d logged batches (%d evals)", label, len(entries), state["n_evals"])
        bar = _Progress(label, budget, max(0.5, min(float(progress_every_s), 5.0)), progress, state["n_evals"])
        clock0 = time.perf_counter() - state["offset_s"]  # after the set-up: wall_s times the loop
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
            bar.update(len(X), state["best_f"])
    except RunError as exc:
        if evals_log is None:  # refused before anything was written
            raise
        status, stop_reason, error = "failed", "error", _error(exc)
    except Exception as exc:  # noqa: BLE001 - a failing plugin, problem or disk fails its own job only; recorded below
        status, stop_reason, error = "failed", "error", _error(exc)
    finally:
        if bar is not None:
            bar.close()
        if evals_log is not None:
            try:
                evals_log.close()
            except OSError as exc:  # e.g. a full disk: the last flush failed; never hides an earlier error
                close_error = _error(exc)
                if error is None:
                    status, stop_reason, error = "failed", "error", close_error
                else:
                    error["also"] = f"closing {evals_path} failed too: {close_error['message']}"
    if error is not None:
        log.error("%s failed: %s: %s", label, error["type"], error["message"])
    else:
        log.info("%s: %d evals, best f %.6g, %s", label, state["n_evals"], state["best_f"], stop_reason)

    name = lambda v: v.get("name") if isinstance(v, dict) else v  # noqa: E731 - identity holds names or sections
    record = {
        "schema": SCHEMA,
        "job_key": header["job_key"],
        "config_hash": header["config_hash"],
        "identity": identity,
        "code_version": header["code"],
        "status": status,
        "error": error,
        "problem": name(identity.get("problem")),
        "optimizer": name(identity.get("optimizer")),
        "seed": identity.get("seed"),
        "budget": {"evals": budget.evals, "seconds": budget.seconds},
        "config": config or {},
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
    return _write_record(job_dir, record, error)


def _error(exc: BaseException) -> dict:
    return {"type": type(exc).__name__, "message": str(exc), "traceback": traceback.format_exc()}


def _write_record(job_dir: Path, record: dict, error: dict | None) -> dict:
    try:
        write_json_atomic(job_dir / RECORD, record)
        return read_record(job_dir)
    except (OSError, RecordError) as err:
        first = f" after the job failed with {error['type']}: {error['message']}" if error else ""
        raise JobFolderError(f"{job_dir}: cannot write {RECORD} ({type(err).__name__}: {err}){first}") from None


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


def _replay(optimizer, entries: list[dict], path: Path, budget: Budget, state: dict,
            tell_every_s: float = 5.0, label: str = "job") -> str | None:
    """Feed a killed job's logged batches back to a fresh optimiser; the stop reason if it had ended.

    Each batch must be what the optimiser asks again, and the job's budget and the optimiser's
    stop are applied before each one exactly as the run loop applies them: a batch the job
    would not have evaluated is refused (RunError; nothing written). A long replay says how far
    it got every ``tell_every_s`` seconds (on stderr).
    """
    last_said = time.perf_counter()
    for i, entry in enumerate(entries):
        if time.perf_counter() - last_said >= tell_every_s:
            last_said = time.perf_counter()
            print(f"{label}: replayed {i}/{len(entries)} batches", file=sys.stderr, flush=True)
        reason = _budget_stop(budget, state, state["offset_s"]) or _optimizer_stop(optimizer)
        if reason is not None:
            raise RunError(f"{path}: the log holds {len(entries)} batches ({sum(len(e['f']) for e in entries)} evals) "
                           f"but this job stops after {i} ({state['n_evals']} evals: {reason}); it was written "
                           "under another budget or stop rule, so it cannot be resumed")
        X_logged = np.asarray(entry["X"], float)
        X_asked = np.asarray(optimizer.ask(), float)
        if (X_logged.ndim != 2 or X_asked[: len(X_logged)].shape != X_logged.shape
                or not np.array_equal(X_asked[: len(X_logged)], X_logged)):
            raise RunError(f"{path}: batch {i} differs from what the optimiser asks again; the log was written "
                           "by another configuration or a non-deterministic optimiser, so it cannot be resumed")
        trimmed = len(X_logged) < len(X_asked)
        over = budget.evals is not None and state["n_evals"] + len(X_asked) > budget.evals
        if trimmed != over or (trimmed and (state["n_evals"] + len(X_logged) != budget.evals or i != len(entries) - 1)):
            raise RunError(f"{path}: batch {i} holds {len(X_logged)} of the {len(X_asked)} points asked, which "
                           f"this job's budget (budget.evals={budget.evals}) does not explain; it cannot be resumed")
        _account(state, entry)
        if trimmed:  # the trimmed last batch of a finished evaluation budget
            return "budget_evals"
        optimizer.tell(X_logged, np.asarray(entry["f"], float))
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


def _lock_job(job_dir: Path, context: str = "") -> "FolderLock":
    """The job folder's lock, held by this process (RunError when another holds it,
    JobFolderError when the folder or its lock file cannot be created)."""
    try:
        return FolderLock(job_dir, "job").acquire()
    except LockError as err:
        raise RunError(str(err)) from None
    except OSError as err:
        raise JobFolderError(f"{job_dir}: cannot create the job folder or its lock ({err}){context}") from None


def record_failure(job_dir: Path, identity: dict, config: dict, exc: BaseException) -> dict:
    """Write the record of a job that failed before its run loop started (e.g. its problem did not build).

    Never replaces a finished record (RunError) and never touches the log; JobFolderError when
    the folder cannot be written.
    """
    job_dir = Path(job_dir)
    lock = _lock_job(job_dir, f" after: {type(exc).__name__}: {exc}")
    try:
        try:
            previous = read_record(job_dir)
        except RecordError:
            previous = None
        if previous is not None and previous.get("status") == "ok":
            raise RunError(f"{job_dir}: {type(exc).__name__}: {exc} (the folder's finished record is left unchanged)")
        now = datetime.now(timezone.utc).isoformat(timespec="seconds")
        name = lambda v: v.get("name") if isinstance(v, dict) else v  # noqa: E731
        record = {
            "schema": SCHEMA,
            "job_key": None,
            "config_hash": config_hash(identity),
            "identity": identity,
            "status": "failed",
            "error": {"type": type(exc).__name__, "message": str(exc),
                      "traceback": "".join(traceback.format_exception(exc))},
            "problem": name(identity.get("problem")), "optimizer": name(identity.get("optimizer")),
            "seed": identity.get("seed"),
            "budget": identity.get("budget"),
            "config": config,
            "space": None, "truth_x": None, "f_truth": None, "f_reference": None, "problem_identity": None,
            "best_x": None, "best_f": None, "best_metrics": {},
            "n_evals": 0, "n_batches": 0, "wall_s": 0.0, "eval_s": 0.0,
            "stop_reason": "error", "started_utc": now, "ended_utc": now,
            **provenance(),
        }
        return _write_record(job_dir, record, record["error"])
    finally:
        lock.release()
