"""``log_metrics``: a log keeps an evaluation's metrics where it improves the job's best so far (and at
the job's first point), and whatever reads the log back sees what a log of every metric gives there."""

from __future__ import annotations

import numpy as np
import pytest

from bench.problems.analytic import AnalyticProblem
from bench.records import EVAL_LOG, read_eval_log
from bench.report.curves import incumbent_index, job_trace
from bench.run.bookkeeping import improving_points
from bench.run.job import ConfigError, log_metrics_of
from bench.run.loop import Budget, run_job
from optimizers.random_search import RandomSearch


@pytest.mark.parametrize("f, best_before, first, kept", [
    ([5.0, 3.0, 4.0, 3.0, 1.0], np.inf, False, [0, 1, 4]),   # a tie keeps the earlier point
    ([5.0, 3.0, 4.0], 4.0, False, [1]),                      # measured against the job's best so far
    ([5.0, 6.0], 1.0, True, [0]),                            # the job's first point: the first incumbent
    ([np.nan, 2.0, np.nan, 1.0], np.inf, False, [1, 3]),     # NaN never improves, nor blocks
    ([np.inf, np.inf], np.inf, True, [0]),                   # a diverged first point is still the first
    ([-np.inf, 3.0, 2.0], np.inf, False, [0, 1, 2]),         # -inf leads the trace, the finite ones the record
    ([], np.inf, True, []),
])
def test_the_improving_points_are_the_strict_improvements_and_the_first(f, best_before, first, kept):
    assert improving_points(f, best_before, first).tolist() == kept


class _SometimesNaN(AnalyticProblem):
    def evaluate(self, X):
        f, metrics = super().evaluate(X)
        f[::3] = np.nan
        return f, metrics


def _run(folder, log_metrics, problem, budget=Budget(evals=150), batch_size=16):
    make = lambda: RandomSearch(problem.space.lower, problem.space.upper, seed=4, batch_size=batch_size)  # noqa: E731
    identity = {"problem": problem.name, "optimizer": "random", "seed": 4, "budget": {"evals": budget.evals}}
    return run_job(problem, make, budget, folder, identity, log_metrics=log_metrics)


def _metrics(folder) -> dict[str, np.ndarray]:
    entries = read_eval_log(folder)
    names = sorted({k for e in entries for k in e["metrics"]})
    return {k: np.concatenate([e["metrics"].get(k, np.full(len(e["f"]), np.nan)) for e in entries]) for k in names}


@pytest.mark.parametrize("problem", [AnalyticProblem("sphere"), _SometimesNaN("rastrigin")], ids=["sphere", "nan"])
def test_a_log_of_improvements_gives_the_same_record_and_trace_in_fewer_bytes(tmp_path, problem):
    every = _run(tmp_path / "all", "all", problem)
    sparse = _run(tmp_path / "improvements", "improvements", problem)
    for key in ("best_f", "best_x", "best_metrics", "n_evals", "n_batches", "stop_reason", "status"):
        assert sparse[key] == every[key], key
    columns = ["batch", "evals", "best_f"] + [c for c in job_trace(tmp_path / "all") if c.startswith("inc.")]
    assert len(columns) > 3  # the trace follows metrics at the incumbents
    assert job_trace(tmp_path / "improvements")[columns].equals(job_trace(tmp_path / "all")[columns])
    full, kept = _metrics(tmp_path / "all"), _metrics(tmp_path / "improvements")
    f = np.concatenate([e["f"] for e in read_eval_log(tmp_path / "all")])
    logged = np.flatnonzero(np.isfinite(kept["distance_to_optimum"]))
    assert set(incumbent_index(f)) <= set(logged) and 0 < len(logged) < len(f) // 4
    for name in full:
        np.testing.assert_array_equal(kept[name][logged], full[name][logged])
    size = {k: (tmp_path / k / EVAL_LOG).stat().st_size for k in ("all", "improvements")}
    assert size["improvements"] < size["all"], size  # one metric here; a VIO evaluation logs 14


def test_a_killed_job_with_a_log_of_improvements_resumes_to_the_identical_record(tmp_path):
    problem = AnalyticProblem("sphere")
    whole = _run(tmp_path / "whole", "improvements", problem)
    _run(tmp_path / "cut", "improvements", problem)
    path = tmp_path / "cut" / EVAL_LOG
    lines = path.read_text().splitlines(keepends=True)
    assert any('"metrics_at"' in line for line in lines[:4])  # the cut keeps lines with kept metrics
    path.write_text("".join(lines[:4]) + lines[4][:30])
    (tmp_path / "cut" / "record.json").unlink()
    resumed = _run(tmp_path / "cut", "improvements", problem)
    for key in ("best_f", "best_x", "best_metrics", "n_evals", "n_batches", "stop_reason", "status"):
        assert resumed[key] == whole[key], key
    assert path.read_bytes().count(b"\n") == len(lines)


def test_an_unknown_log_metrics_setting_is_refused_naming_the_choices():
    assert log_metrics_of({}) == "improvements"
    with pytest.raises(ConfigError, match="log_metrics must be one of improvements, all, got 'some'"):
        log_metrics_of({"log_metrics": "some"})
