"""The run loop's contract: budgets, stop reasons, records, determinism, resume."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.problems.analytic import AnalyticProblem
from bench.records import read_eval_log, read_record
from bench.run.loop import Budget, RunError, run_job
from optimizers.random_search import RandomSearch


def _identity(seed=0, evals=100):
    return {"problem": "sphere", "optimizer": "random", "seed": seed, "budget": {"evals": evals}}


def _run(tmp_path, budget=Budget(evals=100), seed=0, batch_size=32, problem=None, make=None, name="job"):
    problem = problem or AnalyticProblem("sphere")
    make = make or (lambda: RandomSearch(problem.space.lower, problem.space.upper, seed=seed, batch_size=batch_size))
    return run_job(problem, make, budget, tmp_path / name, _identity(seed, budget.evals))


def test_eval_budget_is_never_exceeded_and_the_last_batch_is_trimmed(tmp_path):
    record = _run(tmp_path, Budget(evals=100), batch_size=32)
    log = read_eval_log(tmp_path / "job")
    assert [e["n"] for e in log] == [32, 32, 32, 4]
    assert record["n_evals"] == 100 and record["n_batches"] == 4
    assert record["stop_reason"] == "budget_evals" and record["status"] == "ok"


def test_same_seed_gives_bit_identical_evaluation_logs(tmp_path):
    _run(tmp_path, seed=3, name="a")
    _run(tmp_path, seed=3, name="b")
    _run(tmp_path, seed=4, name="c")
    f = {n: [e["f"] for e in read_eval_log(tmp_path / n)] for n in "abc"}
    assert f["a"] == f["b"]
    assert f["a"] != f["c"]


def test_best_is_the_minimum_of_the_log_with_its_metrics(tmp_path):
    record = _run(tmp_path)
    f_all = np.concatenate([e["f"] for e in read_eval_log(tmp_path / "job")])
    assert record["best_f"] == f_all.min()
    problem = AnalyticProblem("sphere")
    f, metrics = problem.evaluate(np.array([record["best_x"]]))
    assert f[0] == record["best_f"]
    assert record["best_metrics"]["distance_to_optimum"] == metrics["distance_to_optimum"][0]


def test_seconds_budget_stops_between_batches(tmp_path):
    slow = AnalyticProblem("sphere", delay_s_per_batch=0.05)
    record = _run(tmp_path, Budget(evals=None, seconds=0.2), problem=slow)
    assert record["stop_reason"] == "budget_seconds"
    assert 3 <= record["n_batches"] <= 6
    # evaluate time and wall time are counted separately; the loop's own overhead is small
    assert record["eval_s"] <= record["wall_s"]
    assert record["eval_s"] >= 0.05 * record["n_batches"]


class _StopsAfterTwo(RandomSearch):
    @property
    def stop(self):
        return "converged: two batches told" if getattr(self, "_told", 0) >= 2 else None

    def tell(self, X, f):
        self._told = getattr(self, "_told", 0) + 1
        super().tell(X, f)


def test_optimizer_stop_reason_is_recorded(tmp_path):
    problem = AnalyticProblem("sphere")
    def make():
        return _StopsAfterTwo(problem.space.lower, problem.space.upper, seed=0, batch_size=8)
    record = _run(tmp_path, Budget(evals=1000), problem=problem, make=make)
    assert record["stop_reason"] == "optimizer: converged: two batches told"
    assert record["n_evals"] == 16


class _Raises(RandomSearch):
    def tell(self, X, f):
        raise FloatingPointError("optimiser blew up")


def test_a_raising_optimizer_fails_its_job_with_the_error_recorded(tmp_path):
    problem = AnalyticProblem("sphere")
    def make():
        return _Raises(problem.space.lower, problem.space.upper, seed=0, batch_size=8)
    record = _run(tmp_path, problem=problem, make=make)
    assert record["status"] == "failed" and record["stop_reason"] == "error"
    assert record["error"]["type"] == "FloatingPointError"
    assert "optimiser blew up" in record["error"]["message"]
    assert record["n_evals"] == 8  # the evaluated batch is kept


class _OutOfBounds(RandomSearch):
    def ask(self):
        return super().ask() + 1e3


def test_points_outside_the_bounds_fail_the_job(tmp_path):
    problem = AnalyticProblem("sphere")
    def make():
        return _OutOfBounds(problem.space.lower, problem.space.upper, seed=0)
    record = _run(tmp_path, problem=problem, make=make)
    assert record["status"] == "failed" and "outside" in record["error"]["message"]
    assert record["n_evals"] == 0


def test_finished_job_is_skipped_and_a_different_job_is_refused(tmp_path):
    first = _run(tmp_path)
    again = _run(tmp_path)
    assert again["ended_utc"] == first["ended_utc"]  # not re-run
    problem = AnalyticProblem("sphere")
    with pytest.raises(RunError, match="different job"):
        run_job(problem, lambda: None, Budget(evals=100), tmp_path / "job", _identity(seed=9))


def test_resume_from_a_partial_log_reproduces_the_uninterrupted_run(tmp_path):
    full = _run(tmp_path, Budget(evals=200), name="full")
    _run(tmp_path, Budget(evals=200), name="cut")
    # imitate a kill after 3 batches, mid-way through writing the 4th line
    path = tmp_path / "cut" / "evals.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:3]) + lines[3][:20])
    (tmp_path / "cut" / "record.json").unlink()
    resumed = _run(tmp_path, Budget(evals=200), name="cut")
    for key in ("best_f", "best_x", "n_evals", "n_batches", "stop_reason", "status"):
        assert resumed[key] == full[key]
    assert [e["f"] for e in read_eval_log(tmp_path / "cut")] == [e["f"] for e in read_eval_log(tmp_path / "full")]


def test_record_is_plain_json_with_provenance(tmp_path):
    _run(tmp_path)
    record = json.loads((tmp_path / "job" / "record.json").read_text())
    for key in ("git_commit", "versions", "machine", "space", "budget", "wall_s", "eval_s", "job_key"):
        assert key in record
    assert record["versions"]["numpy"] == np.__version__
    assert read_record(tmp_path / "missing") is None


class _SometimesNaN(AnalyticProblem):
    def evaluate(self, X):
        f, metrics = super().evaluate(X)
        f[::3] = np.nan
        return f, metrics


def test_non_finite_values_round_trip_through_the_log_and_never_become_best(tmp_path):
    record = _run(tmp_path, Budget(evals=64), problem=_SometimesNaN("sphere"))
    batches = [np.asarray(e["f"], float) for e in read_eval_log(tmp_path / "job")]
    assert all(np.isnan(f[::3]).all() and np.isfinite(f[1::3]).all() for f in batches)
    assert record["best_f"] == np.nanmin(np.concatenate(batches))
