"""Does a layout across filters (lock-step lanes, issues 13 and 30) pay, phase by phase? Each phase
of the kernel's per-filter code against L filters in lock-step (the lane axis innermost, L a
compile-time constant), timed side by side, bits compared, scalar and packed FP64 instructions
counted (benchmarks/simd.py: fp_counts).

``--phase prediction`` (default): the covariance prediction ``P <- F P F^T + Q``
(avio.filter.kernels.propagate_covariance) as ``committed`` (numba's defaults: constant bounds,
LLVM unrolls the rows and leaves them scalar), ``rows`` (bounds read from the shapes: vectorised
behind a run-time alias check per row), ``committed +noalias+SLP`` (the kernel's own compile),
``lanes L`` (numba's defaults: the lane loops stay scalar, which made the first test of the layout
unfair), ``lanes L +noalias+SLP`` (non-aliasing arrays and LLVM's SLP vectoriser: packed) and
``lanes L (run-time)`` (the lane count read from the shape).

``--phase solve``: the update's 12x12 solve ``(I + A Sigma) X = [A | beta]`` (avio.filter._linalg.solve,
partial pivoting, 13 right-hand sides) against L systems in lock-step with a pivot per lane (the
pivot search and the eliminations packed across lanes, each lane's row swap its own), on systems
shaped like the filter's whose pivots differ between lanes; each call solves fresh copies.

``--phase features``: what lock-step could buy the phases that already run features last (packed
along a frame's features): L filters' feature innovations (avio.filter.outliers) and noise model
(avio.filter.update._noise_model) in lock-step do at best what one call over their features
concatenated does, each filter's 12x12 Cholesky of Sigma added back (the concatenated call
factors one): per filter, (the call on F L features) / L + (1 - 1/L) Cholesky against the call on F.

    python benchmarks/bench_layout.py [--lanes 4 8 16] [--repeats 7] [--calls 20000]
    python benchmarks/bench_layout.py --phase solve [--lanes 4 8 16] [--repeats 15]
    python benchmarks/bench_layout.py --phase features [--features 50] [--lanes 4 8] [--repeats 15]

Prints CPU microseconds per filter (median of --repeats; process CPU time; arrays 64-byte aligned:
simd.aligned) and the medians of the per-repeat ratios (every variant once per repeat, in a new
random order: paired). Written out here, not in avio: the alternatives measured, not the kernel.
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

from simd import aligned, fp_counts, kernel_jit, njit_packed, slp_vectorize

from avio.filter._linalg import solve
from avio.filter.kernels import propagate_covariance
from avio.filter.outliers import _cholesky, feature_innovations_into
from avio.filter.update import _noise_model

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
    return P, Phi, aligned(np.eye(15) * 1e-6)


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
                inputs, same = (aligned(P[0]), aligned(Phi[0]), aligned(T), aligned(U)), np.array_equal(Ps, reference)
            else:
                PL, PhiL = aligned(P[:L].transpose(1, 2, 0)), aligned(Phi[:L].transpose(1, 2, 0))
                TL, UL = aligned(np.zeros((15, 27, L))), aligned(np.zeros((15, 15, L)))
                out = PL.copy()
                kernel(out, PhiL, Qd, TL, UL)
                inputs, same = (PL, PhiL, TL, UL), np.array_equal(out.transpose(2, 0, 1), reference[:L])
            _calls(kernel, inputs[0].copy(), inputs[1], Qd, inputs[2], inputs[3], 1)  # the loop compiled alike
        state[name] = (inputs, same)
    return state


def solve_lanes_kernel(L: int):
    """solve of L systems in lock-step: A (m, m, L), B (m, k, L); scratch piv (L,) int64, big, inv,
    f (L,), ra (m, L), rb (k, L). Each lane does the operations of :func:`avio.filter._linalg.solve`
    in its order: its own pivot (the first largest |A[i, c]|), its own swap, and an elimination step
    skipped where its factor is zero, here by a select (the same bits: the skipped update is not
    computed). The pivot row and the row being solved are copied to ra, rb: a row read and another
    row of the same array written in one lane loop could alias for LLVM, which then packs nothing."""

    def lanes(A, B, piv, big, inv, f, ra, rb):
        m, k = A.shape[0], B.shape[1]
        for c in range(m):
            for q in range(L):
                piv[q], big[q] = c, abs(A[c, c, q])
            for i in range(c + 1, m):
                for q in range(L):
                    v = abs(A[i, c, q])
                    piv[q] = i if v > big[q] else piv[q]
                    big[q] = v if v > big[q] else big[q]
            for q in range(L):  # a lane's swap is its own (rows differ per lane: no common vector)
                p = piv[q]
                if p != c:
                    for j in range(m):
                        A[c, j, q], A[p, j, q] = A[p, j, q], A[c, j, q]
                    for j in range(k):
                        B[c, j, q], B[p, j, q] = B[p, j, q], B[c, j, q]
            for j in range(m):
                for q in range(L):
                    ra[j, q] = A[c, j, q]
            for j in range(k):
                for q in range(L):
                    rb[j, q] = B[c, j, q]
            for q in range(L):
                inv[q] = 1.0 / ra[c, q]
            for i in range(c + 1, m):
                for q in range(L):
                    f[q] = A[i, c, q] * inv[q]
                for j in range(c + 1, m):
                    for q in range(L):
                        a = A[i, j, q]
                        A[i, j, q] = a - f[q] * ra[j, q] if f[q] != 0.0 else a
                for j in range(k):
                    for q in range(L):
                        b = B[i, j, q]
                        B[i, j, q] = b - f[q] * rb[j, q] if f[q] != 0.0 else b
        for c in range(m - 1, -1, -1):
            for j in range(k):
                for q in range(L):
                    rb[j, q] = B[c, j, q]
            for i in range(c + 1, m):
                for q in range(L):
                    f[q] = A[c, i, q]
                for j in range(k):
                    for q in range(L):
                        rb[j, q] -= f[q] * B[i, j, q]
            for q in range(L):
                inv[q] = 1.0 / A[c, c, q]
            for j in range(k):
                for q in range(L):
                    B[c, j, q] = rb[j, q] * inv[q]

    return njit_packed(lanes, error_model="numpy")


@numba.njit
def _solve_calls(kernel, A0, B0, A, B, n):
    for _ in range(n):
        A[:] = A0
        B[:] = B0
        kernel(A, B)


@numba.njit
def _solve_lane_calls(kernel, A0, B0, A, B, piv, big, inv, f, ra, rb, n):
    for _ in range(n):
        A[:] = A0
        B[:] = B0
        kernel(A, B, piv, big, inv, f, ra, rb)


def _systems(n: int, seed: int = 0):
    """n systems shaped like the update's: M = I + A Sigma (12, 12) and [A | beta] (12, 13)."""
    rng = np.random.default_rng(seed)
    J, S = rng.normal(size=(n, 24, 12)), rng.normal(size=(n, 12, 12))
    A = np.einsum("nki,nkj->nij", J, J)
    Sig = np.einsum("nik,njk->nij", S, S) * 0.05
    M = np.eye(12) + A @ Sig
    return M, np.concatenate([A, rng.normal(size=(n, 12, 1))], axis=2)


