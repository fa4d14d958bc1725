"""benchmarks/bench_filter.py: the schedule replay's two-thread makespan; the scaling line."""

from __future__ import annotations

import argparse

import pytest


def test_makespan_gives_each_task_to_the_first_free_thread(load_script):
    makespan = load_script("bench_filter")._makespan
    costs = [4.0, 1.0, 1.0, 1.0, 1.0]
    assert makespan(costs, range(6)) == pytest.approx(4.0)  # one task each: the long one alone on a thread
    assert makespan(costs, [0, 2, 3, 4, 5]) == pytest.approx(5.0)  # the long one shares its range with a short one
    assert makespan(costs, [0, 5], n_threads=2) == pytest.approx(8.0)  # one range: one thread does everything
    assert makespan([2.0, 2.0], range(3), n_threads=1) == pytest.approx(4.0)


def test_scaling_line_times_each_window_and_feature_count(load_script, shared_data, capsys):
    bench = load_script("bench_filter")
    args = argparse.Namespace(data=str(shared_data), repeats=1)
    bench._scaling(args, bench.FilterConfig(), lasts=(40, 50), features=(8,), n=2)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("scaling, batch 2, ms per evaluation: 26 frames ") and "36 frames " in out[0]
    assert out[1].startswith("scaling, batch 2, 36 frames, ms per evaluation: <= 8 features (")
