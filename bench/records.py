"""Run records on disk: the append-only evaluation log and the final record of one job.

A job folder holds
- ``evals.jsonl``: one JSON object per evaluated batch, appended and flushed as it happens:
  ``{"batch": i, "n": n, "evals_total": k, "t_start_s": .., "t_end_s": .., "eval_s": ..,
  "X": [[..]], "f": [..], "metrics": {name: [..]}}`` (times in seconds since the job started;
  ``eval_s`` is the time spent inside ``Problem.evaluate``). Python's JSON writes floats with
  ``repr`` so they read back bit-for-bit. With ``log_metrics: improvements`` (the default) a batch
  keeps its metrics only at the points that improved the job's best so far (and the job's first
  point), listed in ``"metrics_at": [i, ..]`` when they are not all of it; the readers below give
  every batch's metrics at full length, NaN where none were kept (:func:`dense_metrics`).
- ``record.json``: the final record, written atomically (temp file + rename), with
  ``status`` "ok" or "failed"; see ``bench.run`` for its fields.
- ``job.json``: the job's identity, written before the first batch is logged: the hash of the
  resolved job config, the config itself, the problem's data identity and the code version
  (``bench.run.job_header``). A log is only ever resumed by the job that wrote it.
- ``.lock``: the lock file one process holds (``fcntl.flock``) for the job's whole lifetime;
  it names the holder (pid, host, start time).

Every line of ``evals.jsonl`` also carries ``"job_key"``, the key of the job that wrote it (the
``job_key`` of ``job.json`` and ``record.json``): a log copied from another job folder is refused on
resume and on skip (``bench.run.loop``), naming both files. Lines written before the key existed
(harness 0.2 and older) carry none: they are still resumed or skipped when ``job.json`` is this job's
and the last keyless batch, evaluated again, gives the logged values bit for bit (refusing them would
throw away every unfinished job of an upgraded sweep; trusting them on ``job.json`` alone would replay a
copied log), and only as the log's leading lines: a keyless line after a keyed one is refused.

No file of a job folder is ever written through a symbolic link (one could point outside the sweep,
into another job or a file of the user's): the log is opened with ``O_NOFOLLOW``, the lock file too,
and ``write_json_atomic`` refuses to replace a link (``RecordError`` naming it).

Records, logs and caches are data: they are parsed as JSON, never imported, unpickled or instantiated.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import tempfile
import typing
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import orjson

from bench.errors import BenchError

if typing.TYPE_CHECKING:  # pandas only where records are read back: a job that writes them saves ~0.2 s of import
    import pandas as pd

EVAL_LOG = "evals.jsonl"
RECORD = "record.json"
JOB_FILE = "job.json"
LOCK_FILE = ".lock"
FILE_MODE = 0o644  # like every other file the harness writes (mkstemp alone gives 0600)


class RecordError(BenchError):
    """A record or log file is unreadable; the message names the file and line."""


def job_name(instance, seed) -> str:
    """A job's folder name inside ``<problem>/<optimizer>/`` (``hydra.sweep.subdir``) and its label:
    ``i<instance>``, or ``i<instance>-seed<seed>`` when the optimiser's seed was set apart from the
    instance (so that sweeping ``seed`` on one instance gives each job a folder of its own)."""
    return f"i{instance}" if str(seed) == str(instance) else f"i{instance}-seed{seed}"


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def refuse_symlink(path: Path) -> None:
    """RecordError when ``path`` is a symbolic link (the harness never writes or trusts a file through one)."""
    path = Path(path)
    if path.is_symlink():
        raise RecordError(f"{path} is a symbolic link (to {os.readlink(path)}); a job's files are never written or "
                          "read through one (it could lead outside the sweep): replace it by the file itself")


def write_json_atomic(path: Path, payload: dict) -> None:
    """Write ``payload`` as JSON to ``path`` so that readers see the old or the new file, never half.

    RecordError when ``path`` is a symbolic link: the rename would replace the link, silently."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    refuse_symlink(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, FILE_MODE)
        with os.fdopen(fd, "w") as fh:
            json.dump(_jsonable(payload), fh, indent=1, sort_keys=True)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _all_finite(entry: dict) -> bool:
    arrays = [entry.get("X"), entry.get("f"), *entry.get("metrics", {}).values()]
    return all(np.isfinite(a).all() for a in arrays if a is not None)


