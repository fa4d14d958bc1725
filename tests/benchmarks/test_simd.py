"""benchmarks/simd.py: numba's non-aliasing arguments and LLVM's SLP vectoriser, switched on as
the module says, pack a 4-lane kernel; without them (or with either alone) it stays scalar. If a
numba upgrade moves either switch, this fails rather than the lock-step kernel silently turning
scalar."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from llvmlite import binding as llvm


def _four_lanes(out, a, b):
    for k in range(4):
        out[k] = out[k] + a[k] * b[k]


@pytest.fixture
def simd(load_script):
    if not llvm.get_host_cpu_features().get("avx", False):
        pytest.skip("this CPU has no AVX: LLVM would not emit packed vmulpd for 4 lanes")
    return load_script("simd")


def _compiled(simd, noalias: bool, slp: bool):
    x = np.arange(4.0)
    kernel = simd.njit_packed(_four_lanes) if noalias else numba.njit(_four_lanes)
    with simd.slp_vectorize(slp):
        out = x.copy()
        kernel(out, x, x + 1)
    assert out.tolist() == (x + x * (x + 1)).tolist()
    return simd.fp_counts(kernel)


def test_a_four_lane_kernel_is_packed_only_with_both_switches(simd):
    assert _compiled(simd, noalias=True, slp=True) == {"scalar": 0, "packed": 2}  # one vmulpd, one vaddpd
    for noalias, slp in ((False, False), (True, False), (False, True)):
        assert _compiled(simd, noalias, slp) == {"scalar": 8, "packed": 0}, (noalias, slp)


def test_the_switch_is_restored_after_the_block(simd):
    before = numba.config.SLP_VECTORIZE
    with pytest.raises(RuntimeError), simd.slp_vectorize(not before):
        assert numba.config.SLP_VECTORIZE == int(not before)
        raise RuntimeError
    assert numba.config.SLP_VECTORIZE == before


def test_fp_counts_reads_scalar_packed_and_fused_forms(load_script):
    class Fake:
        def inspect_asm(self):
            return {"sig": "\tvmulsd\t%xmm1, %xmm0, %xmm0\n\tvfmadd231pd\t%ymm2, %ymm1, %ymm0\n"
                           "\tvmovsd\t(%rax), %xmm0\n\tvaddpd\t%zmm1, %zmm0, %zmm0\n\tsqrtsd\t%xmm0, %xmm0\n"}

    assert load_script("simd").fp_counts(Fake()) == {"scalar": 2, "packed": 2}
