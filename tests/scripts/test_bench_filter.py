"""scripts/bench_filter.py: the schedule replay's two-thread makespan."""

from __future__ import annotations

import pytest


def test_makespan_gives_each_task_to_the_first_free_thread(load_script):
    makespan = load_script("bench_filter")._makespan
    costs = [4.0, 1.0, 1.0, 1.0, 1.0]
    assert makespan(costs, range(6)) == pytest.approx(4.0)  # one task each: the long one alone on a thread
    assert makespan(costs, [0, 2, 3, 4, 5]) == pytest.approx(5.0)  # the long one shares its range with a short one
    assert makespan(costs, [0, 5], n_threads=2) == pytest.approx(8.0)  # one range: one thread does everything
    assert makespan([2.0, 2.0], range(3), n_threads=1) == pytest.approx(4.0)