def _dumps_line(entry: dict) -> bytes:
    """One log line. orjson (exact shortest float repr) when every number is finite, since it
    writes NaN as null; Python's json, which writes NaN and Infinity, otherwise."""
    if _all_finite(entry):
        contiguous = {k: np.ascontiguousarray(v) if isinstance(v, np.ndarray) else v for k, v in entry.items()}
        if "metrics" in entry:
            contiguous["metrics"] = {k: np.ascontiguousarray(v) for k, v in entry["metrics"].items()}
        return orjson.dumps(contiguous, option=orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_SORT_KEYS) + b"\n"
    return (json.dumps(_jsonable(entry), sort_keys=True) + "\n").encode()


def open_no_follow(path: Path, flags: int, mode: str | None = None):
    """``os.open(path, flags | O_NOFOLLOW, FILE_MODE)`` (a file object when ``mode`` is given); RecordError
    naming the link when ``path`` is a symbolic link."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW, FILE_MODE)
    except OSError as err:
        if err.errno == errno.ELOOP:
            refuse_symlink(path)
        raise
    return fd if mode is None else os.fdopen(fd, mode)


class EvalLog:
    """Append-only evaluation log of one job (``evals.jsonl``)."""

    def __init__(self, job_dir: Path) -> None:
        self.path = Path(job_dir) / EVAL_LOG
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = None

    def append(self, entry: dict) -> None:
        if self._fh is None:
            self._fh = open_no_follow(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, "ab")
        # flushed to the kernel, which survives a killed process; an fsync per batch would cost
        # more than the harness's whole overhead budget on a cheap objective
        self._fh.write(_dumps_line(entry))
        self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def truncate_bytes(self, size: int) -> None:
        """Cut the file to its first ``size`` bytes: drops a torn last line after a kill, nothing else
        (the complete lines before it are not rewritten)."""
        self.close()
        refuse_symlink(self.path)
        os.truncate(self.path, size)


def scan_eval_log(job_dir: Path) -> tuple[list[dict], int, int]:
    """``(entries, complete_bytes, file_bytes)`` of a job's log: the complete lines parsed in order,
    the byte length they span, and the file's length (larger when the last line is torn).

    A line that is not valid JSON before the last newline is corruption, not a torn write:
    RecordError naming the file and line.
    """
    path = Path(job_dir) / EVAL_LOG
    if not path.exists():
        return [], 0, 0
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1  # the piece after the last newline is empty or a torn write
    entries = []
    for number, line in enumerate(data[:end].split(b"\n")[:-1], start=1):
        try:
            entry = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise RecordError(f"{path}:{number}: not a JSON line ({getattr(err, 'msg', err)})") from None
        if not isinstance(entry, dict) or not {"X", "f", "t_end_s"} <= set(entry):
            raise RecordError(f"{path}:{number}: not a batch entry (needs X, f, t_end_s)")
        if "metrics_at" in entry:
            try:
                entry["metrics"] = dense_metrics(entry)
            except (TypeError, ValueError, IndexError) as err:
                raise RecordError(f"{path}:{number}: metrics_at does not fit the batch ({err})") from None
            del entry["metrics_at"]
        entries.append(entry)
    return entries, end, len(data)


def dense_metrics(entry: dict) -> dict[str, np.ndarray]:
    """A batch entry's metrics at full length (n,) floats: those kept at ``metrics_at`` (when the line
    lists them) placed at their points, NaN at the others."""
    metrics = entry.get("metrics") or {}
    at = entry.get("metrics_at")
    if at is None:
        return {k: np.asarray(v, float).reshape(-1) for k, v in metrics.items()}
    out = {}
    for key, values in metrics.items():
        full = np.full(len(entry["f"]), np.nan)
        full[np.asarray(at, int)] = np.asarray(values, float)
        out[key] = full
    return out


def read_eval_log(job_dir: Path) -> list[dict]:
    """The batches of a job's log in order; a torn (unterminated) last line is ignored."""
    return scan_eval_log(job_dir)[0]


def read_record(job_dir: Path) -> dict | None:
    """The final record of a job, or None when the job has not finished.

    RecordError (naming the file) when it is not valid JSON or not a JSON object; the fields
    are checked by their users (the run loop, the leaderboard), which name what is missing.
    """
    path = Path(job_dir) / RECORD
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise RecordError(f"{path}: corrupt record ({getattr(err, 'msg', err)})") from None
    if not isinstance(record, dict):
        raise RecordError(f"{path}: corrupt record (not a JSON object but a {type(record).__name__})")
    record["job_dir"] = str(Path(job_dir))
    return record


