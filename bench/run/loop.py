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
- **A log is this job's.** Every log line carries the job's ``job_key`` (``bench.records``). On resume
  and on skip a line with another key (a log copied from another job folder) is refused, and so is a
  finished record whose log is missing, empty or not the length it records (``n_batches``, ``n_evals``):
  a record without its log cannot be checked or reported. Both messages name both files. Keyless lines
  (logs of harness 0.2 and older) are trusted on ``job.json`` alone, as before, as the log's leading lines only.
- **No symbolic links.** ``evals.jsonl``, ``record.json`` or ``job.json`` that is a symbolic link is refused
  before anything is read or written through it (it could lead outside the sweep).
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
import time
import traceback
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

from bench.errors import BenchError
from bench.problems.base import Problem
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
from bench.run.bookkeeping import account, batch_entry, job_record, outcome, problem_fields
from bench.run.identity import config_hash, header_mismatch, job_header
from bench.run.log_checks import finished_log_problem, foreign_line, keyless_mismatch, linked_file
from bench.run.progress import Progress

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
    log_metrics: str = "improvements",
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
                           progress_every_s, optimizer_class, progress, log_metrics)
    finally:
        lock.release()


def _previous_record(job_dir: Path, header: dict, problem) -> tuple[dict | None, str | None]:
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
    _refuse(finished_log_problem(job_dir, previous, header))
    _refuse(keyless_mismatch(problem, scan_eval_log(job_dir)[0], job_dir))
    return previous, None


def _refuse(why: str | None) -> None:
    if why:
        raise RunError(why)


def _run_locked(problem, make_optimizer, budget, job_dir, identity, config, label, progress_every_s,
                optimizer_class, progress, log_metrics) -> dict:
    """``run_job`` once the folder is locked: skip a finished job, check the folder, run, write the record."""
    header = job_header(identity, problem, optimizer_class)
    _refuse(linked_file(job_dir))
    try:
        previous, corrupt_note = _previous_record(job_dir, header, problem)
    except OSError as err:
        raise JobFolderError(f"{job_dir}: cannot read or set aside its record ({err})") from None
    if previous is not None:
        log.info("%s: already finished in %s, skipped", label, job_dir)
        return previous
    on_disk = _job_file_of_this_job(job_dir, header)
    evals_path = job_dir / "evals.jsonl"

    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    state = {"n_evals": 0, "n_batches": 0, "eval_s": 0.0, "best_f": np.inf, "best_x": None,
             "best_metrics": {}, "offset_s": 0.0}
    stop_reason, error, status = None, None, "ok"
    clock0 = time.perf_counter()
    evals_log, bar = None, None
    try:
        _set_aside_corrupt_record(job_dir, corrupt_note)
        optimizer = make_optimizer()
        entries, complete_bytes, file_bytes = scan_eval_log(job_dir)
        _refuse(foreign_line(entries, job_dir, header))  # RunError: nothing changed
        _refuse(keyless_mismatch(problem, entries, job_dir))
        if entries:
            print(f"{label}: resuming: replaying {len(entries)} logged batches through the optimiser",
                  file=sys.stderr, flush=True)
        stop_reason = _replay(optimizer, entries, evals_path, budget, state,  # RunError: nothing changed
                              tell_every_s=max(0.5, min(float(progress_every_s), 5.0)), label=label)
        evals_log = EvalLog(job_dir)
        if file_bytes > complete_bytes:
            log.warning("%s: dropping a torn last line of %s (%d bytes)", label, evals_path,
                        file_bytes - complete_bytes)
            evals_log.truncate_bytes(complete_bytes)
        if on_disk is None:
            write_json_atomic(job_dir / JOB_FILE, header)
        if entries:
            log.info("%s: resumed after %d logged batches (%d evals)", label, len(entries), state["n_evals"])
        bar = Progress(label, budget, max(0.5, min(float(progress_every_s), 5.0)), progress, state["n_evals"])
        clock0 = time.perf_counter() - state["offset_s"]  # after the set-up: wall_s times the loop
        stop_reason = _run_batches(problem, optimizer, budget, state, evals_log, bar, clock0, stop_reason,
                                   header["job_key"], log_metrics)
    except RunError as exc:
        if evals_log is None:  # refused before anything was written
            raise
        status, stop_reason, error = "failed", "error", _error(exc)
    except Exception as exc:
        status, stop_reason, error = "failed", "error", _error(exc)
    finally:
        if bar is not None:
            bar.close()
        if evals_log is not None:
            status, stop_reason, error = _close_log(evals_log, evals_path, status, stop_reason, error)
    if error is not None:
        log.error("%s failed: %s: %s", label, error["type"], error["message"])
    else:
        log.info("%s: %d evals, best f %.6g, %s", label, state["n_evals"], state["best_f"], stop_reason)

    record = job_record(
        identity, header["job_key"], header["config_hash"], header["code"], status, error,
        {"evals": budget.evals, "seconds": budget.seconds}, config or {}, problem_fields(problem),
        outcome(state, time.perf_counter() - clock0, stop_reason, started),
    )
    return _write_record(job_dir, record, error)


