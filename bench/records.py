"""Run records on disk: the append-only evaluation log and the final record of one job.

A job folder holds
- ``evals.jsonl``: one JSON object per evaluated batch, appended and flushed as it happens:
  ``{"batch": i, "n": n, "evals_total": k, "t_start_s": .., "t_end_s": .., "eval_s": ..,
  "X": [[..]], "f": [..], "metrics": {name: [..]}}`` (times in seconds since the job started;
  ``eval_s`` is the time spent inside ``Problem.evaluate``). Python's JSON writes floats with
  ``repr`` so they read back bit-for-bit.
- ``record.json``: the final record, written atomically (temp file + rename), with
  ``status`` "ok" or "failed"; see ``bench.run`` for its fields.

Records are plain JSON: nothing is ever unpickled.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import orjson
import pandas as pd

EVAL_LOG = "evals.jsonl"
RECORD = "record.json"


class RecordError(ValueError):
    """A record or log file is unreadable; the message names the file and line."""


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


def write_json_atomic(path: Path, payload: dict) -> None:
    """Write ``payload`` as JSON to ``path`` so that readers see the old or the new file, never half."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
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


class EvalLog:
    """Append-only evaluation log of one job (``evals.jsonl``)."""

    def __init__(self, job_dir: Path) -> None:
        self.path = Path(job_dir) / EVAL_LOG
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = None

    def append(self, entry: dict) -> None:
        if self._fh is None:
            self._fh = open(self.path, "ab")
        # flushed to the kernel, which survives a killed process; an fsync per batch would cost
        # more than the harness's whole overhead budget on a cheap objective
        self._fh.write(_dumps_line(entry))
        self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def truncate_to(self, n_batches: int) -> None:
        """Keep only the first ``n_batches`` complete lines (drops a torn last line after a kill)."""
        self.close()
        entries = read_eval_log(self.path.parent)[:n_batches]
        tmp = self.path.with_suffix(".jsonl.tmp")
        with open(tmp, "w") as fh:
            for entry in entries:
                fh.write(json.dumps(entry, sort_keys=True) + "\n")
        os.replace(tmp, self.path)


def read_eval_log(job_dir: Path) -> list[dict]:
    """The batches of a job's log in order; a torn (unterminated) last line is ignored."""
    path = Path(job_dir) / EVAL_LOG
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.split("\n")
    complete = lines[:-1]  # the piece after the last newline is empty or a torn write
    entries = []
    for number, line in enumerate(complete, start=1):
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError as err:
            raise RecordError(f"{path}:{number}: not a JSON line ({err.msg})") from None
    return entries


def read_record(job_dir: Path) -> dict | None:
    """The final record of a job, or None when the job has not finished."""
    path = Path(job_dir) / RECORD
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise RecordError(f"{path}: corrupt record ({err.msg} at line {err.lineno})") from None
    record["job_dir"] = str(Path(job_dir))
    return record


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
    rows = [read_record(d) for d in find_job_dirs(roots)]
    if not rows:
        return pd.DataFrame()
    return pd.json_normalize(rows, sep=".")


def eval_log_frame(job_dir: Path, names: list[str] | None = None) -> pd.DataFrame:
    """One row per evaluation of a job, in order: ``batch``, ``eval`` (1-based count),
    ``t_end_s``, ``f``, ``best_f`` (best so far), metric columns ``m.<name>``, and
    ``x.<name>`` columns (names from ``names`` or x0, x1, ...)."""
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