def read_job_file(job_dir: Path) -> dict | None:
    """The job's identity (``job.json``), or None when there is none; RecordError when unreadable."""
    path = Path(job_dir) / JOB_FILE
    if not path.exists():
        return None
    try:
        header = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise RecordError(f"{path}: corrupt job identity ({getattr(err, 'msg', err)})") from None
    if not isinstance(header, dict) or "config_hash" not in header:
        raise RecordError(f"{path}: corrupt job identity (no config_hash)")
    return header


class LockError(BenchError):
    """Another process holds the lock; the message names it."""


def lock_holder(folder: Path) -> str | None:
    """Who holds ``folder``'s lock ("pid N on host H (since T)"), or None when it is free or absent.

    Probes with a shared, non-blocking flock on a read-only descriptor: nothing is written.
    """
    path = Path(folder) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    except BlockingIOError:
        return os.pread(fd, 512, 0).decode(errors="replace").strip() or "an unknown process"
    finally:
        os.close(fd)


class FolderLock:
    """An exclusive ``fcntl.flock`` on ``folder/.lock`` held until ``release()`` (or process exit).

    ``acquire()`` never waits: when another process holds the lock it raises LockError naming the
    holder's pid, host and start time (written into the lock file by the holder). The lock file is
    never deleted (deleting it would let a third process lock a new inode while the old one is held).
    """

    def __init__(self, folder: Path, what: str = "job") -> None:
        self.path = Path(folder) / LOCK_FILE
        self.what = what
        self._fd: int | None = None

    def acquire(self) -> "FolderLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = open_no_follow(self.path, os.O_RDWR | os.O_CREAT)
        except RecordError as err:
            raise OSError(errno.ELOOP, str(err)) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 512, 0).decode(errors="replace").strip() or "an unknown process"
            os.close(fd)
            raise LockError(f"{self.path.parent}: this {self.what} is in use by {holder}; wait for it to end "
                            f"or stop it (two writers would lose or duplicate batches)") from None
        me = (f"pid {os.getpid()} on host {socket.gethostname()} "
              f"(since {datetime.now(timezone.utc).isoformat(timespec='seconds')})")
        os.ftruncate(fd, 0)
        os.pwrite(fd, me.encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def find_job_dirs(roots) -> list[Path]:
    """Every folder under ``roots`` (files or folders) that holds a ``record.json``."""
    found = set()
    for root in map(Path, roots):
        if not root.exists():
            raise RecordError(f"{root}: no such file or folder")
        if (root / RECORD).exists():
            found.add(root.resolve())
        found.update(p.parent.resolve() for p in root.rglob(RECORD))
    return sorted(found)


def load_records(roots) -> pd.DataFrame:
    """One row per finished job under ``roots``: the record's scalar fields, flattened."""
    import pandas as pd

    rows = [read_record(d) for d in find_job_dirs(roots)]
    if not rows:
        return pd.DataFrame()
    return pd.json_normalize(rows, sep=".")


def eval_log_frame(job_dir: Path, names: list[str] | None = None) -> pd.DataFrame:
    """One row per evaluation of a job, in order: ``batch``, ``eval`` (1-based count),
    ``t_end_s``, ``f``, ``best_f`` (best so far), metric columns ``m.<name>``, and
    ``x.<name>`` columns (names from ``names`` or x0, x1, ...)."""
    import pandas as pd

    frames = []
    for entry in read_eval_log(job_dir):
        X = np.asarray(entry["X"], float)
        cols = names or [f"x{i}" for i in range(X.shape[1])]
        frame = pd.DataFrame(X, columns=[f"x.{c}" for c in cols])
        frame.insert(0, "f", np.asarray(entry["f"], float))
        frame.insert(0, "t_end_s", entry["t_end_s"])
        frame.insert(0, "batch", entry["batch"])
        for key, values in entry.get("metrics", {}).items():
            frame[f"m.{key}"] = np.asarray(values, float)
        frames.append(frame)
    if not frames:
        return pd.DataFrame(columns=["batch", "t_end_s", "f", "eval", "best_f"])
    out = pd.concat(frames, ignore_index=True)
    out.insert(1, "eval", np.arange(1, len(out) + 1))
    out.insert(out.columns.get_loc("f") + 1, "best_f", out["f"].cummin())
    return out
