"""How the filter's kernel is compiled: numba with non-aliasing array arguments and LLVM's SLP
vectoriser on (issue 30), and the count of packed and scalar FP64 instructions that checks it.

numba 0.68.1 (the pinned version) exposes neither switch as a decorator option:

- **non-aliasing array arguments**: the compiler flag ``Flags.noalias`` (numba/core/compiler.py)
  puts LLVM's ``noalias`` on every pointer argument, the array data pointers included
  (``CPUCallConv.decorate_function``); only parfors' gufunc lowering sets it. The compiler
  pipeline :class:`PackedCompiler` (``numba.njit(pipeline_class=...)``, numba's documented
  extension point) sets it before the passes run. It is a promise: a function compiled so must
  never get two overlapping arrays of which one is written (no kernel function does: every call
  passes distinct arrays or disjoint views).
- **LLVM's SLP vectoriser** (straight-line code: the unrolled loops over a compile-time lane
  count): ``numba.config.SLP_VECTORIZE`` (env ``NUMBA_SLP_VECTORIZE``, default 0 since numba PR
  #8705, a miscompilation in LLVM 11/14), read when a function's LLVM module is optimised, which
  is inside the compile. :class:`PackedCompiler` switches it on around its own compile only
  (``_compile_core``), so whoever triggers the compile (the filter, a test calling one kernel
  function, a benchmark) gets the same code, and numba's cache (whose key does not include the
  switch) only ever holds the switched code; other numba code in the process is untouched.

tests/avio/filter/test_simd.py compiles kernel functions afresh and checks that they are packed
(:func:`fp_counts`); a numba upgrade that moves either switch fails there rather than the kernel
silently turning scalar. The filter's outputs are the same bits with or without the switches
(no fastmath: LLVM may only pack what it can compute in the same order).
"""

from __future__ import annotations

import re
from contextlib import contextmanager

import numba
from numba.core.compiler import Compiler

_FP = re.compile(r"^\s*v?(add|sub|mul|div|sqrt|min|max|f[n]?m(?:add|sub)(?:132|213|231))(sd|pd)\b", re.MULTILINE)


@contextmanager
def slp_vectorize(on: bool = True):
    """LLVM's SLP vectoriser on (or off) for the numba compiles inside the ``with``."""
    old = numba.config.SLP_VECTORIZE
    numba.config.SLP_VECTORIZE = int(on)
    try:
        yield
    finally:
        numba.config.SLP_VECTORIZE = old


class NoAliasCompiler(Compiler):
    """numba's default pipeline with ``Flags.noalias`` set: the function's array arguments are
    declared non-aliasing to LLVM (``numba.njit(pipeline_class=NoAliasCompiler)``)."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return super().define_pipelines()


class PackedCompiler(NoAliasCompiler):
    """:class:`NoAliasCompiler` with LLVM's SLP vectoriser on for this compile (and only it)."""

    def _compile_core(self):
        with slp_vectorize(True):
            return super()._compile_core()


def kernel_jit(func=None, *, allocates: bool = False, **options):
    """``numba.njit`` of the filter's kernel functions: ``cache=True``, ``error_model="numpy"``
    (a division by zero gives inf/NaN; such features are dropped), no fastmath (the same bits on
    every run) and :class:`PackedCompiler` (non-aliasing arguments, SLP on).

    Without numba's reference counting (NRT, ``_nrt=False``) unless ``allocates``: a function that
    only computes on arrays its caller owns needs none, and each view or array bound to a name
    cost an atomic increment and decrement (issue 30: ~8 % of the kernel's time went to them,
    ``perf``). A function that allocates (np.empty, a workspace) must say ``allocates=True``; without
    it numba refuses to compile the allocation, so a forgotten flag is a compile error, not a leak.

    ``inline="always"`` (numba's IR inlining) for a function called per filter and frame with the
    kernel's structures: numba passes a NamedTuple of arrays as its flattened fields (~10 words an
    array), so a call with the update's workspaces stored ~700 words on the stack each time; perf
    put 13 % of the lock-step kernel's time in those stores. Inlining the update's stages, the
    block's update and its small per-lane helpers made the kernel 1.36x faster at batch 64, same
    bits (benchmarks/README.md, 2026-12-07)."""
    options = {"cache": True, "error_model": "numpy", "pipeline_class": PackedCompiler, "_nrt": allocates, **options}
    return numba.njit(**options) if func is None else numba.njit(**options)(func)


def fp_counts(dispatcher) -> dict[str, int]:
    """Scalar and packed FP64 arithmetic instructions in the assembly of every compiled signature
    of ``dispatcher`` (numba's ``inspect_asm``; not available for code loaded from numba's cache),
    callees inlined into it included. Counted: add, sub, mul, div, sqrt, min, max and the fused
    multiply-adds, scalar (``…sd``) or packed (``…pd``); moves, compares and conversions are not."""
    asm = "".join(dispatcher.inspect_asm().values())
    kinds = [m.group(2) for m in _FP.finditer(asm)]
    return {"scalar": kinds.count("sd"), "packed": kinds.count("pd")}
