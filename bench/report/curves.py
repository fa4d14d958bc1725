"""Anytime curves: best-so-far objective against evaluations and wall seconds, over seeds.

The unit of progress is the evaluated batch: an optimiser learns the values of a batch when the
whole batch returns, so a run's best-so-far value changes only at batch ends (``evals`` = the
cumulative evaluation count after the batch, ``seconds`` = its ``t_end_s`` since the job started,
optimiser overhead included). Before its first batch a run has nothing to recommend: in the
median and quartiles over runs it counts as +inf (not drawn), so those statistics never rise as
late-starting runs join; after its last batch (finished, stopped or failed) a run keeps its
final best — the fixed-budget view of IOHprofiler, where a run that stopped early still
recommends its incumbent. A NaN objective is likewise no recommendation (+inf).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bench.errors import BenchError
from bench.records import EVAL_LOG, read_eval_log

AXES = ("evals", "seconds")
TRACE_COLUMNS = ["job_dir", "problem", "optimizer", "seed", "batch", "evals", "seconds", "best_f"]


class CurvesError(BenchError):
    """An evaluation log cannot be turned into a trace; the message names the job folder."""


def incumbent_index(f: np.ndarray) -> np.ndarray:
    """Index of the best-so-far point after each evaluation: (n,) ints into ``f`` (n,).

    The incumbent changes only on a strict improvement, so ties keep the earlier point; NaN
    values never become the incumbent unless nothing finite came before them.
    """
    f = np.asarray(f, float)
    best_before = np.concatenate([[np.inf], np.fmin.accumulate(f)[:-1]])
    best_before[np.isnan(best_before)] = np.inf  # a leading NaN is no incumbent to beat
    improved = f < best_before
    return np.maximum.accumulate(np.where(improved, np.arange(len(f)), 0))


def job_trace(job_dir: Path) -> pd.DataFrame:
    """One row per evaluated batch of one job.

    Columns: ``batch``, ``evals`` (cumulative evaluations at the batch end), ``seconds``
    (``t_end_s``), ``best_f`` (best objective so far) and ``inc.<metric>`` (each logged metric
    at the incumbent, i.e. the point the optimiser would return if stopped there).
    Reads the log lines directly rather than through ``eval_log_frame``: building a frame per
    batch costs seconds on logs of thousands of one-point batches.
    """
    entries = read_eval_log(job_dir)
    if not entries:
        return pd.DataFrame(columns=["batch", "evals", "seconds", "best_f"])
    try:
        sizes = np.array([len(e["f"]) for e in entries])
        f = np.concatenate([np.asarray(e["f"], float).reshape(-1) for e in entries])
        names = sorted({k for e in entries for k in e.get("metrics", {})})
        metrics = {k: np.concatenate([np.asarray(e.get("metrics", {}).get(k, [np.nan] * n), float).reshape(n)
                                      for e, n in zip(entries, sizes)]) for k in names}
        batch = np.array([e["batch"] for e in entries])
        seconds = np.array([e["t_end_s"] for e in entries], float)
    except (KeyError, TypeError, ValueError) as err:
        raise CurvesError(f"{Path(job_dir) / EVAL_LOG}: malformed batch entry ({type(err).__name__}: {err})") from None
    ends = np.cumsum(sizes)
    keep = sizes > 0  # an empty batch adds no evaluation and no value
    inc = incumbent_index(f)[ends[keep] - 1]
    trace = pd.DataFrame({"batch": batch[keep], "evals": ends[keep], "seconds": seconds[keep], "best_f": f[inc]})
    for k in names:
        trace["inc." + k] = metrics[k][inc]
    return trace


def run_traces(runs: pd.DataFrame) -> pd.DataFrame:
    """The batch traces of every run in ``runs`` (one row per job: job_dir, problem, optimizer,
    seed), stacked: ``TRACE_COLUMNS`` plus ``inc.<metric>`` columns. Runs with an empty log add
    no rows (they still count as runs wherever ``runs`` is used)."""
    frames = []
    for job in runs[["job_dir", "problem", "optimizer", "seed"]].itertuples(index=False):
        trace = job_trace(Path(job.job_dir))
        if trace.empty:
            continue
        trace.insert(0, "seed", job.seed)
        trace.insert(0, "optimizer", job.optimizer)
        trace.insert(0, "problem", job.problem)
        trace.insert(0, "job_dir", job.job_dir)
        frames.append(trace)
    if not frames:
        return pd.DataFrame(columns=TRACE_COLUMNS)
    return pd.concat(frames, ignore_index=True)


def _grid(x: np.ndarray, max_points: int) -> np.ndarray:
    """Sorted grid of at most ~``max_points`` values taken from ``x``, log-spaced when x > 0.

    Using the runs' own batch ends keeps the step curves exact; thinning keeps figures small.
    """
    u = np.unique(x[np.isfinite(x)])
    if len(u) <= max_points:
        return u
    spaced = (np.geomspace(u[0], u[-1], max_points) if u[0] > 0
              else np.linspace(u[0], u[-1], max_points))
    idx = np.searchsorted(u, spaced).clip(max=len(u) - 1)
    return u[np.unique(np.append(idx, len(u) - 1))]


def step_values(x_run: np.ndarray, y_run: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Right-continuous step function of one run on ``grid``: y after the last x <= g; NaN before.

    x_run, y_run: (n_batches,) increasing batch ends and best-so-far values; grid: (n_grid,).
    """
    idx = np.searchsorted(x_run, grid, side="right") - 1
    return np.where(idx >= 0, np.asarray(y_run, float)[idx.clip(min=0)], np.nan)


