"""benchmarks/native/bench_native.py measures the C route of issue 30 against the kernel's numba code: its
C variants must do the kernel's work (the same bits), its gain phase must be the kernel's own lines, and
its lock-step lanes must compile packed, or its ratios compare different work."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
needs_cc = pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                              reason="no C compiler (cc or $CC) on this machine: bench_native.py needs one")


@needs_cc
def test_every_c_variant_gives_the_kernels_bits_and_the_lanes_pack(load_script, capsys):
    native = load_script("bench_native")
    native.main(["--repeats", "1", "--calls", "8", "--features", "11"])  # 11: a partial SIMD block of features
    out = capsys.readouterr().out
    rows = {}
    phase = None
    for line in out.splitlines():
        if line.endswith(":") and not line.startswith(" "):
            phase = line[:-1]
        elif "us/filter" in line:
            rows[phase, line.split(" us/filter")[0].rsplit(None, 1)[0].strip()] = line
    with_numba_lanes = ["numba", "numba lanes 4", "numba lanes 8", "C", "C lanes 4", "C lanes 8"]
    c_lanes = ["numba", "C", "C lanes 4", "C lanes 8"]
    for p, names in {"prediction": with_numba_lanes, "project": c_lanes, "information": c_lanes, "gain": c_lanes,
                     "solve": with_numba_lanes, "innovations": ["numba", "C"]}.items():
        assert [name for q, name in rows if q == p] == names, (p, out)
    assert all("bit-identical=True" in line for line in rows.values()), out
    counts = {key: [int(w) for w in re.findall(r"(\d+) (?:scalar|packed)", line)] for key, line in rows.items()}
    assert all(sum(c) > 0 for c in counts.values()), counts  # each variant's code was found in the assembly
    for p in ("prediction", "project", "information", "gain", "solve"):
        assert counts[p, "C lanes 8"][1] > 0, counts  # the lanes are packed
    from llvmlite import binding as llvm

    if llvm.get_host_cpu_features().get("avx", False):  # as bench_layout.py's own test
        assert counts["prediction", "numba lanes 8"][0] == 0, counts


def test_aligned_copies_start_on_a_cache_line_and_keep_the_values(load_script):
    native = load_script("bench_native")
    a = np.arange(24.0).reshape(2, 3, 4)[:, :, ::2]  # not contiguous
    out = native.aligned(a)
    assert out.ctypes.data % 64 == 0 and out.flags.c_contiguous and np.array_equal(out, a)


def test_the_update_phases_are_taken_from_the_kernels_source_and_a_changed_kernel_is_named(load_script):
    """kernel_phase compiles update()'s own statements: the gain and downdate computes P - K C P (lower
    triangle, mirrored), the projection C P C^T, the information sum J^T J over the inliers."""
    native = load_script("bench_native")
    source = (REPO / "avio/filter/update.py").read_text()
    rng = np.random.default_rng(0)
    P, PCt, X, CP = rng.normal(size=(27, 27)), rng.normal(size=(27, 12)), rng.normal(size=(12, 13)), rng.normal(size=(12, 27))
    expected = (P - (PCt @ X[:, :12]) @ CP)[np.tril_indices(27)]
    native.kernel_phase("gain", source)(P, PCt, X, CP, np.zeros((27, 12)))
    assert np.allclose(P[np.tril_indices(27)], expected) and np.array_equal(P, P.T)
    C, S = rng.normal(size=(12, 27)), rng.normal(size=(27, 27))
    out = [np.zeros((12, 27)), np.zeros((27, 12)), np.zeros((12, 12))]
    native.kernel_phase("project", source)(C, S @ S.T, *out)
    assert np.allclose(out[2], C @ S @ S.T @ C.T) and np.array_equal(out[2], out[2].T)
    Jw, rw, inl = rng.normal(size=(3, 12, 9)), rng.normal(size=(3, 9)), np.arange(9) % 3 == 0
    A, beta, Xi = np.zeros((12, 12)), np.zeros(12), np.zeros((12, 13))
    used, rr, _ = native.kernel_phase("information", source)(A, beta, Xi, rw, Jw, np.zeros((3, 12)), inl,
                                                              np.zeros(9), False, np.zeros(9, np.uint8))
    J = Jw[:, :, inl].transpose(2, 0, 1).reshape(-1, 12)
    assert used == 3 and np.isclose(rr, (rw[:, inl] ** 2).sum()) and np.allclose(A, J.T @ J)
    assert np.allclose(Xi[:, 12], J.T @ rw[:, inl].T.reshape(-1))
    with pytest.raises(SystemExit, match="no longer has the phase 'gain'"):
        native.kernel_phase("gain", source.replace("acc -= K[a, b] * CP[b, c]", "acc -= CP[b, c]"))


def test_a_missing_compiler_is_one_message_naming_it(load_script, monkeypatch):
    native = load_script("bench_native")
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(SystemExit, match="needs a C compiler: 'no-such-cc' is not on PATH"):
        native.main(["--repeats", "1", "--calls", "1"])


_CALLER = '''
import ctypes, sys
import numba, numpy as np
lib = ctypes.CDLL(sys.argv[1])
axpy = lib.axpy
axpy.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double, ctypes.c_long]
axpy.restype = None

@numba.njit(cache=True)
def by_argument(fn, y, x):
    fn(y.ctypes.data, x.ctypes.data, 2.0, y.size)

@numba.njit(cache=True)
def by_global(y, x):
    axpy(y.ctypes.data, x.ctypes.data, 2.0, y.size)

y = np.zeros(3)
by_argument(axpy, y, np.ones(3))
by_global(y, np.ones(3))
print(y.tolist())
'''


@needs_cc
def test_numba_caches_a_kernel_given_a_c_function_as_an_argument_not_as_a_global(tmp_path):
    """docs/decisions.md's route for C lanes in the kernel: the compiled frame loop calls C functions passed
    to it; numba (as pinned) caches such a caller and loads it in a new process, but refuses to cache one
    that calls the C function as a global (the kernel must stay cached: its first compile is ~1 min)."""
    import subprocess
    import sys

    (tmp_path / "f.c").write_text("void axpy(double *y, const double *x, double a, long n) "
                                  "{ for (long i = 0; i < n; i++) y[i] += a * x[i]; }\n")
    lib = tmp_path / "libf.so"
    subprocess.run([os.environ.get("CC", "cc"), "-O2", "-shared", "-fPIC", "-o", str(lib), str(tmp_path / "f.c")],
                   check=True)
    (tmp_path / "caller.py").write_text(_CALLER)
    env = {**os.environ, "NUMBA_DEBUG_CACHE": "1", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    runs = [subprocess.run([sys.executable, str(tmp_path / "caller.py"), str(lib)], capture_output=True, text=True,
                           env=env, cwd=tmp_path, check=True) for _ in range(2)]
    assert all(run.stdout.strip().endswith("[4.0, 4.0, 4.0]") for run in runs)
    assert "Cannot cache compiled function \"by_global\"" in runs[0].stderr
    second = runs[1].stdout + runs[1].stderr
    assert re.search(r"data loaded from .*by_argument", second) and not re.search(r"data loaded from .*by_global", second)
