"""The two numba switches that let LLVM pack a lock-step kernel into SIMD instructions, and the
count of packed and scalar FP64 instructions in a compiled function (issue 30). They live in
avio/filter/_simd.py, where the filter's kernel is compiled with them (its docstring says how
numba 0.68.1 is made to use them); re-exported here for the benchmarks.

The toy check (tests/benchmarks/test_simd.py): a 4-lane multiply-add with constant bounds
compiles to 4 ``vmulsd`` without the switches, with either alone, and to one packed ``vmulpd``
with both.
"""

from __future__ import annotations

import numba
import numpy as np

from avio.filter._simd import _FP, NoAliasCompiler, PackedCompiler, fp_counts, kernel_jit, slp_vectorize

__all__ = ["NoAliasCompiler", "PackedCompiler", "aligned", "asm_fp_counts", "fp_counts", "kernel_jit", "njit_packed",
           "slp_vectorize"]


def aligned(a: np.ndarray) -> np.ndarray:
    """A C-contiguous copy of ``a`` starting on a 64-byte boundary (a cache line). The benchmarks time
    every variant on aligned arrays: a lane loop's vector loads on arrays as the allocator left them
    changed a variant's speed by up to 2x from one allocation to the next (benchmarks/README.md)."""
    raw = np.empty(a.nbytes + 64, np.uint8)
    start = -raw.ctypes.data % 64
    out = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
    out[...] = a
    return out


def asm_fp_counts(asm: str) -> dict[str, int]:
    """:func:`fp_counts` of assembly text (a C compiler's, benchmarks/native/bench_native.py): scalar and
    packed FP64 arithmetic instructions, counted alike."""
    kinds = [m.group(2) for m in _FP.finditer(asm)]
    return {"scalar": kinds.count("sd"), "packed": kinds.count("pd")}


def njit_packed(func=None, **options):
    """``numba.njit`` with non-aliasing arguments; compile it inside :func:`slp_vectorize` (the
    first call, or ``.compile(signature)``) for the SLP vectoriser to run on it."""
    options.setdefault("pipeline_class", NoAliasCompiler)
    return numba.njit(**options) if func is None else numba.njit(**options)(func)