def _job_file_of_this_job(job_dir: Path, header: dict) -> dict | None:
    """The folder's ``job.json`` (None when absent) once it is known to be this job's; RunError otherwise."""
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
    return on_disk


def _set_aside_corrupt_record(job_dir: Path, corrupt_note: str | None) -> None:
    """Keep an unreadable previous record as ``record.json.corrupt`` and fail the job with why (RecordError)."""
    if corrupt_note:
        kept = job_dir / f"{RECORD}.corrupt"
        os.replace(job_dir / RECORD, kept)
        raise RecordError(f"the previous record was unreadable ({corrupt_note}; kept as {kept.name}); run "
                          "the job again to resume from its log")


def _run_batches(problem, optimizer, budget: Budget, state: dict, evals_log: EvalLog, bar: Progress,
                 clock0: float, stop_reason: str | None, job_key: str, log_metrics: str) -> str:
    """Ask, evaluate, log (each line keyed by ``job_key``, metrics as ``log_metrics`` says: bookkeeping)
    and tell batches until a budget or the optimiser stops; the stop reason."""
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
        entry = batch_entry(state, X, f, metrics, t_start, t_end, log_metrics)
        entry["job_key"] = job_key
        evals_log.append(entry)
        account(state, entry)
        if trimmed:
            stop_reason = "budget_evals"
        else:
            optimizer.tell(X, f)
        bar.update(len(X), state["best_f"])
    return stop_reason


def _close_log(evals_log: EvalLog, evals_path: Path, status: str, stop_reason: str | None,
               error: dict | None) -> tuple[str, str | None, dict | None]:
    """Close the log; a failure to close fails the job, but never hides an earlier error."""
    try:
        evals_log.close()
    except OSError as exc:  # e.g. a full disk: the last flush failed; never hides an earlier error
        close_error = _error(exc)
        if error is None:
            status, stop_reason, error = "failed", "error", close_error
        else:
            error["also"] = f"closing {evals_path} failed too: {close_error['message']}"
    return status, stop_reason, error


def _error(exc: BaseException) -> dict:
    return {"type": type(exc).__name__, "message": str(exc), "traceback": traceback.format_exc()}


def _write_record(job_dir: Path, record: dict, error: dict | None) -> dict:
    try:
        write_json_atomic(job_dir / RECORD, record)
        return read_record(job_dir)
    except (OSError, RecordError) as err:
        first = f" after the job failed with {error['type']}: {error['message']}" if error else ""
        raise JobFolderError(f"{job_dir}: cannot write {RECORD} ({type(err).__name__}: {err}){first}") from None


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
        account(state, entry)
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
        error = {"type": type(exc).__name__, "message": str(exc), "traceback": "".join(traceback.format_exception(exc))}
        no_problem = {"space": None, "truth_x": None, "f_truth": None, "f_reference": None, "problem_identity": None}
        no_outcome = {"best_x": None, "best_f": None, "best_metrics": {}, "n_evals": 0, "n_batches": 0,
                      "wall_s": 0.0, "eval_s": 0.0, "stop_reason": "error", "started_utc": now, "ended_utc": now}
        record = job_record(identity, None, config_hash(identity), None, "failed", error, identity.get("budget"),
                             config, no_problem, no_outcome)
        return _write_record(job_dir, record, record["error"])
    finally:
        lock.release()
