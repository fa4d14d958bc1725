"""The drives' disk cache (avio/sim/cache.py): a cached drive is the simulated one, its key covers
what a drive depends on, and a bad entry or an unwritable folder costs a simulation, never a wrong drive."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from avio.sim import cache
from avio.sim.simulator import SimConfig, simulate


def _leaves(value, path="") -> dict:
    """Every array and scalar of a (nested) dataclass, by its dotted path."""
    if dataclasses.is_dataclass(value):
        out = {}
        for f in dataclasses.fields(value):
            out.update(_leaves(getattr(value, f.name), f"{path}.{f.name}"))
        return out
    return {path: value}


def _assert_same(a, b) -> None:
    left, right = _leaves(a), _leaves(b)
    assert left.keys() == right.keys()
    for key in left:
        if isinstance(left[key], np.ndarray):
            assert left[key].dtype == right[key].dtype and np.array_equal(left[key], right[key], equal_nan=True), key
        else:
            assert left[key] == right[key], key


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path))
    return tmp_path / "drives"


CONFIG = SimConfig.paper_540m(duration_s=8.0)


def test_a_cached_drive_is_the_simulated_drive_and_is_loaded_not_simulated(folder, monkeypatch):
    first = cache.simulate_cached(CONFIG, (3, 1))
    assert len(list(folder.glob("drive_*.pkl"))) == 1
    _assert_same(first, simulate(CONFIG, (3, 1)))

    def refuse(*args):
        raise AssertionError("simulated although cached")

    monkeypatch.setattr(cache, "_simulate", refuse)
    _assert_same(cache.simulate_cached(CONFIG, (3, 1)), first)


def test_the_key_covers_config_seeds_truth_and_code(monkeypatch):
    truth = simulate(CONFIG, 0).truth_calibration
    moved = dataclasses.replace(truth, fx_px=truth.fx_px + 1e-9)
    keys = {cache.drive_key(CONFIG, 0, None, None), cache.drive_key(CONFIG, 1, None, None),
            cache.drive_key(CONFIG, 0, None, (0, 1)), cache.drive_key(CONFIG, 0, truth, None),
            cache.drive_key(CONFIG, 0, moved, None),
            cache.drive_key(dataclasses.replace(CONFIG, pixel_noise_px=0.71), 0, None, None)}
    assert len(keys) == 6
    before = cache.drive_key(CONFIG, 0, None, None)
    monkeypatch.setattr(cache, "_code_digest", lambda: "an edited simulator")
    assert cache.drive_key(CONFIG, 0, None, None) != before


def test_an_unreadable_entry_is_simulated_again_and_replaced(folder):
    good = cache.simulate_cached(CONFIG, 5)
    (entry,) = folder.glob("drive_*.pkl")
    entry.write_bytes(b"not a pickle")
    _assert_same(cache.simulate_cached(CONFIG, 5), good)
    _assert_same(cache.simulate_cached(CONFIG, 5), good)
    assert entry.stat().st_size > 1000 and not list(folder.glob(".drive_*"))


def test_off_and_an_unwritable_folder_cost_a_simulation_only(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, "off")
    assert cache.cache_folder() is None
    _assert_same(cache.simulate_cached(CONFIG, 2), simulate(CONFIG, 2))
    blocked = tmp_path / "file"
    blocked.write_text("a file where the cache folder would be")
    monkeypatch.setenv(cache.CACHE_ENV, str(blocked))
    _assert_same(cache.simulate_cached(CONFIG, 2), simulate(CONFIG, 2))


def test_a_cached_drive_imports_no_spline(folder):
    """The point of the cache: a job that loads its drives never imports scipy's splines (~0.3 s)."""
    cache.simulate_cached(CONFIG, 9)
    code = ("import sys; from avio.sim.cache import simulate_cached; from avio.sim.simulator import SimConfig; "
            "simulate_cached(SimConfig.paper_540m(duration_s=8.0), 9); "
            "print(sorted(m for m in sys.modules if m.startswith(('scipy.interpolate', 'scipy.integrate'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**__import__("os").environ, cache.CACHE_ENV: str(folder.parent)})
    assert out.stdout.strip() == "[]"


def test_the_code_part_of_the_key_reads_every_avio_module_a_drive_is_built_from():
    """A simulated drive's avio modules (those a fresh simulation imports) are all in the key's sources,
    so an edit to any of them makes a new entry."""
    code = ("import sys; from avio.sim.simulator import SimConfig, simulate; "
            "simulate(SimConfig.paper_540m(duration_s=8.0), 0); "
            "print(' '.join(sorted(m.__file__ for n, m in sys.modules.items() if n.startswith('avio.') "
            "and getattr(m, '__file__', None) and not n.endswith('__init__'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    used = {p for p in out.stdout.split() if not p.endswith("__init__.py")}
    assert used and used <= {str(p) for p in cache._SOURCES}, used - {str(p) for p in cache._SOURCES}
