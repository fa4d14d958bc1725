"""The records in the IOHprofiler format, for IOHanalyzer: ``report/iohprofiler/``.

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
