"""The filter's kernel functions are compiled with non-aliasing arguments and LLVM's SLP vectoriser
(avio/filter/_simd.py: kernel_jit): compiled afresh, the covariance prediction has more packed and
fewer scalar FP64 instructions than with numba's defaults. If a numba upgrade moves either switch, this fails
rather than the kernel silently turning scalar (its outputs stay the same bits either way:
tests/avio/filter/test_against_history.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from llvmlite import binding as llvm

ROOT = Path(__file__).resolve().parents[3]

_PROBE = """
import json, numba, numpy as np
from avio.filter import kernels
from avio.filter._simd import fp_counts
P, Phi, Qd = np.eye(27), np.eye(15), np.eye(15)
kernels.propagate_covariance(P, Phi, Qd, np.empty((15, 27)), np.empty((15, 15)))  # the kernel's own compile
plain = numba.njit(error_model="numpy")(kernels.propagate_covariance.py_func)  # numba's defaults
plain(P, Phi, Qd, np.empty((15, 27)), np.empty((15, 15)))
print(json.dumps({"kernel": fp_counts(kernels.propagate_covariance), "plain": fp_counts(plain),
                  "slp_after": numba.config.SLP_VECTORIZE}))
"""


@pytest.mark.skipif(not llvm.get_host_cpu_features().get("avx", False),
                    reason="this CPU has no AVX: LLVM would not emit packed FP64 for the kernel")
def test_the_kernels_covariance_prediction_compiles_to_packed_fp64(tmp_path):
    # A fresh numba cache: code loaded from a cache cannot be inspected, and the compile is the test.
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "NUMBA_SLP_VECTORIZE": "0",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    # The switches pack more (numba's defaults vectorise the register sums of _phi_product only in
    # part); without them the two compiles would be the same.
    assert got["kernel"]["packed"] > got["plain"]["packed"] and got["kernel"]["scalar"] < got["plain"]["scalar"], got
    assert got["slp_after"] == 0  # the switch was on for the kernel's compile only
