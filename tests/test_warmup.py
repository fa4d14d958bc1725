"""tests/conftest.py: the xdist controller compiles the filter kernels before its workers start, only for a
run that includes tests/avio/filter, and says how long it took or which compile failed."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import pytest

# By path: in the whole suite the name ``conftest`` may be another folder's conftest.py.
_SPEC = importlib.util.spec_from_file_location("_tests_conftest", Path(__file__).with_name("conftest.py"))
conftest = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(conftest)
TESTS = conftest.REPO_ROOT / "tests"


def _config(*args, n=2, collect_only=False, worker=False):
    config = SimpleNamespace(option=SimpleNamespace(numprocesses=n, collectonly=collect_only), args=list(args))
    if worker:
        config.workerinput = {}
    return config


@pytest.mark.parametrize(("args", "warms"), [
    ((), True),
    ((str(TESTS),), True),
    ((str(TESTS / "avio"),), True),
    ((str(TESTS / "avio" / "filter"),), True),
    ((str(TESTS / "optimizers"), str(TESTS / "avio")), True),
    ((str(TESTS / "optimizers"),), False),
    ((f"{TESTS / 'avio' / 'filter' / 'test_batch.py'}::test_x",), False),
])
def test_only_a_run_that_includes_the_filter_tests_warms(monkeypatch, args, warms):
    monkeypatch.delenv("AVIO_TEST_NO_WARMUP", raising=False)
    assert conftest._warms_kernels(_config(*args)) is warms


def test_no_warmup_on_a_worker_without_xdist_when_collecting_or_when_turned_off(monkeypatch):
    monkeypatch.delenv("AVIO_TEST_NO_WARMUP", raising=False)
    assert not conftest._warms_kernels(_config(worker=True))
    assert not conftest._warms_kernels(_config(n=0))
    assert not conftest._warms_kernels(_config(n=None))
    assert not conftest._warms_kernels(_config(collect_only=True))
    monkeypatch.setenv("AVIO_TEST_NO_WARMUP", "1")
    assert not conftest._warms_kernels(_config())


def test_the_summary_line_names_a_failed_compile(monkeypatch):
    monkeypatch.setattr(conftest, "_WARM", {"good": "x = make_circle_sequence\n", "bad": "raise SystemExit(3)\n"})
    config = _config()
    conftest._warm_kernels(config)
    assert config._avio_warmup.startswith("before the workers started: good and bad compiled or loaded in ")
    assert config._avio_warmup.endswith("; bad failed (the tests say why)")
