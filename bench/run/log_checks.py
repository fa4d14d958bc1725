"""Is a job folder's log this job's, whole? The checks ``bench.run.loop`` makes before it resumes or
skips a job (its module docstring: "A log is this job's", "No symbolic links"). Each returns why
not, naming the files, or None; the loop refuses the job with it and changes nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.records import EVAL_LOG, JOB_FILE, RECORD, RecordError, refuse_symlink, scan_eval_log


def linked_file(job_dir: Path) -> str | None:
    """Why not, when a job file is a symbolic link (nothing is read or written through one): the
    harness's files, and Hydra's ``.hydra/`` folder, its files and the job's ``*.log``."""
    job_dir = Path(job_dir)
    hydra_dir = job_dir / ".hydra"
    hydra_files = sorted(hydra_dir.glob("*")) if hydra_dir.is_dir() and not hydra_dir.is_symlink() else []
    logs = sorted(job_dir.glob("*.log")) if job_dir.is_dir() else []
    for path in (job_dir / EVAL_LOG, job_dir / RECORD, job_dir / JOB_FILE, hydra_dir, *hydra_files, *logs):
        try:
            refuse_symlink(path)
        except RecordError as err:
            return str(err)
    return None


def foreign_line(entries: list[dict], job_dir: Path, header: dict) -> str | None:
    """Why not, when a log line was written by another job (its ``job_key``), or is keyless after a
    keyed one (the logs of older harnesses are keyless from their first line)."""
    keyed = False
    for i, entry in enumerate(entries):
        key = entry.get("job_key")
        if key is None and not keyed:
            continue  # a line of an older harness: trusted on job.json, as it always was
        keyed = True
        if key != header["job_key"]:
            written_by = "a line without a job key after keyed ones" if key is None else f"job {key}"
            log, job_file = Path(job_dir) / EVAL_LOG, Path(job_dir) / JOB_FILE
            return (f"{log}: batch {i} was written by {written_by}, but {job_file} is job {header['job_key']}: "
                    "the log was copied from another job folder (or mixed with one), so it is neither resumed nor "
                    "skipped; move it away, or restore the job's own log")
    return None


def finished_log_problem(job_dir: Path, record: dict, header: dict) -> str | None:
    """Why a finished record is not skipped: its log is unreadable, another job's, missing, empty or not
    the length the record says (``n_batches``, ``n_evals``). Both files are named."""
    record_path, evals_path = Path(job_dir) / RECORD, Path(job_dir) / EVAL_LOG
    try:
        entries, complete_bytes, file_bytes = scan_eval_log(job_dir)
    except RecordError as err:
        return (f"{record_path} is finished, but its log is unreadable ({err}); it is not skipped: move both "
                "files away to run the job again")
    why = foreign_line(entries, job_dir, header)
    if why:
        return why
    n_batches, n_evals = len(entries), sum(len(e["f"]) for e in entries)
    if (n_batches, n_evals, file_bytes) == (record.get("n_batches"), record.get("n_evals"), complete_bytes):
        return None
    torn = " and a torn last line" if file_bytes > complete_bytes else ""
    state = ("is missing" if not evals_path.exists() else "is empty" if not file_bytes else
             f"holds {n_batches} batches ({n_evals} evals){torn}")
    return (f"{record_path} records {record.get('n_batches')} batches ({record.get('n_evals')} evals), but "
            f"{evals_path} {state}: a record without its whole log cannot be checked or reported, so it is not "
            "skipped; restore the log, or move both files away to run the job again")


def keyless_mismatch(problem, entries: list[dict], job_dir: Path) -> str | None:
    """Why not, when the log's leading keyless lines (an older harness's) are not this job's: the last
    of them is evaluated again and must give the logged values bit for bit (the objective is
    deterministic). A key would say whose lines they are; without one, one batch of work does."""
    keyless = [e for e in entries if e.get("job_key") is None]
    if not keyless:
        return None
    entry = keyless[-1]
    f_now = np.asarray(problem.evaluate(np.asarray(entry["X"], dtype=float))[0], dtype=float)
    f_logged = np.asarray([np.nan if v is None else v for v in entry["f"]], dtype=float)
    if f_now.shape == f_logged.shape and np.array_equal(f_now, f_logged, equal_nan=True):
        return None
    log, job_file = Path(job_dir) / EVAL_LOG, Path(job_dir) / JOB_FILE
    return (f"{log}: its lines carry no job key (an older harness's log), and its batch {len(keyless) - 1} "
            f"evaluated again does not give the logged values, so it was not written by the job of {job_file}: "
            "it is neither resumed nor skipped; move it away, or restore the job's own log")
