"""The two numba switches that let LLVM pack a lock-step kernel into SIMD instructions, and the
count of packed and scalar FP64 instructions in a compiled function (issue 30).

numba 0.68.1 (the pinned version) exposes neither switch as a decorator option:

- **non-aliasing array arguments**: the compiler flag ``Flags.noalias`` (numba/core/compiler.py)
  puts LLVM's ``noalias`` on every pointer argument, the array data pointers included
  (``CPUCallConv.decorate_function``); only parfors' gufunc lowering sets it. Here a compiler
  pipeline (:class:`NoAliasCompiler`, passed as ``numba.njit(pipeline_class=...)``, numba's
  documented extension point) sets it before the passes run. It is a promise: a function
  compiled so must never get two overlapping arrays (LLVM may then reorder their loads and stores).
- **LLVM's SLP vectoriser** (straight-line code: the unrolled loops over a compile-time lane
  count): ``numba.config.SLP_VECTORIZE`` (env ``NUMBA_SLP_VECTORIZE``, default 0 since numba PR
  #8705, a miscompilation in LLVM 11/14), read when a function's module is optimised, i.e. at
  its compile; :func:`slp_vectorize` switches it for the compiles inside a ``with``. numba's
  cache key does not include it: a function compiled with ``cache=True`` and SLP on is loaded as
  is later, and one cached with SLP off stays scalar (so a kernel that relies on it must compile
  with it on in every process, or not use the cache for the switch to matter).

The toy check (tests/benchmarks/test_simd.py): a 4-lane multiply-add with constant bounds
compiles to 4 ``vmulsd`` without the switches, with either alone, and to one packed ``vmulpd``
with both.

Counted (:func:`fp_counts`): FP64 arithmetic instructions of x86 assembly, scalar (``…sd``) and
packed (``…pd``, on xmm/ymm/zmm registers): add, sub, mul, div, sqrt, min, max and the fused
multiply-adds. Moves, compares and conversions are not arithmetic and not counted.
"""

from __future__ import annotations

import re
from contextlib import contextmanager

import numba
from numba.core.compiler import Compiler

_FP = re.compile(r"^\s*v?(add|sub|mul|div|sqrt|min|max|f[n]?m(?:add|sub)(?:132|213|231))(sd|pd)\b", re.MULTILINE)


class NoAliasCompiler(Compiler):
    """numba's default pipeline with ``Flags.noalias`` set: the function's array arguments are
    declared non-aliasing to LLVM (``numba.njit(pipeline_class=NoAliasCompiler)``)."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return super().define_pipelines()


@contextmanager
def slp_vectorize(on: bool = True):
    """LLVM's SLP vectoriser on (or off) for the numba compiles inside the ``with``."""
    old = numba.config.SLP_VECTORIZE
    numba.config.SLP_VECTORIZE = int(on)
    try:
        yield
    finally:
        numba.config.SLP_VECTORIZE = old


def njit_packed(func=None, **options):
    """``numba.njit`` with non-aliasing arguments; compile it inside :func:`slp_vectorize` (the
    first call, or ``.compile(signature)``) for the SLP vectoriser to run on it."""
    options.setdefault("pipeline_class", NoAliasCompiler)
    return numba.njit(**options) if func is None else numba.njit(**options)(func)


def fp_counts(dispatcher) -> dict[str, int]:
    """Scalar and packed FP64 arithmetic instructions in the assembly of every compiled signature
    of ``dispatcher`` (numba's ``inspect_asm``), callees inlined into it included."""
    asm = "".join(dispatcher.inspect_asm().values())
    kinds = [m.group(2) for m in _FP.finditer(asm)]
    return {"scalar": kinds.count("sd"), "packed": kinds.count("pd")}
