"""Does a vectorising layout pay for the filter's dense phases (issue 13)? The covariance
prediction ``P <- F P F^T + Q`` (avio.filter.kernels.propagate_covariance, ~6 % of the kernel and
the simplest of its dense phases) written three ways, timed side by side, bits compared:

- ``committed``: one filter, constant loop bounds (27, 15): LLVM unrolls the rows and its SLP
  vectoriser cannot prove the arrays apart, so the code is scalar (``vmulsd``);
- ``rows``: one filter, bounds read from the shapes: LLVM's loop vectoriser versions every row
  loop on a run-time alias check and runs it in 4-wide AVX2 (``vmulpd``);
- ``lanes L``: L filters in lock-step, the calibration axis innermost (P (27, 27, L)), L a
  compile-time constant, meant to make each multiply-add one L-wide operation across filters
  (the layout issue 13 proposes). Compiled as numba does by default, LLVM unrolls the constant
  lane loops and leaves them scalar: numba tells it nothing about aliasing and its SLP vectoriser
  is off, so this variant alone was not a fair test of the layout (issue 30);
- ``lanes L +noalias+SLP``: the same source with the array arguments declared non-aliasing and
  LLVM's SLP vectoriser on (benchmarks/simd.py: how numba 0.68.1 exposes both), which packs
  the lane loops;
- ``committed +noalias+SLP``: the committed function with the same two switches;
- ``lanes L (run-time)``: the lane count read from the shape, so the loop vectoriser takes the
  lane loops (with a run-time alias check each).

    python benchmarks/bench_layout.py [--lanes 4 8 16] [--repeats 7] [--calls 20000]

Prints CPU microseconds per filter and call (median of --repeats; process CPU time, fairer than
wall time on a shared machine), the median of the per-repeat ratios to ``committed`` (each repeat
times every variant once, in a new random order: paired), whether the result is bit-identical, and
the count of scalar and packed FP64 arithmetic instructions of each compiled version
(benchmarks/simd.py: fp_counts; deterministic, unlike the times). Written out here, not in avio: these are the alternatives measured, not the
kernel.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np
from llvmlite import binding as llvm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from simd import fp_counts, njit_packed, slp_vectorize

from avio.filter.kernels import propagate_covariance

committed = numba.njit(error_model="numpy")(propagate_covariance.py_func)  # uncached: its assembly can be read
committed_packed = njit_packed(propagate_covariance.py_func, error_model="numpy")  # compiled with SLP on


@numba.njit(error_model="numpy")
def rows(Pi, Phi, Qd, T, U):
    """propagate_covariance with the loop bounds read from the shapes (15, 27)."""
    nc, n = Phi.shape[0], Pi.shape[1]
    for a in range(nc):
        for b in range(n):
            T[a, b] = 0.0
        for c in range(nc):
            f = Phi[a, c]
            if f != 0.0:
                for b in range(n):
                    T[a, b] += f * Pi[c, b]
    for a in range(nc):
        for b in range(nc):
            U[a, b] = T[b, a]
    for a in range(nc):
        for b in range(nc):
            Pi[a, b] = Qd[a, b]
        for c in range(nc):
            f = Phi[a, c]
            if f != 0.0:
                for b in range(nc):
                    Pi[a, b] += f * U[c, b]
        for b in range(nc, n):
            Pi[a, b] = T[a, b]
            Pi[b, a] = T[a, b]


@numba.njit(error_model="numpy", inline="always")
def _add_rows(dst, a, Phi, src, ncols, L):
    """dst[a, :ncols] += sum_c Phi[a, c] src[c, :ncols] in every lane (dst, src (rows, cols, L));
    a c is skipped when Phi[a, c] is zero in every lane (adding 0 * finite changes no bit).
    Inlined, so a compiled-in L stays a constant."""
    for c in range(Phi.shape[1]):
        nz = False
        for k in range(L):
            nz |= Phi[a, c, k] != 0.0
        if nz:
            for b in range(ncols):
                for k in range(L):
                    dst[a, b, k] += Phi[a, c, k] * src[c, b, k]


def lanes_kernel(L: int, runtime: bool = False, packed: bool = False):
    """propagate_covariance of L filters in lock-step: P (27, 27, L), Phi (15, 15, L). runtime:
    the lane count read from P's shape instead of compiled in; packed: the arrays declared
    non-aliasing (compile it with SLP on: benchmarks/simd.py)."""

    def lanes(P, Phi, Qd, T, U):
        L = P.shape[2] if runtime else L_fixed
        for a in range(15):
            for b in range(27):
                for k in range(L):
                    T[a, b, k] = 0.0
            _add_rows(T, a, Phi, P, 27, L)
        for a in range(15):
            for b in range(15):
                for k in range(L):
                    U[a, b, k] = T[b, a, k]
        for a in range(15):
            for b in range(15):
                for k in range(L):
                    P[a, b, k] = Qd[a, b]
            _add_rows(P, a, Phi, U, 15, L)
            for b in range(15, 27):
                for k in range(L):
                    P[a, b, k] = T[a, b, k]
                    P[b, a, k] = T[a, b, k]

    L_fixed = L
    return njit_packed(lanes, error_model="numpy") if packed else numba.njit(error_model="numpy")(lanes)


@numba.njit
def _calls(kernel, P, Phi, Qd, T, U, n):
    for _ in range(n):
        kernel(P, Phi, Qd, T, U)


def _counts(kernel) -> str:
    c = fp_counts(kernel)
    return f"{c['scalar']:4d} scalar / {c['packed']:3d} packed FP64"


def _inputs(n: int, seed: int = 0):
    """n filters' covariances (27, 27) and transitions (15, 15) with the prediction's zero pattern."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 27, 27))
    P = np.einsum("nij,nkj->nik", A, A) * 1e-3
    Phi = np.tile(np.eye(15), (n, 1, 1))
    for i in range(3):
        Phi[:, i, 6 + i] = 0.1  # dp <- dv (T on the diagonal: the zero pattern of Eq. 16, which the kernel relies on)
    Phi[:, 6:9, 3:6] = rng.normal(size=(n, 3, 3))  # dv <- dtheta
    Phi[:, 6:9, 9:12] = -0.1  # dv <- db_a
    Phi[:, 3:6, 12:15] = -0.1  # dtheta <- db_g
    return P, Phi, np.eye(15) * 1e-6


