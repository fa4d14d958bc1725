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
    numba_lanes = ["numba", "numba lanes 4", "numba lanes 8", "C", "C lanes 4", "C lanes 8"]
    assert [name for p, name in rows if p == "prediction"] == numba_lanes
    assert [name for p, name in rows if p == "gain"] == ["numba", "C", "C lanes 4", "C lanes 8"]
    assert [name for p, name in rows if p == "solve"] == numba_lanes
    assert [name for p, name in rows if p == "innovations"] == ["numba", "C"]
    assert all("bit-identical=True" in line for line in rows.values()), out
    counts = {key: [int(w) for w in re.findall(r"(\d+) (?:scalar|packed)", line)] for key, line in rows.items()}
    assert all(sum(c) > 0 for c in counts.values()), counts  # each variant's code was found in the assembly
    for p in ("prediction", "gain", "solve"):
        assert counts[p, "C lanes 8"][1] > 0, counts  # the lanes are packed
    from llvmlite import binding as llvm

    if llvm.get_host_cpu_features().get("avx", False):  # as bench_layout.py's own test
        assert counts["prediction", "numba lanes 8"][0] == 0, counts


def test_aligned_copies_start_on_a_cache_line_and_keep_the_values(load_script):
    native = load_script("bench_native")
    a = np.arange(24.0).reshape(2, 3, 4)[:, :, ::2]  # not contiguous
    out = native.aligned(a)
    assert out.ctypes.data % 64 == 0 and out.flags.c_contiguous and np.array_equal(out, a)


def test_the_gain_phase_is_taken_from_the_kernels_source_and_a_changed_kernel_is_named(load_script):
    native = load_script("bench_native")
    source = (REPO / "avio/filter/update.py").read_text()
    fn = native.kernel_gain_downdate(source)
    rng = np.random.default_rng(0)
    P, PCt, X, CP = rng.normal(size=(27, 27)), rng.normal(size=(27, 12)), rng.normal(size=(12, 13)), rng.normal(size=(12, 27))
    K = np.zeros((27, 12))
    expected = (P - (PCt @ X[:, :12]) @ CP)[np.tril_indices(27)]
    fn(P, PCt, X, CP, K)
    assert np.allclose(P[np.tril_indices(27)], expected) and np.array_equal(P, P.T)
    with pytest.raises(SystemExit, match="update\\(\\) has 1 loops writing K\\[a, b\\]"):
        native.kernel_gain_downdate(source.replace("acc -= K[a, b] * CP[b, c]", "acc -= CP[b, c]"))


def test_a_missing_compiler_is_one_message_naming_it(load_script, monkeypatch):
    native = load_script("bench_native")
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(SystemExit, match="needs a C compiler: 'no-such-cc' is not on PATH"):
        native.main(["--repeats", "1", "--calls", "1"])