def quantiles_with_inf(values: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Linear-interpolation quantiles over axis 0 of (n_runs, n_grid) values that may hold +inf.

    Returns (len(q), n_grid). Hand-written because numpy's quantile interpolates between two
    infinities as inf - inf = NaN; here anything interpolated towards +inf is +inf.
    """
    v = np.sort(values, axis=0)
    h = (v.shape[0] - 1) * np.asarray(q, float)[:, None]
    lo, hi = np.floor(h).astype(int), np.ceil(h).astype(int)
    cols = np.arange(v.shape[1])[None, :]
    a, b = v[lo, cols], v[hi, cols]
    w = np.broadcast_to(h - lo, a.shape)
    diff = np.subtract(b, a, out=np.zeros_like(a), where=np.isfinite(b))
    return np.where((w == 0) | (a == b), a, np.where(np.isfinite(b), a + w * diff, np.inf))


def anytime_curves(traces: pd.DataFrame, axis: str = "evals", max_points: int = 200) -> pd.DataFrame:
    """Median and inter-quartile band of the best-so-far objective over runs.

    traces: from ``run_traces``. axis: "evals" or "seconds".
    Returns one row per (problem, optimizer, grid point): ``problem, optimizer, axis, x,
    n_runs`` (runs that have reported by x), ``median, q25, q75`` of best_f over all the
    group's runs, a run that has not reported yet counting as +inf (see the module doc).
    """
    if axis not in AXES:
        raise CurvesError(f"axis must be one of {AXES}, got {axis!r}")
    out_cols = ["problem", "optimizer", "axis", "x", "n_runs", "median", "q25", "q75"]
    rows = []
    for (problem, optimizer), group in traces.groupby(["problem", "optimizer"], sort=True):
        grid = _grid(group[axis].to_numpy(float), max_points)
        values = np.vstack([step_values(run[axis].to_numpy(float), run["best_f"].to_numpy(float), grid)
                            for _, run in group.groupby("job_dir", sort=True)])
        n = np.sum(~np.isnan(values), axis=0)
        q25, med, q75 = quantiles_with_inf(np.where(np.isnan(values), np.inf, values), [0.25, 0.5, 0.75])
        rows.append(pd.DataFrame({"problem": problem, "optimizer": optimizer, "axis": axis, "x": grid,
                                  "n_runs": n, "median": med, "q25": q25, "q75": q75}))
    if not rows:
        return pd.DataFrame(columns=out_cols)
    return pd.concat(rows, ignore_index=True)[out_cols]
