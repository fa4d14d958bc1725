"""Does a vectorising layout pay for the filter's dense phases (issue 13)? The covariance
prediction ``P <- F P F^T + Q`` (avio.filter.kernels.propagate_covariance, ~6 % of the kernel and
the simplest of its dense phases) written three ways, timed side by side, bits compared:

- ``committed``: one filter, constant loop bounds (27, 15): LLVM unrolls the rows and its SLP
  vectoriser cannot prove the arrays apart, so the code is scalar (``vmulsd``);
- ``rows``: one filter, bounds read from the shapes: LLVM's loop vectoriser versions every row
  loop on a run-time alias check and runs it in 4-wide AVX2 (``vmulpd``);
- ``lanes L``: L filters in lock-step, the calibration axis innermost (P (27, 27, L)), L a
  compile-time constant, meant to make each multiply-add one L-wide operation across filters
  (the layout issue 13 proposes). LLVM, as numba 0.68 drives it, unrolls the constant lane loops
  and leaves them scalar: its SLP vectoriser is off by default, and with NUMBA_SLP_VECTORIZE=1,
  unsigned indices or a freshly allocated output it still does not pack them (measured);
- ``lanes L (run-time)``: the same with the lane count read from the shape, so the loop
  vectoriser takes the lane loops (with a run-time alias check each).

    python benchmarks/bench_layout.py [--lanes 4 8 16] [--repeats 7] [--calls 20000]

Prints microseconds per filter and call (median of --repeats), the ratio to ``committed`` and
whether the result is bit-identical, plus the count of scalar and packed multiplies in each
compiled version. Written out here, not in avio: these are the alternatives measured, not the
kernel.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numba
import numpy as np
from llvmlite import binding as llvm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from avio.filter.kernels import propagate_covariance

committed = numba.njit(error_model="numpy")(propagate_covariance.py_func)  # uncached: its assembly can be read


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


def lanes_kernel(L: int, runtime: bool = False):
    """propagate_covariance of L filters in lock-step: P (27, 27, L), Phi (15, 15, L). runtime:
    the lane count read from P's shape instead of compiled in."""

    @numba.njit(error_model="numpy")
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
    return lanes


@numba.njit
def _calls(kernel, P, Phi, Qd, T, U, n):
    for _ in range(n):
        kernel(P, Phi, Qd, T, U)


def _multiplies(kernel) -> str:
    asm = "".join(kernel.inspect_asm().values())
    return f"{len(re.findall('vmulsd', asm))} scalar / {len(re.findall('vmulpd', asm))} packed multiplies"


def _inputs(n: int, seed: int = 0):
    """n filters' covariances (27, 27) and transitions (15, 15) with the prediction's zero pattern."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 27, 27))
    P = np.einsum("nij,nkj->nik", A, A) * 1e-3
    Phi = np.tile(np.eye(15), (n, 1, 1))
    Phi[:, 0:3, 6:9] = 0.1  # dp <- dv
    Phi[:, 6:9, 3:6] = rng.normal(size=(n, 3, 3))  # dv <- dtheta
    Phi[:, 6:9, 9:12] = -0.1  # dv <- db_a
    Phi[:, 3:6, 12:15] = -0.1  # dtheta <- db_g
    return P, Phi, np.eye(15) * 1e-6


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lanes", type=int, nargs="+", default=[4, 8, 16])
    p.add_argument("--runtime-lanes", type=int, nargs="+", default=[8, 32, 64])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--calls", type=int, default=20000, help="filter-calls per timing")
    args = p.parse_args(argv)
    L_max = max(args.lanes + args.runtime_lanes)
    P, Phi, Qd = _inputs(L_max)
    T, U = np.empty((15, 27)), np.empty((15, 15))
    reference = P.copy()
    for i in range(L_max):
        committed(reference[i], Phi[i], Qd, T, U)
    candidates = {"committed": (committed, 1), "rows": (rows, 1)}
    candidates.update({f"lanes {L}": (lanes_kernel(L), L) for L in args.lanes})
    candidates.update({f"lanes {L} (run-time)": (lanes_kernel(L, runtime=True), L) for L in args.runtime_lanes})
    times = {name: [] for name in candidates}
    state = {}
    for name, (kernel, L) in candidates.items():  # compile, check the bits, keep the inputs
        if L == 1:
            Ps = P.copy()
            for i in range(L_max):
                kernel(Ps[i], Phi[i], Qd, T, U)
            state[name] = (P[0].copy(), Phi[0], T, U, np.array_equal(Ps, reference))
        else:
            PL, PhiL = np.ascontiguousarray(P[:L].transpose(1, 2, 0)), np.ascontiguousarray(Phi[:L].transpose(1, 2, 0))
            TL, UL = np.empty((15, 27, L)), np.empty((15, 15, L))
            out = PL.copy()
            kernel(out, PhiL, Qd, TL, UL)
            state[name] = (PL, PhiL, TL, UL, np.array_equal(out.transpose(2, 0, 1), reference[:L]))
    for _ in range(args.repeats):  # interleaved, so a drift of the machine's speed hits all alike
        for name, (kernel, L) in candidates.items():
            P0, Phi0, T0, U0, _ = state[name]
            work = P0.copy()
            n = max(1, args.calls // L)
            t = time.perf_counter()
            _calls(kernel, work, Phi0, Qd, T0, U0, n)
            times[name].append((time.perf_counter() - t) / (n * L) * 1e6)
    base = np.median(times["committed"])
    print(f"covariance prediction, median of {args.repeats} x {args.calls} filter-calls "
          f"(numba {numba.__version__}, CPU {llvm.get_host_cpu_name()})")
    for name, (kernel, _) in candidates.items():
        us = np.median(times[name])
        print(f"  {name:21s} {us:7.3f} us/filter  {base / us:5.2f}x  bit-identical={state[name][4]}  "
              f"({_multiplies(kernel)})")


if __name__ == "__main__":
    main()
