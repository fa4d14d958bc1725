"""The filter's threads per job (``threads``): checked before any work, applied in the job, and
left out of the job's identity (results do not depend on it: tests/avio/filter/test_batch.py)."""

from __future__ import annotations

import pytest

from bench.run.job import ConfigError, identity_of, run_configured_job, threads_of


def test_threads_is_auto_or_an_integer_within_the_cores(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 4)
    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    assert threads_of({}) is None and threads_of({"threads": "auto"}) is None
    assert threads_of({"threads": 1}) == 1 and threads_of({"threads": 4}) == 4
    for bad in (0, 5, -1, 1.5, True, "two"):
        with pytest.raises(ConfigError, match=r"threads must be auto or an integer from 1 to 4 \(this machine's cores\)"):
            threads_of({"threads": bad})


@pytest.mark.parametrize("value", ["0", "-2", "abc", "1.5"])
def test_a_bad_numba_num_threads_is_refused_whatever_threads_says(monkeypatch, value):
    monkeypatch.setenv("NUMBA_NUM_THREADS", value)
    for threads in ("auto", 1):
        with pytest.raises(ConfigError, match=rf"NUMBA_NUM_THREADS='{value}' \(environment\): must be an integer >= 1"):
            threads_of({"threads": threads})


def test_an_empty_numba_num_threads_counts_as_unset(monkeypatch):
    monkeypatch.setenv("NUMBA_NUM_THREADS", "")
    assert threads_of({"threads": "auto"}) is None


def test_the_job_runs_the_filter_on_the_threads_asked_and_auto_restores_the_default(tmp_path):
    from avio.filter import batch

    cfg = {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {}},
           "instance": 0, "seed": 0, "budget": {"evals": 4, "seconds": None}, "progress": False, "threads": 1}
    try:
        assert run_configured_job(cfg, tmp_path / "one")["status"] == "ok"
        assert batch.threads() == 1
        assert run_configured_job({**cfg, "threads": "auto"}, tmp_path / "auto")["status"] == "ok"
        assert batch.threads() == batch.default_threads()
    finally:
        batch.set_threads(None)
    assert identity_of(cfg) == identity_of({**cfg, "threads": "auto"})  # the same job either way
