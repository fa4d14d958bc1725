"""Fixed targets, ERT and ECDF against COCO's definitions worked by hand; traces and anytime curves."""

import numpy as np
import pandas as pd
import pytest
from record_factory import write_job

from bench.records import eval_log_frame, load_records
from bench.report.curves import anytime_curves, incumbent_index, job_trace, quantiles_with_inf, run_traces, step_values
from bench.report.leaderboard import runs_table
from bench.report.targets import TargetsError, ecdf, ert, ert_table, hitting_times, objective_targets, problem_targets


def load(root):
    runs = runs_table(load_records([root]))
    traces = run_traces(runs)
    targets = problem_targets(runs, traces)
    return runs, traces, targets, hitting_times(runs, traces, targets)


def test_ert_hand_case():
    # two successes after 10 and 30 evaluations, one failure that spent 100: (10 + 30 + 100) / 2
    assert ert([True, True, False], [10, 30, np.nan], [50, 60, 100]) == 70.0
    assert ert([False, False], [np.nan, np.nan], [5, 5]) == np.inf
    assert np.isnan(ert([], [], []))


def test_objective_targets_follow_the_documented_fallbacks():
    rel = objective_targets(f_truth=2.0, f_reference=9.0, f_best=1.0)
    assert [t.threshold for t in rel] == pytest.approx([2.02, 2.1, 2.2])
    assert [t.main for t in rel] == [False, True, False]
    gap = objective_targets(f_truth=0.0, f_reference=10.0, f_best=0.3)
    assert [t.threshold for t in gap] == pytest.approx([0.1, 0.5, 1.0])
    best = objective_targets(f_truth=np.nan, f_reference=np.nan, f_best=4.0)
    assert [t.name for t in best][0] == "f_best+1%" and best[0].threshold == pytest.approx(4.04)
    absolute = objective_targets(f_truth=np.nan, f_reference=np.nan, f_best=0.0)
    assert [t.threshold for t in absolute] == pytest.approx([0.01, 0.05, 0.1])
    assert objective_targets(np.nan, np.nan, np.nan) == []


def test_hit_is_charged_at_the_end_of_its_batch(tmp_path):
    # f_truth = 1: targets 1.01, 1.05, 1.1. Batch 2 holds the hit of 1.05 as its 2nd point.
    write_job(tmp_path, "p", "o", 0, [[5, 4], [1.04, 3], [0.5]], t_batches=[1.0, 2.5, 4.0], f_truth=1.0)
    _, _, targets, hits = load(tmp_path)
    got = hits.set_index("target")
    assert got.loc["f_truth+5%", "evals"] == 4 and got.loc["f_truth+5%", "seconds"] == 2.5
    assert got.loc["f_truth+1%", "evals"] == 5 and got.loc["f_truth+1%", "seconds"] == 4.0
    assert got["hit"].all() and (got["spent_evals"] == 5).all()


def test_ert_table_and_ecdf_on_a_hand_computed_case(tmp_path):
    # f_truth = 1, targets t1 (<= 1.01), t5 (<= 1.05), t10 (<= 1.1); one evaluation per batch.
    write_job(tmp_path, "p", "o", 0, [[2], [1.08], [1.0]], t_batches=[1, 2, 3], f_truth=1.0)
    write_job(tmp_path, "p", "o", 1, [[3], [2], [1.5], [1.04]], t_batches=[1, 2, 3, 4], f_truth=1.0)
    write_job(tmp_path, "p", "o", 2, [[9], [8]], t_batches=[1, 2], f_truth=1.0, status="failed")
    _, _, targets, hits = load(tmp_path)
    table = ert_table(hits, targets).set_index("target")
    # runtimes: run0 (t1: 3, t5: 3, t10: 2), run1 (t1: miss/4, t5: 4, t10: 4), run2 misses all (spent 2)
    assert table.loc["f_truth+1%", "ert_evals"] == pytest.approx((3 + 4 + 2) / 1)
    assert table.loc["f_truth+5%", "ert_evals"] == pytest.approx((3 + 4 + 2) / 2)
    assert table.loc["f_truth+10%", "ert_evals"] == pytest.approx((2 + 4 + 2) / 2)
    assert (table["n_runs"] == 3).all() and list(table["n_hit"]) == [1, 2, 2]
    curve = ecdf(hits, "evals")
    # 9 (run, target) pairs; hits by budget 2: 1, by 3: 3, by 4: 5
    assert list(curve["budget"]) == [2, 3, 4] and curve["fraction"].tolist() == pytest.approx([1 / 9, 3 / 9, 5 / 9])
    with pytest.raises(TargetsError):
        ecdf(hits, "minutes")