def _candidates(args) -> dict:
    """name: (kernel, lanes, compiled with the SIMD switches)."""
    out = {"committed": (committed, 1, False), "rows": (rows, 1, False), "committed +noalias+SLP": (committed_packed, 1, True)}
    out.update({f"lanes {L}": (lanes_kernel(L), L, False) for L in args.lanes})
    out.update({f"lanes {L} +noalias+SLP": (lanes_kernel(L, packed=True), L, True) for L in args.lanes})
    out.update({f"lanes {L} (run-time)": (lanes_kernel(L, runtime=True), L, False) for L in args.runtime_lanes})
    return out


def _prepare(candidates, P, Phi, Qd, reference) -> dict:
    """Compile each variant (with SLP on where asked), check its bits; name: (inputs, same bits)."""
    state = {}
    L_max = P.shape[0]
    for name, (kernel, L, packed) in candidates.items():
        with slp_vectorize(packed):
            if L == 1:
                Ps, T, U = P.copy(), np.empty((15, 27)), np.empty((15, 15))
                for i in range(L_max):
                    kernel(Ps[i], Phi[i], Qd, T, U)
                inputs, same = (P[0].copy(), Phi[0], T, U), np.array_equal(Ps, reference)
            else:
                PL, PhiL = np.ascontiguousarray(P[:L].transpose(1, 2, 0)), np.ascontiguousarray(Phi[:L].transpose(1, 2, 0))
                TL, UL = np.empty((15, 27, L)), np.empty((15, 15, L))
                out = PL.copy()
                kernel(out, PhiL, Qd, TL, UL)
                inputs, same = (PL, PhiL, TL, UL), np.array_equal(out.transpose(2, 0, 1), reference[:L])
            _calls(kernel, inputs[0].copy(), inputs[1], Qd, inputs[2], inputs[3], 1)  # the loop compiled alike
        state[name] = (inputs, same)
    return state


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lanes", type=int, nargs="+", default=[4, 8, 16])
    p.add_argument("--runtime-lanes", type=int, nargs="+", default=[8, 32, 64])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--calls", type=int, default=20000, help="filter-calls per timing")
    args = p.parse_args(argv)
    P, Phi, Qd = _inputs(max(args.lanes + args.runtime_lanes))
    reference = P.copy()
    T, U = np.empty((15, 27)), np.empty((15, 15))
    for i in range(len(P)):
        committed(reference[i], Phi[i], Qd, T, U)
    candidates = _candidates(args)
    state = _prepare(candidates, P, Phi, Qd, reference)
    times = {name: [] for name in candidates}
    rng = np.random.default_rng(0)
    for _ in range(args.repeats):  # paired: every variant once per repeat, in a new order each
        for name in rng.permutation(list(candidates)):
            kernel, L, _ = candidates[name]
            (P0, Phi0, T0, U0), _ = state[name]
            work = P0.copy()
            n = max(1, args.calls // L)
            t = time.process_time()
            _calls(kernel, work, Phi0, Qd, T0, U0, n)
            times[name].append((time.process_time() - t) / (n * L) * 1e6)
    base = np.asarray(times["committed"])
    print(f"covariance prediction, median of {args.repeats} x {args.calls} filter-calls, CPU time "
          f"(numba {numba.__version__}, CPU {llvm.get_host_cpu_name()})")
    for name, (kernel, _, _) in candidates.items():
        us = np.asarray(times[name])
        print(f"  {name:24s} {np.median(us):7.3f} us/filter  {np.median(base / us):5.2f}x  "
              f"bit-identical={state[name][1]}  ({_counts(kernel)})")


if __name__ == "__main__":
    main()
