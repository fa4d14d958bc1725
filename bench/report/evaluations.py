"""Every evaluation of every job: one table (``report/evaluations.parquet``) and the IOHprofiler
export (``report/iohprofiler/``).

**The table** (``write_evaluations``).

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
- ``x.<name>`` the decision variables by the record's space names, ``m.<name>`` the metrics (NaN
  where the log kept none: ``log_metrics``, bench.records).

Read it with ``pandas.read_parquet("report/evaluations.parquet")``.

**IOHprofiler export** (``write_iohprofiler``): the records in the IOHprofiler format, for
IOHanalyzer, in ``report/iohprofiler/``.

Written by ``ioh``'s own logger (``ioh.logger.Analyzer``): each job's logged evaluations are
replayed, in order, through a problem (a ``RealSingleObjective`` subclass) that returns the
logged f, so the files are exactly what ioh writes for a live run. Layout (IOHanalyzer loads the
folder, or a zip of it, as one data set):

- one sub-folder per optimiser (the leaderboard's label, e.g. ``pso`` or ``pso[pop_size=10]``,
  made file-safe), the IOHprofiler *algorithm* (``algorithm.name`` = the label,
  ``algorithm.info`` = the plain optimiser name);
- in it, per problem setting, ``IOHprofiler_f<id>_<name>.json`` and
  ``data_f<id>_<name>/IOHprofiler_f<id>_DIM<d>.dat``: the *function* is the leaderboard's problem
  label (name + the settings that differ between records, e.g. ``synthetic[data_seed=1]``, made
  file-safe), ``<id>`` its 1-based position among the sorted labels, the same in every folder
  (``functions.csv`` maps id, name and label); instance 1;
- one *run* per job (in seed order), with the job's ``seed`` as a run attribute. A job that
  logged no evaluation has no run (ioh writes none).

**How evaluations are charged.** As the harness counts them: a batch of n points charges n
evaluations. Every evaluation is one line of the .dat file, in the order of the log (within a
batch, in the order of its points): ``evaluations`` (1-based count), ``raw_y`` (that
evaluation's f; the ALWAYS trigger logs every evaluation, so IOHanalyzer derives best-so-far from
these lines), plus ``batch`` (0-based batch index) and ``t_end_s`` (seconds from the job's start
to the end of the batch, the same for its points). Each run's ``best`` in the .json is ioh's
best-so-far at the end of the run (its evaluation count, y and x). Values are written with
round-trip precision (``%.17g``); ioh writes an infinite f as ``None``. The harness never logs a
non-finite x; were one there, it would be replayed as 0 (it only shows in a run's ``best.x``).

Nothing here depends on the time or the machine: two builds from the same records are byte-identical.
"""

from __future__ import annotations

import re
import shutil
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


# --- the IOHprofiler export -------------------------------------------------------------


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "x"


def _unique(labels) -> dict[str, str]:
    out, used = {}, set()
    for label in sorted(set(labels)):
        slug = _slug(label)
        while slug in used:
            slug += "_"
        used.add(slug)
        out[label] = slug
    return out


class _Tracker:
    """What the extra .dat columns read at each logged evaluation."""

    def __init__(self) -> None:
        self.batch = 0.0
        self.t_end_s = float("nan")


def write_iohprofiler(runs: pd.DataFrame, out: Path) -> list[Path]:
    """Write ``out`` (replaced when it exists) from the jobs of ``runs`` (``runs_table``); return its files."""
    import ioh

    class Replay(ioh.iohcpp.problem.RealSingleObjective):
        """A problem whose f is the next logged value: evaluating it replays a run for ioh's logger."""

        def __init__(self, name: str, d: int) -> None:
            super().__init__(name, d, 1, True)
            self.values: list[float] = []

        def evaluate(self, x):
            return self.values.pop(0)

    out = Path(out)
    if out.exists():
        shutil.rmtree(out)  # the Analyzer would write beside old files into "<name>-1"
    out.mkdir(parents=True)
    functions = _unique(runs["problem"])
    ids = {label: i for i, label in enumerate(sorted(functions), start=1)}
    algorithms = _unique(runs["optimizer"])
    pd.DataFrame({"function_id": [ids[p] for p in sorted(functions)],
                  "function_name": [functions[p] for p in sorted(functions)],
                  "problem": sorted(functions)}).to_csv(out / "functions.csv", index=False, lineterminator="\n")
    keep = []  # ioh's logger refers to its problems until it is closed
    for optimizer in sorted(algorithms):
        mine = runs[runs["optimizer"] == optimizer].sort_values(["problem", "seed", "job_dir"], kind="stable")
        tracker = _Tracker()
        # the logger keeps pointers to its triggers and properties: they must outlive it (keep)
        triggers = [ioh.logger.trigger.ALWAYS]
        properties = [ioh.logger.property.Property(tracker, "batch"), ioh.logger.property.Property(tracker, "t_end_s")]
        keep += [tracker, triggers, properties]
        logger = ioh.logger.Analyzer(
            triggers=triggers, root=str(out), folder_name=algorithms[optimizer],
            algorithm_name=optimizer, algorithm_info=str(mine["optimizer_name"].iloc[0]),
            additional_properties=properties)
        logger.full_precision = True
        logger.add_run_attribute("seed", 0.0)
        problems: dict[tuple[str, int], Replay] = {}
        for run in mine.itertuples(index=False):
            entries = read_eval_log(Path(run.job_dir))
            if not entries:
                continue
            d = int(np.asarray(entries[0]["X"], float).reshape(len(entries[0]["f"]), -1).shape[1])
            key = (run.problem, d)
            if key not in problems:
                problems[key] = Replay(functions[run.problem], d)
                problems[key].set_id(ids[run.problem])
                problems[key].attach_logger(logger)
                keep.append(problems[key])
            problem = problems[key]
            logger.set_run_attribute("seed", float(run.seed))
            for i, entry in enumerate(entries):
                f = np.asarray(entry["f"], float).reshape(-1)
                X = np.asarray(entry["X"], float).reshape(len(f), -1)
                tracker.batch = float(entry.get("batch", i))
                tracker.t_end_s = float(entry["t_end_s"])
                problem.values = [float(v) for v in f]
                for x in np.where(np.isfinite(X), X, 0.0):  # ioh skips evaluate() on a non-finite x
                    problem(x)
                if problem.values:
                    raise RuntimeError(f"{run.job_dir}: ioh did not evaluate every logged point")
            problem.reset()  # ends this run
        logger.close()
    del keep
    return sorted(p for p in out.rglob("*") if p.is_file())
