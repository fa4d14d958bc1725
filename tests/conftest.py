"""Fixtures shared by the whole suite, and one summary line for the tests skipped without the real data."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
# Every skip for missing real data says this (``no_data``): the terminal summary folds them into one line.
NO_DATA = "real data absent"


def pytest_configure(config):
    """The suite's simulated drives are cached in a folder of its own (avio/sim/cache.py), so that no test
    reads a drive a user's session (or an older checkout) left, and none is written to the user's cache.
    Set before xdist starts its workers: they and every subprocess share it."""
    if not os.environ.get("AVIO_CACHE_DIR") and not hasattr(config, "workerinput"):
        os.environ["AVIO_CACHE_DIR"] = config._avio_cache = tempfile.mkdtemp(prefix="avio-test-cache-")
    if _warms_kernels(config):
        _warm_kernels(config)


# Under xdist every worker meets the filter kernel in its first tests, so on a fresh checkout each one
# compiled it (~100 s on 2 cores) at the same time, and one of them then compiled the pinned commit's
# kernel (test_against_history.py, ~80 s) alone. Before the workers start, the controller compiles both
# into numba's caches, side by side in two processes; the workers then load them (a few seconds): on 2
# cores the suite went from 551-603 s to 473-541 s (benchmarks/README.md). AVIO_TEST_NO_WARMUP=1 turns it off.
_WARM = {
    "kernel": "from avio.filter import FilterConfig, run\n"
              "seq = make_circle_sequence(8, seed=0)\n"
              "run(seq, seq.truth_calibration, FilterConfig())\n",
    "lock-step kernel": "from avio.filter import FilterConfig, run, set_threads\n"
                        "from test_batch import _candidates\n"
                        "set_threads(1)\n"
                        "seq = make_circle_sequence(8, seed=0)\n"
                        "run(seq, _candidates(seq.truth_calibration, 8, seed=0), FilterConfig())\n",
    "reference kernel": "import git_reference\n"
                        "from test_against_history import REFERENCE_COMMIT, compiled_reference\n"
                        "if git_reference.unavailable(REFERENCE_COMMIT) is None:\n"
                        "    compiled_reference()\n",
}


def _warms_kernels(config) -> bool:
    """Only the xdist controller of a run that includes tests/avio/filter (the whole suite, say)."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return False
    if config.option.collectonly or os.environ.get("AVIO_TEST_NO_WARMUP"):
        return False
    target = REPO_ROOT / "tests" / "avio" / "filter"
    paths = [Path(a.split("::")[0]).resolve() for a in config.args] or [REPO_ROOT / "tests"]
    return any(target == p or p in target.parents for p in paths)


def _warm_kernels(config) -> None:
    """Compile the kernels of ``_WARM`` in parallel processes; a failure is left to the tests to report."""
    t = time.monotonic()
    prelude = (f"import sys; sys.path[:0] = [{str(REPO_ROOT)!r}, {str(REPO_ROOT / 'tests/avio/filter')!r}]\n"
               "from test_filter import make_circle_sequence\n")
    procs = {name: subprocess.Popen([sys.executable, "-c", prelude + code], cwd=REPO_ROOT,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for name, code in _WARM.items()}
    failed = []
    for name, proc in procs.items():
        try:
            proc.wait(timeout=900)
        except subprocess.TimeoutExpired:
            proc.kill()
        if proc.wait() != 0:
            failed.append(name)
    note = f"; {', '.join(failed)} failed (the tests say why)" if failed else ""
    # pytest's own clock starts after this, so the summary says it (pytest_terminal_summary below)
    config._avio_warmup = (f"before the workers started: {' and '.join(_WARM)} compiled or loaded in "
                           f"{time.monotonic() - t:.0f} s (not in the time below){note}")


def pytest_unconfigure(config):
    if getattr(config, "_avio_cache", None):
        shutil.rmtree(config._avio_cache, ignore_errors=True)


def shared_data_dir() -> Path:
    """The real-data folder: $AVIO_DATA, else ../shared/data relative to the repository root."""
    return Path(os.environ.get("AVIO_DATA", REPO_ROOT.parent / "shared" / "data"))


def no_data(detail: str) -> str:
    """The reason of a skip for missing real data: ``NO_DATA``, what is missing, and the way out."""
    return f"{NO_DATA}: {detail} (set AVIO_DATA to use another folder)"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of the real data; skips the test (with the path tried) when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(no_data(f"no folder {path}"))
    return path


@pytest.fixture(scope="session")
def skip_no_data():
    """``skip_no_data(detail)`` skips the test for missing real data, with the reason every such skip gives."""
    def skip(detail: str):
        pytest.skip(no_data(detail))

    return skip


def _skip_reason(report) -> str:
    longrepr = getattr(report, "longrepr", None)
    reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
    return reason.removeprefix("Skipped: ")


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_terminal_summary(terminalreporter):
    """``-rs`` lists each skip; those for missing real data (a few dozen when ../shared/data is absent)
    become one line per missing thing, with their count. Other skips are listed as usual, and the
    final counts are unchanged. First, the warm-up's line (``_warm_kernels``), if it ran."""
    if getattr(terminalreporter.config, "_avio_warmup", None):
        terminalreporter.write_line(terminalreporter.config._avio_warmup)
    skipped = terminalreporter.stats.get("skipped", [])
    no_data_skips = [r for r in skipped if NO_DATA in _skip_reason(r)]
    if not no_data_skips or not terminalreporter.hasopt("s"):
        return (yield)
    terminalreporter.stats["skipped"] = [r for r in skipped if r not in no_data_skips]
    try:
        result = yield  # the short test summary (-ra) is written inside, without them
    finally:
        terminalreporter.stats["skipped"] = skipped
    counts: dict[str, int] = {}
    for report in no_data_skips:
        reason = _skip_reason(report)
        counts[reason] = counts.get(reason, 0) + 1
    for reason, n in counts.items():
        terminalreporter.write_line(f"SKIPPED {n} test{'s' if n != 1 else ''}: {reason}", yellow=True)
    return result


@pytest.fixture
def load_script(request):
    """``load_script("name")``: the script ``name.py`` of the folder this test mirrors
    (tests/benchmarks/… -> benchmarks/name.py, tests/studies/objective/… -> studies/objective/name.py).
    Scripts are files, not a package, so they load by path."""
    folder = REPO_ROOT / Path(request.fspath).parent.relative_to(REPO_ROOT / "tests")

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


def _cpu_quota() -> float | None:
    """Cores the cgroup lets this process use (``cpu.max`` v2, or v1's quota/period); None when unlimited."""
    for quota_file, period_file in (("/sys/fs/cgroup/cpu.max", None),
                                    ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu/cpu.cfs_period_us")):
        try:
            text = Path(quota_file).read_text().split()
            quota, period = text[0], (text[1] if period_file is None else Path(period_file).read_text().strip())
        except (OSError, IndexError):
            continue
        if quota not in ("max", "-1"):
            return int(quota) / int(period)
    return None


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core this process may use. xdist counts the machine's cores, which
    in a container can be far more than its CPU quota; each extra worker compiles the filter kernel
    again and the suite slows down instead of speeding up."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    quota = _cpu_quota()
    return max(1, min(cores, int(quota) if quota else cores))
