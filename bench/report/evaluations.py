"""Every evaluation of every job as one table: ``report/evaluations.parquet``.

One row per evaluation, jobs in the order of ``runs.csv`` (problem, optimizer, seed) and
evaluations in the order they were evaluated. Columns:

- the job: ``problem``, ``optimizer`` (the leaderboard's labels, settings included when they
  differ, e.g. ``synthetic[data_seed=1]``), ``problem_name``, ``optimizer_name`` (the plain
  names), ``seed``, ``job_key``, ``config_hash`` (from record.json; missing when the record has
  none), ``job`` (the job folder relative to the DIR it was found in, as in runs.csv), ``status``;
- the evaluation: ``batch`` (0-based batch index of the log), ``batch_size``, ``index_in_batch``
  (0-based), ``eval`` (1-based count over the job: the harness charges a batch of n with n
  evaluations), ``f``;
- the batch's times from the log, in seconds since the job started: ``t_start_s``, ``t_end_s``,
  ``eval_s`` (time inside ``Problem.evaluate`` for the whole batch), shared by its evaluations;
- ``x.<name>`` the decision variables by the record's space names, ``m.<name>`` the metrics.

Read it with ``pandas.read_parquet("report/evaluations.parquet")``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bench.records import read_eval_log

JOB_COLUMNS = ["problem", "optimizer", "problem_name", "optimizer_name", "seed", "job_key", "config_hash", "job",
               "status"]
EVAL_COLUMNS = ["batch", "batch_size", "index_in_batch", "eval", "f", "t_start_s", "t_end_s", "eval_s"]
TIME_FIELDS = ("t_start_s", "t_end_s", "eval_s")


def _names(record: pd.Series, d: int) -> list[str]:
    names = record.get("space.names")
    if isinstance(names, (list, tuple, np.ndarray)) and len(names) == d:
        return [str(n) for n in names]
    return [f"x{i}" for i in range(d)]


def _text(value) -> str | None:
    return None if value is None or (isinstance(value, float) and np.isnan(value)) else str(value)


def job_evaluations(job_dir: Path, record: pd.Series) -> pd.DataFrame:
    """The evaluation rows of one job (without the job columns); empty when it logged none."""
    entries = read_eval_log(job_dir)
    if not entries:
        return pd.DataFrame(columns=EVAL_COLUMNS)
    sizes = np.array([len(e["f"]) for e in entries], int)
    n = int(sizes.sum())
    cols: dict[str, np.ndarray] = {
        "batch": np.repeat([int(e.get("batch", i)) for i, e in enumerate(entries)], sizes),
        "batch_size": np.repeat(sizes, sizes),
        "index_in_batch": np.concatenate([np.arange(s) for s in sizes]),
        "eval": np.arange(1, n + 1),
        "f": np.concatenate([np.asarray(e["f"], float).reshape(-1) for e in entries]),
    }
    for field in TIME_FIELDS:
        cols[field] = np.repeat([float(e[field]) if e.get(field) is not None else np.nan for e in entries], sizes)
    X = np.concatenate([np.asarray(e["X"], float).reshape(len(e["f"]), -1) for e in entries])
    for i, name in enumerate(_names(record, X.shape[1])):
        cols[f"x.{name}"] = X[:, i]
    keys = sorted({k for e in entries for k in (e.get("metrics") or {})})
    for key in keys:
        cols[f"m.{key}"] = np.concatenate([
            np.asarray((e.get("metrics") or {}).get(key, [np.nan] * s), float).reshape(-1)
            for e, s in zip(entries, sizes)])
    return pd.DataFrame(cols)


def evaluations_table(records: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """One row per evaluation of every job of ``runs`` (``runs_table``), see the module docstring.

    records: ``load_job_records`` (for ``job``, ``job_key``, ``config_hash`` and the space names).
    """
    by_dir = records.set_index(records["job_dir"].astype(str))
    frames = []
    for run in runs.itertuples(index=False):
        record = by_dir.loc[run.job_dir]
        rows = job_evaluations(Path(run.job_dir), record)
        job = {"problem": run.problem, "optimizer": run.optimizer, "problem_name": run.problem_name,
               "optimizer_name": run.optimizer_name, "seed": int(run.seed),
               "job_key": _text(record.get("job_key")), "config_hash": _text(record.get("config_hash")),
               "job": str(record["job"]), "status": run.status}
        for pos, (key, value) in enumerate(job.items()):
            rows.insert(pos, key, [value] * len(rows))
        frames.append(rows)
    frames = [f for f in frames if len(f)] or frames[:1]
    out = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=JOB_COLUMNS + EVAL_COLUMNS)
    xs = [c for c in out.columns if c.startswith("x.")]
    ms = sorted(c for c in out.columns if c.startswith("m."))
    out = out[JOB_COLUMNS + EVAL_COLUMNS + xs + ms]
    int_cols = ["seed", "batch", "batch_size", "index_in_batch", "eval"]
    out[int_cols] = out[int_cols].astype("int64")
    for col in JOB_COLUMNS:
        if col != "seed":
            out[col] = out[col].astype(object)
    return out


def write_evaluations(records: pd.DataFrame, runs: pd.DataFrame, path: Path) -> Path:
    """``evaluations_table`` as Parquet (pyarrow, no index); byte-identical for the same records."""
    evaluations_table(records, runs).to_parquet(path, index=False, engine="pyarrow")
    return path
