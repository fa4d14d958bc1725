"""Hydra callbacks: one sweep per folder (a lock), a count of every job's outcome, the report at the end.

``SweepReport`` runs in the sweep's main process. ``on_multirun_start`` takes the sweep folder's
lock before Hydra writes anything there (a second sweep into the same folder fails fast, exit 2,
naming the holder) and starts a fresh outcome list; each job, in whatever process a launcher
runs it, appends one line to it (``note_outcome``); ``on_multirun_end`` builds the report and
prints, as the sweep's last lines, which jobs failed, how many ended ok, and where the records and
the report are (``report.html`` last). ``LAST_SWEEP`` keeps
the counts for ``bench.__main__``, which exits 1 when any job failed.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from bench.records import FolderLock, LockError, RecordError, open_no_follow

log = logging.getLogger(__name__)

OUTCOMES = ".outcomes.jsonl"
PLANNED = ".jobs.txt"  # the sweep's job folders, relative, one a line (for bench.status: jobs not started yet)
LAST_SWEEP: dict = {}


def note_outcome(sweep_dir: Path, num: int, label: str, outcome: dict) -> None:
    """Append one job's outcome to the sweep's list (one ``write`` on an O_APPEND descriptor, so
    lines from parallel workers never interleave)."""
    error = outcome.get("error") or {}
    line = json.dumps({"num": num, "label": label, "status": outcome.get("status"),
                       "message": error.get("message", ""), "job_dir": outcome.get("job_dir")}) + "\n"
    try:
        fd = open_no_follow(Path(sweep_dir) / OUTCOMES, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)
    except (OSError, RecordError) as err:  # the job is then counted as "did not report" at the end
        log.error("%s: cannot note its outcome in %s: %s", label, sweep_dir, err)


def write_planned(sweep_dir: Path, job_dirs: list[str]) -> None:
    """Write the sweep's job folders (relative to it) to ``PLANNED``, atomically."""
    tmp = Path(sweep_dir) / f"{PLANNED}.{os.getpid()}.tmp"
    tmp.write_text("".join(f"{d}\n" for d in job_dirs))
    os.replace(tmp, Path(sweep_dir) / PLANNED)


def read_outcomes(sweep_dir: Path) -> list[dict]:
    path = Path(sweep_dir) / OUTCOMES
    if not path.exists() and not path.is_symlink():
        return []
    try:
        with open_no_follow(path, os.O_RDONLY, "r") as fh:
            return [json.loads(line) for line in fh.read().splitlines() if line.strip()]
    except RecordError as err:  # a link is not followed: every job then counts as "did not report"
        log.error("%s", err)
        return []


class SweepReport(Callback):
    """Lock the sweep folder, count job outcomes, build ``bench.report`` at the end (see the module doc).

    Hydra hands this only the config, so the results are read back from the folder.
    """

    def __init__(self) -> None:
        self._lock: FolderLock | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        try:
            self._lock = FolderLock(sweep_dir, "sweep folder").acquire()
            (sweep_dir / OUTCOMES).write_text("")
            if LAST_SWEEP.get("planned"):
                write_planned(sweep_dir, LAST_SWEEP["planned"])
        except LockError as err:
            print(f"error: {err}", file=sys.stderr)
            raise SystemExit(2) from None
        except OSError as err:
            print(f"error: hydra.sweep.dir={sweep_dir}: cannot write there ({err})", file=sys.stderr)
            raise SystemExit(2) from None
        LAST_SWEEP["sweep_dir"] = sweep_dir  # named by bench.__main__ after a Ctrl-C
        n = os.environ.get("BENCH_SWEEP_JOBS")
        jobs = "jobs" if not n else f"{n} job" + ("" if n == "1" else "s")
        print(f"Sweep: {jobs} into {sweep_dir}", file=sys.stderr, flush=True)

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        if "submitted" in LAST_SWEEP:  # hydra.launcher.wait=false: the jobs run on after this process
            self._submitted(sweep_dir, LAST_SWEEP.pop("submitted"))
            return
        try:
            report_error, where = self._report(config, sweep_dir)
            outcomes = read_outcomes(sweep_dir)
        finally:
            if self._lock is not None:
                self._lock.release()
        expected = int(os.environ.get("BENCH_SWEEP_JOBS") or len(outcomes))
        bad = [o for o in outcomes if o["status"] != "ok"]
        missing = max(0, expected - len(outcomes))
        n_failed = len(bad) + missing + (1 if report_error else 0)
        LAST_SWEEP.clear()
        LAST_SWEEP.update(n_jobs=expected, n_ok=len(outcomes) - len(bad), n_failed_jobs=len(bad) + missing,
                          n_failed=n_failed, report_error=report_error)
        for o in sorted(bad, key=lambda o: o["num"]):
            print(f"  {o['status']}: {o['label']}: {o['message']}")
        if missing:
            print(f"  {missing} job(s) did not report an outcome (killed, or their folder could not be written)")
        if report_error:
            print(f"  report failed: {report_error}")
        print(f"Jobs: {expected} in all, {len(outcomes) - len(bad)} ok, {len(bad) + missing} failed"
              + (" (exit code 1)" if n_failed else ""))
        for line in where:  # the sweep's last lines: where its results are, report.html last
            print(line)

    def _submitted(self, sweep_dir: Path, submitted: dict) -> None:
        if self._lock is not None:
            self._lock.release()
        LAST_SWEEP.update(n_jobs=submitted["n_jobs"], n_failed=0)
        print(f"Submitted: {submitted['n_jobs']} jobs in {submitted['n_tasks']} array tasks "
              f"(SLURM job(s) {', '.join(submitted['job_ids'])}); they run on after this command.")
        print(f"Follow:      python -m bench.status {sweep_dir}")
        print(f"Report:      python -m bench.report {sweep_dir}   (when they have ended)")

    def _report(self, config: DictConfig, sweep_dir: Path) -> tuple[str | None, list[str]]:
        """(the report's error or None, the lines that say where the results are)."""
        if not config.get("report", True):
            return None, [f"Records:     {sweep_dir}"]
        if not any(sweep_dir.rglob("record.json")):
            return None, [f"Records:     {sweep_dir} (none written: no report)"]
        from bench.report.build import build_report

        print("Report: building the leaderboard, statistics, tables and figures ...", file=sys.stderr, flush=True)
        try:
            out = build_report([sweep_dir], sweep_dir / "report")
        except Exception as err:
            log.exception("the report of %s failed", sweep_dir)
            return f"{type(err).__name__}: {err}", [f"Records:     {sweep_dir}"]
        folder = out.parent if out.is_file() else out
        return None, [f"Records:     {sweep_dir}",
                      f"Leaderboard: {folder / 'leaderboard.csv'}",
                      f"Markdown:    {folder / 'report.md'}",
                      f"Report:      {folder / 'report.html'}"]
