"""``python -m bench.status DIR``: where a sweep stands, read from its folder, from any shell, while it runs.

Each job folder is classified without writing anything:

- **running**: its ``.lock`` is held (probed with the same ``flock`` the job holds, shared and non-blocking:
  ``bench.records.lock_holder``), so a job on another node of a shared file system counts too;
- **finished** / **failed**: its ``record.json`` says ``ok`` / ``failed``;
- **interrupted**: a folder with no record and no holder (killed; the same command resumes it);
- **refused**: the sweep's outcome list (``.outcomes.jsonl``) says so (a refused job writes nothing);
- **not started**: planned (``.jobs.txt``, written when the sweep starts) but with no folder yet.

Exit codes: 0, or 2 with one message when DIR is not a sweep folder.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from bench.records import JOB_FILE, LOCK_FILE, RECORD, RecordError, lock_holder, read_record
from bench.run.callbacks import OUTCOMES, PLANNED, read_outcomes

STATES = ("finished", "running", "failed", "refused", "interrupted", "not started")


@dataclass
class SweepStatus:
    """The jobs of one sweep folder by state (relative job folders), and the seconds each took or has run."""

    folder: Path
    jobs: dict[str, list[str]] = field(default_factory=lambda: {s: [] for s in STATES})
    seconds: dict[str, float] = field(default_factory=dict)
    messages: dict[str, str] = field(default_factory=dict)
    planned: bool = False

    def counts(self) -> dict[str, int]:
        return {state: len(names) for state, names in self.jobs.items()}


def _since(holder: str) -> float | None:
    """Seconds since the lock holder started (its lock file says "... (since ISO-TIME)")."""
    if "(since " not in holder:
        return None
    try:
        started = datetime.fromisoformat(holder.rsplit("(since ", 1)[1].rstrip(")"))
    except ValueError:
        return None
    return max(0.0, time.time() - started.timestamp())


def _job_folders(folder: Path) -> set[Path]:
    """Every job folder under ``folder``: one that holds a lock, a job file or a record."""
    found = set()
    for name in (LOCK_FILE, JOB_FILE, RECORD):
        found.update(p.parent for p in folder.rglob(name) if p.parent != folder)
    return found


def sweep_status(folder: Path) -> SweepStatus:
    """Classify every job of the sweep in ``folder`` (see the module doc); nothing is written."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordError(f"{folder}: no such folder")
    planned_file = folder / PLANNED
    if not (planned_file.exists() or (folder / OUTCOMES).exists() or any(folder.rglob(RECORD))):
        raise RecordError(f"{folder}: not a sweep folder (no {PLANNED}, {OUTCOMES} or record.json under it)")
    status = SweepStatus(folder)
    planned = [line for line in planned_file.read_text().splitlines() if line] if planned_file.exists() else []
    status.planned = bool(planned)
    refused = {str(Path(o["job_dir"]).resolve()): o.get("message", "") for o in read_outcomes(folder)
               if o.get("status") == "refused" and o.get("job_dir")}
    existing = {str(p.relative_to(folder)): p for p in _job_folders(folder)}
    for rel in sorted(set(planned) | set(existing)):
        path = folder / rel
        state, seconds = _classify(path, refused)
        status.jobs[state].append(rel)
        if seconds is not None:
            status.seconds[rel] = seconds
        if state in ("failed", "refused"):
            status.messages[rel] = refused.get(str(path.resolve())) or _error(path)
    return status


def _classify(path: Path, refused: dict[str, str]) -> tuple[str, float | None]:
    if not path.is_dir():
        return ("refused" if str(path.resolve()) in refused else "not started"), None
    holder = lock_holder(path)
    if holder:
        return "running", _since(holder)
    try:
        record = read_record(path)
    except RecordError:
        return "failed", None
    if record is None:
        return ("refused" if str(path.resolve()) in refused else "interrupted"), None
    return ("finished" if record.get("status") == "ok" else "failed"), record.get("wall_s")


def _error(path: Path) -> str:
    try:
        record = read_record(path) or {}
    except RecordError as err:
        return str(err)
    error = record.get("error") or {}
    return f"{error.get('type', '')}: {error.get('message', '')}".strip(": ")


def format_status(status: SweepStatus, n_slowest: int = 5) -> str:
    """The lines ``python -m bench.status`` prints: the counts, the slowest jobs, the failed and refused ones."""
    counts = status.counts()
    total = sum(counts.values())
    lines = [f"Sweep {status.folder}: {total} jobs"
             + ("" if status.planned else f" found (no {PLANNED}: jobs not started yet are not counted)")]
    lines.append("  " + ", ".join(f"{counts[s]} {s}" for s in STATES))
    timed = sorted(status.seconds.items(), key=lambda kv: -kv[1])[:n_slowest]
    if timed:
        lines.append("Slowest (seconds; running ones so far):")
        running = set(status.jobs["running"])
        lines += [f"  {s:9.1f}  {rel}{' (running)' if rel in running else ''}" for rel, s in timed]
    for state in ("failed", "refused"):
        if status.jobs[state]:
            lines.append(f"{state.capitalize()}:")
            lines += [f"  {rel}: {status.messages.get(rel, '')}" for rel in status.jobs[state]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.status",
                                     description="Counts of a sweep's jobs by state, while it runs or after.")
    parser.add_argument("dir", help="the sweep folder (hydra.sweep.dir)")
    parser.add_argument("--json", action="store_true", help="print the jobs by state as JSON")
    args = parser.parse_args(argv)
    try:
        status = sweep_status(Path(args.dir))
    except (RecordError, OSError) as err:
        print(f"bench.status: error: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"counts": status.counts(), "jobs": status.jobs, "seconds": status.seconds,
                          "messages": status.messages}, indent=1))
    else:
        print(format_status(status))
    return 0


if __name__ == "__main__":
    sys.exit(main())