def solve_phase(args) -> None:
    """--phase solve: the committed per-filter solve against L filters in lock-step (module docstring)."""
    Ls = sorted(set(args.lanes))
    M, X = _systems(max(Ls))
    ref_A, ref_B, state, kernels = M.copy(), X.copy(), {}, {L: solve_lanes_kernel(L) for L in Ls}
    for i in range(len(M)):
        solve(ref_A[i], ref_B[i])
    for L, kernel in kernels.items():
        A0, B0 = aligned(M[:L].transpose(1, 2, 0)), aligned(X[:L].transpose(1, 2, 0))
        scratch = (np.zeros(L, np.int64), *(aligned(np.zeros(shape)) for shape in (L, L, L, (12, L), (13, L))))
        A, B = aligned(A0), aligned(B0)
        with slp_vectorize(True):
            _solve_lane_calls(kernel, A0, B0, A, B, *scratch, 1)
        same = np.array_equal(A.transpose(2, 0, 1), ref_A[:L]) and np.array_equal(B.transpose(2, 0, 1), ref_B[:L])
        state[L] = (A0, B0, A, B, scratch, same)
    committed_solve = kernel_jit(solve.py_func, cache=False)  # the kernel's compile, uncached: its assembly can be read
    A, B = aligned(M[0]), aligned(X[0])
    with slp_vectorize(True):
        _solve_calls(committed_solve, M[0], X[0], A, B, 1)
    times, rng = {"committed": [], **{L: [] for L in Ls}}, np.random.default_rng(0)
    for _ in range(args.repeats):  # paired: every variant once per repeat, in a new order each
        for name in rng.permutation(np.array(list(times), dtype=object)):
            L = 1 if name == "committed" else name
            n = max(1, args.calls // L)
            t = time.process_time()
            if name == "committed":
                _solve_calls(committed_solve, M[0], X[0], A, B, n)
            else:
                _solve_lane_calls(kernels[name], *state[name][:4], *state[name][4], n)
            times[name].append((time.process_time() - t) / (n * L) * 1e6)
    base = np.asarray(times["committed"])
    print(f"12x12 solve with 13 right-hand sides, median of {args.repeats} x {args.calls} filter-calls, CPU time "
          f"(numba {numba.__version__}, CPU {llvm.get_host_cpu_name()})")
    print(f"  {'committed':24s} {np.median(base):7.3f} us/filter  {1.0:5.2f}x  bit-identical=True  "
          f"({_counts(committed_solve)})")
    for L in Ls:
        us = np.asarray(times[L])
        print(f"  {f'lanes {L} +noalias+SLP':24s} {np.median(us):7.3f} us/filter  {np.median(base / us):5.2f}x  "
              f"bit-identical={state[L][5]}  ({_counts(kernels[L])})")


@numba.njit
def _feature_calls(innov, noise, r, H, P, Gp, Rm, sd, Lm, ldR, B, z, ld, Lp, S, L, y, n, which):
    for _ in range(n):
        if which == 0:
            innov(r, H, P, Rm, B, z, ld, Lp, S, L, y)
        elif which == 1:
            noise(Gp, 0.7, Rm, sd, Lm, ldR)
        else:
            _cholesky(P, Lp)


def features_phase(args) -> None:
    """--phase features (module docstring): per-filter CPU us of each phase at --features, and its
    lock-step estimate at L lanes (medians of the per-repeat ratios: paired)."""
    rng, F0, m, d, inputs = np.random.default_rng(0), args.features, 3, 12, {}
    J = rng.normal(size=(27, 12))
    P = J.T @ J + np.eye(12)  # a covariance Sigma (12, 12)
    for F in sorted({F0} | {F0 * L for L in args.lanes}):
        shapes = ((m, m, F), (m, F), (m, m, F), (F,), (m, d, F), (m, F), (F,), (d, d), (m, m, F), (m, m, F), (m, F))
        r, H, G = rng.normal(size=(m, F)), rng.normal(size=(m, d, F)), rng.normal(size=(m, 6, F))
        inputs[F] = tuple(map(aligned, (r, H, P, G, *map(np.zeros, shapes))))
        for which in (1, 0, 2):  # the noise model first: it fills R for the innovations
            _feature_calls(feature_innovations_into, _noise_model, *inputs[F], 1, which)
    times = {(w, F): [] for w in range(3) for F in inputs}
    for rep in range(args.repeats):  # every (phase, F) once per repeat, in a new order each
        for i in np.random.default_rng(rep).permutation(len(times)):
            w, F = list(times)[i]
            n = max(1, args.calls * F0 // F)
            t = time.process_time()
            _feature_calls(feature_innovations_into, _noise_model, *inputs[F], n, w)
            times[(w, F)].append((time.process_time() - t) / n * 1e6)
    t = {key: np.asarray(v) for key, v in times.items()}
    print(f"phases over features, CPU us per filter ({F0} features), median of {args.repeats}; lock-step at L lanes "
          f"estimated from one call over {F0} L features (12x12 Cholesky {np.median(t[(2, F0)]):.3f} us, added back per lane)")
    for w, name in ((0, "feature innovations"), (1, "noise model")):
        cells = []
        for L in args.lanes:
            est = t[(w, F0 * L)] / L + (t[(2, F0)] * (1 - 1 / L) if w == 0 else 0.0)
            cells.append(f"{L} lanes {np.median(est):6.3f} us ({np.median(t[(w, F0)] / est):4.2f}x)")
        print(f"  {name:20s} {np.median(t[(w, F0)]):6.3f} us   " + "   ".join(cells))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--phase", choices=["prediction", "solve", "features"], default="prediction")
    p.add_argument("--lanes", type=int, nargs="+", default=[4, 8, 16])
    p.add_argument("--runtime-lanes", type=int, nargs="+", default=[8, 32, 64])
    p.add_argument("--features", type=int, default=50, help="--phase features: a frame's (kitti00: 50)")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--calls", type=int, default=20000, help="filter-calls per timing")
    args = p.parse_args(argv)
    if args.phase != "prediction":
        return solve_phase(args) if args.phase == "solve" else features_phase(args)
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
            work = aligned(P0)
            n = max(1, args.calls // L)
            t = time.process_time()
            _calls(kernel, work, Phi0, Qd, T0, U0, n)
            times[name].append((time.process_time() - t) / (n * L) * 1e6)
    base, ours = np.asarray(times["committed"]), np.asarray(times["committed +noalias+SLP"])
    print(f"covariance prediction, median of {args.repeats} x {args.calls} filter-calls, CPU time "
          f"(numba {numba.__version__}, CPU {llvm.get_host_cpu_name()}); x: against committed, and against "
          "the kernel's own compile (committed +noalias+SLP)")
    for name, (kernel, _, _) in candidates.items():
        us = np.asarray(times[name])
        print(f"  {name:24s} {np.median(us):7.3f} us/filter  {np.median(base / us):5.2f}x  {np.median(ours / us):5.2f}x  "
              f"bit-identical={state[name][1]}  ({_counts(kernel)})")


if __name__ == "__main__":
    main()