def test_metric_targets_use_the_incumbent_not_the_best_metric_seen(tmp_path):
    # The point with rotation error 0.05 is not the incumbent (f = 2 > 1), so "< 0.1" is never hit.
    write_job(tmp_path, "p", "o", 0, [[2, 1]],
              metrics_batches=[{"rotation_error_deg": [0.05, 0.4], "focal_error_px": [0.1, 0.5]}], f_truth=1.0)
    _, _, targets, hits = load(tmp_path)
    names = [t.name for t in targets["p"]]
    assert names[3:] == ["rotation_error_deg<0.5", "rotation_error_deg<0.1", "focal_error_px<1"]
    got = hits.set_index("target")["hit"]
    assert got["rotation_error_deg<0.5"] and not got["rotation_error_deg<0.1"] and got["focal_error_px<1"]


def test_incumbent_index_keeps_the_first_of_equal_values_and_skips_nan():
    assert incumbent_index(np.array([3.0, 1.0, 1.0, 2.0, 0.5])).tolist() == [0, 1, 1, 1, 4]
    assert incumbent_index(np.array([np.nan, 2.0, np.nan, 1.0])).tolist() == [0, 1, 1, 3]


def test_step_values_are_nan_before_the_first_batch_and_hold_after_the_last():
    got = step_values(np.array([2.0, 4.0]), np.array([5.0, 3.0]), np.array([1, 2, 3, 4, 9]))
    np.testing.assert_array_equal(got, [np.nan, 5, 5, 3, 3])


def test_anytime_median_and_quartiles_over_runs(tmp_path):
    # best-so-far after each batch (one eval per batch): run0 4,2,1; run1 6,6,3; run2 8,5 (stops)
    for seed, fs in enumerate([[4, 2, 1], [6, 7, 3], [8, 5]]):
        write_job(tmp_path, "p", "o", seed, [[v] for v in fs])
    runs = runs_table(load_records([tmp_path]))
    curves = anytime_curves(run_traces(runs), "evals")
    assert curves["x"].tolist() == [1, 2, 3]
    assert curves["median"].tolist() == [6, 5, 3]
    assert curves["q25"].tolist() == [5, 3.5, 2] and curves["q75"].tolist() == [7, 5.5, 4]
    assert (curves["n_runs"] == 3).all()
    seconds = anytime_curves(run_traces(runs), "seconds")
    assert seconds["median"].tolist() == [6, 5, 3]


def test_anytime_grid_is_thinned_but_keeps_the_last_point(tmp_path):
    write_job(tmp_path, "p", "o", 0, [[1000 - i] for i in range(500)])
    runs = runs_table(load_records([tmp_path]))
    curves = anytime_curves(run_traces(runs), "evals", max_points=50)
    assert len(curves) <= 51 and curves["x"].iloc[-1] == 500 and curves["median"].iloc[-1] == 501
    assert pd.Series(curves["median"]).is_monotonic_decreasing


def test_trace_agrees_with_the_eval_log_frame_at_batch_ends(tmp_path):
    rng = np.random.default_rng(2)
    batches = [list(rng.uniform(0, 10, n)) for n in (3, 1, 4, 2)]
    metrics = [{"focal_error_px": list(rng.uniform(0, 5, len(b)))} for b in batches]
    job = write_job(tmp_path, "p", "o", 0, batches, metrics_batches=metrics)
    trace = job_trace(job)
    frame = eval_log_frame(job)
    ends = frame.groupby("batch")["eval"].max().to_numpy()
    assert trace["evals"].tolist() == ends.tolist() == [3, 4, 8, 10]
    np.testing.assert_array_equal(trace["best_f"], frame.set_index("eval").loc[ends, "best_f"])
    inc = [int(np.argmin(frame["f"].to_numpy()[:e])) for e in ends]
    np.testing.assert_array_equal(trace["inc.focal_error_px"], frame["m.focal_error_px"].to_numpy()[inc])


def test_quantiles_with_inf_match_numpy_on_finite_values():
    values = np.random.default_rng(4).normal(size=(7, 5))
    q = np.array([0.25, 0.5, 0.75])
    np.testing.assert_allclose(quantiles_with_inf(values, q), np.quantile(values, q, axis=0))


def test_runs_that_have_not_reported_count_as_infinite_so_the_median_never_rises(tmp_path):
    # seconds axis: run0 reports 5 at t=1 and 2 at t=3, run1 reports 4 at t=2, run2 reports 1 at t=4
    write_job(tmp_path, "p", "o", 0, [[5], [2]], t_batches=[1, 3])
    write_job(tmp_path, "p", "o", 1, [[4]], t_batches=[2])
    write_job(tmp_path, "p", "o", 2, [[1]], t_batches=[4])
    runs = runs_table(load_records([tmp_path]))
    curves = anytime_curves(run_traces(runs), "seconds")
    assert curves["x"].tolist() == [1, 2, 3, 4] and curves["n_runs"].tolist() == [1, 2, 2, 3]
    assert curves["median"].tolist() == [np.inf, 5, 4, 2]
    assert curves["q25"].tolist() == [np.inf, 4.5, 3, 1.5] and curves["q75"].tolist() == [np.inf, np.inf, np.inf, 3]
