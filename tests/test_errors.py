"""One error base per package (``avio.errors.AvioError``, ``bench.errors.BenchError``,
``optimizers.OptimizerError``), and edges that catch those bases, never ``ValueError``: a
project error is one clear message, a bug keeps its traceback."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

from bench.problems import analytic
from bench.problems.base import ProblemError, _problem_cached
from bench.run.preflight import preflight_plan
from optimizers.random_search import RandomSearch

PACKAGES = ("avio", "bench", "optimizers")
# exceptions that are not errors of their package: control flow that never leaves its module
NOT_PROJECT_ERRORS = {"optimizers.scipy_local._Abort"}  # stops scipy's minimiser from inside its callback


def _bases() -> dict[str, type[Exception]]:
    from avio.errors import AvioError
    from bench.errors import BenchError
    from optimizers import OptimizerError

    return {"avio": AvioError, "bench": BenchError, "optimizers": OptimizerError}


def _exception_classes() -> list[tuple[str, type[BaseException]]]:
    """Every exception class defined in a module of the three packages (every module imported)."""
    found = []
    for package in PACKAGES:
        root = importlib.import_module(package)
        modules = [root] + [importlib.import_module(info.name)
                            for info in pkgutil.walk_packages(root.__path__, package + ".")]
        for module in modules:
            for name, obj in vars(module).items():
                if inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == module.__name__:
                    found.append((f"{module.__name__}.{name}", obj))
    return found


def test_every_exception_class_derives_from_its_packages_base():
    bases = _bases()
    classes = [(name, cls) for name, cls in _exception_classes() if name not in NOT_PROJECT_ERRORS]
    assert len(classes) >= 35  # the walk found the packages' errors (34 today, and the three bases)
    wrong = sorted(f"{name} ({', '.join(b.__name__ for b in cls.__mro__[1:])})" for name, cls in classes
                   if not issubclass(cls, bases[name.split(".")[0]]))
    assert wrong == []
    # and each base is its package's own: no error of one package passes for another's
    for package, base in bases.items():
        assert {p for p, other in bases.items() if issubclass(base, other)} == {package}


@pytest.mark.parametrize("package", PACKAGES)
def test_the_bases_are_not_value_errors(package):
    """The edges catch the base; were it a ValueError, an ``except ValueError`` anywhere would
    still pass a library's or a bug's ValueError for bad input, and the other way round."""
    base = _bases()[package]
    assert base.__bases__ == (Exception,)
    assert not issubclass(base, (ValueError, RuntimeError))


def test_the_allowed_non_errors_still_exist():
    names = {name for name, _ in _exception_classes()}
    assert NOT_PROJECT_ERRORS <= names  # an entry for a class that is gone would hide nothing, silently


# --- the edge: `python -m bench` validates every job first (bench/run/preflight.py) ------------------

@pytest.fixture
def fresh_problems():
    """build_problem caches problems per process: a patched problem must not leak into other tests."""
    _problem_cached.cache_clear()
    yield
    _problem_cached.cache_clear()


def _preflight(tmp_path, capsys) -> tuple[int, str]:
    code, _ = preflight_plan(["problem=sphere", "optimizer=random", "seed=0", "budget.evals=8",
                              f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    out = capsys.readouterr()
    return code, out.out + out.err


def _buggy(*args, **kwargs):
    raise ValueError("a deliberate bug, not bad input")


def test_a_bug_in_an_optimisers_ask_keeps_its_traceback(tmp_path, capsys, monkeypatch, fresh_problems):
    # before the bases, preflight turned it into "error: optimizer=random ... its first ask() fails", exit 2
    monkeypatch.setattr(RandomSearch, "_ask", _buggy)
    with pytest.raises(ValueError, match="a deliberate bug"):
        _preflight(tmp_path, capsys)
    assert not (tmp_path / "sweep").exists()


def test_a_bug_in_a_problems_evaluate_keeps_its_traceback(tmp_path, capsys, monkeypatch, fresh_problems):
    # the analytic problem evaluates its reference while it is built, which preflight does once
    monkeypatch.setitem(analytic._FUNCTIONS, "sphere", (_buggy, 10.0))
    with pytest.raises(ValueError, match="a deliberate bug"):
        _preflight(tmp_path, capsys)
    assert not (tmp_path / "sweep").exists()


def test_bad_input_from_an_optimiser_or_a_problem_is_still_one_message(tmp_path, capsys, monkeypatch,
                                                                       fresh_problems):
    from optimizers import OptimizerError

    def refuses(self):
        raise OptimizerError("random: this space is too small")

    monkeypatch.setattr(RandomSearch, "_ask", refuses)
    code, out = _preflight(tmp_path, capsys)
    assert code == 2 and "its first ask() fails: OptimizerError: random: this space is too small" in out
    monkeypatch.undo()

    def bad_data(z):
        raise ProblemError("sphere: a data file is corrupt")

    monkeypatch.setitem(analytic._FUNCTIONS, "sphere", (bad_data, 10.0))
    code, out = _preflight(tmp_path, capsys)
    assert code == 2 and "error: problem=sphere: sphere: a data file is corrupt" in out and "Traceback" not in out
    assert not (tmp_path / "sweep").exists()


# --- the report's edges: python -m bench.report, bench.export, bench.report.paper ------------------------

def _raiser(exc: BaseException):
    def run(*args, **kwargs):
        raise exc
    return run


@pytest.mark.parametrize("entry, target", [("bench.report.__main__", "build_report"),
                                           ("bench.report.export", "export"),
                                           ("bench.report.paper.tables", "build_tables")])
def test_report_entries_say_project_errors_and_let_bugs_through(entry, target, tmp_path, monkeypatch, capsys):
    from avio.metrics import MetricsError
    from bench.report.stats import StatsError

    module = importlib.import_module(entry)
    argv = {"bench.report.export": [str(tmp_path), "--format", "tum"],
            "bench.report.paper.tables": [str(tmp_path), "--out", str(tmp_path / "t")]}.get(entry, [str(tmp_path)])
    for error in (StatsError("alpha must be in (0, 1)"), MetricsError("no common frames")):
        monkeypatch.setattr(module, target, _raiser(error))
        assert module.main(argv) == 2
        assert f"error: {error}" in capsys.readouterr().err
    monkeypatch.setattr(module, target, _raiser(ValueError("a deliberate bug, not bad input")))
    with pytest.raises(ValueError, match="a deliberate bug"):
        module.main(argv)


def test_export_says_a_diverged_filter_with_exit_1_and_lets_other_runtime_errors_through(tmp_path, monkeypatch,
                                                                                         capsys):
    from bench.report import export

    argv = [str(tmp_path), "--format", "tum"]
    monkeypatch.setattr(export, "export", _raiser(export.ExportDivergedError("the filter diverged at frame 7")))
    assert export.main(argv) == 1 and "the filter diverged at frame 7" in capsys.readouterr().err
    monkeypatch.setattr(export, "export", _raiser(RecursionError("a deliberate bug")))  # a RuntimeError
    with pytest.raises(RecursionError):
        export.main(argv)
