"""Does a compiled C kernel pay where numba's lock-step lanes did not, per filter or in lock-step? Issue
30 leaves the route of a lock-step kernel open, "numba with non-aliasing arguments and SLP, or a compiled
C/C++ kernel, chosen by a fair side-by-side measurement"; benchmarks/bench_layout.py measures the numba
side. Here three phases of the update frame (benchmarks/native/layout.c) run as

- ``numba``: the kernel's own code and compile (non-aliasing arguments, SLP; avio/filter/_simd.py);
- ``C``: the same operations per filter in C;
- ``C lanes L``: L filters in lock-step in C (every array lanes-last, the lane loop innermost, ``restrict``),

compiled by the system's C compiler (``$CC``, else ``cc``) with ``-O3 -march=native -ffp-contract=off``
and no fast-math, so every variant must give the kernel's bits (checked). Timed side by side: CPU time
per filter, every variant once per repeat in a new random order, ratios paired per repeat; scalar and
packed FP64 instructions counted in the compiler's assembly (numba's: benchmarks/simd.py: fp_counts).

    python benchmarks/native/bench_native.py [--phase prediction gain solve] [--lanes 4 8] [--repeats 15]

``prediction``: P <- F P F^T + Q (avio.filter.kernels.propagate_covariance); ``gain``: K = P C^T X and
the downdate P -= K C P (the end of avio.filter.update.update, its two loops taken from the kernel's
source); ``solve``: the 12x12 solve with 13 right-hand sides
(avio.filter._linalg.solve), a pivot per lane, on systems whose lanes pivot differently.
"""

from __future__ import annotations

import argparse
import ast
import ctypes
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numba
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE.parent))

from bench_layout import _calls as _layout_calls
from bench_layout import _inputs, _solve_lane_calls, _systems, lanes_kernel, solve_lanes_kernel
from simd import aligned, asm_fp_counts, fp_counts, kernel_jit, slp_vectorize

from avio.filter import update as update_module
from avio.filter._linalg import solve
from avio.filter.kernels import propagate_covariance
from avio.filter.outliers import feature_innovations_into

FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fno-fast-math", "-shared", "-fPIC")
PHASES = ("prediction", "gain", "solve", "innovations")
_PREFIX = {"prediction": "pred", "gain": "gain", "solve": "solve", "innovations": "innov"}  # in layout.c


def kernel_gain_downdate(source: str | None = None):
    """The kernel's gain and downdate (Eq. 42) as a Python function of (Pi, PCt, X, CP, K): the two loops of
    avio.filter.update.update that write K[a, b], taken from its source (``source``: that module's text), so
    the phase timed is the kernel's own code, not a copy. SystemExit when the kernel no longer has them."""
    tree = ast.parse(source if source is not None else Path(update_module.__file__).read_text())
    body = next((n.body for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "update"), [])
    loops = [n for n in body if isinstance(n, ast.For) and "K[a, b]" in ast.unparse(n)]
    if len(loops) != 2:
        raise SystemExit(f"bench_native.py: avio/filter/update.py's update() has {len(loops)} loops writing "
                         "K[a, b], not the gain's and the downdate's two: update the phase 'gain' here")
    code = "def gain_downdate(Pi, PCt, X, CP, K):\n    d = 12\n" + textwrap.indent("\n".join(map(ast.unparse, loops)), "    ")
    namespace: dict = {}
    exec(compile(code, "<avio.filter.update.update: gain and downdate>", "exec"), namespace)
    return namespace["gain_downdate"]


def compiler() -> str:
    """The C compiler to use: ``$CC``, else ``cc``; SystemExit naming what is missing."""
    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise SystemExit(f"bench_native.py needs a C compiler: {cc!r} is not on PATH (set CC)")
    return cc


def build(out_dir: Path) -> tuple[ctypes.CDLL, str]:
    """layout.c compiled into out_dir: the loaded library and the compiler's assembly."""
    cc = compiler()
    lib = out_dir / "layout.so"
    for command in ([cc, *FLAGS, "-o", str(lib), str(HERE / "layout.c"), "-lm"],
                    [cc, *FLAGS[:-2], "-S", "-o", str(out_dir / "layout.s"), str(HERE / "layout.c")]):
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"bench_native.py: {' '.join(command)} failed:\n{done.stderr}")
    asm = (out_dir / "layout.s").read_text()
    return ctypes.CDLL(str(lib)), asm


def c_counts(asm: str, function: str) -> dict[str, int]:
    """Scalar and packed FP64 arithmetic instructions of ``function`` in the assembly, its clones
    (``function.constprop.0``) and what it inlined included: each phase's static function has one
    caller, its ``*_calls`` loop, which inlines it (the tests check no variant counts empty)."""
    bodies, name = {}, None
    for line in asm.splitlines():
        label = re.match(r"^([A-Za-z_][\w.]*):", line)
        if label and not label.group(1).startswith(".L"):
            name = label.group(1)
        elif name is not None:
            bodies.setdefault(name, []).append(line)
    text = "\n".join(line for key, lines in bodies.items() if key == function or key.startswith(f"{function}.")
                     for line in lines)
    return asm_fp_counts(text)


def _lanes(a: np.ndarray, L: int) -> np.ndarray:
    """The first L filters of an (n, ...) array, lanes-last, aligned."""
    return aligned(np.moveaxis(a[:L], 0, -1))


@numba.njit
def _numba_calls(kernel, n, fresh, a, b, c, d, e):
    for _ in range(n):
        kernel(a, b, c, d, e)


@numba.njit
def _numba_solve_calls(kernel, n, fresh, A, B):
    for _ in range(n):
        A[:] = fresh[0]
        B[:] = fresh[1]
        kernel(A, B)


@numba.njit
def _numba_innov_calls(kernel, n, fresh, r, H, P, Rm, B, z, ld, Lp, S, L, y):
    for _ in range(n):
        kernel(r, H, P, Rm, B, z, ld, Lp, S, L, y)


class Phase:
    """One phase: n filters' arguments in the numba kernel's order (``args``: name -> (n, ...) array per
    filter, or one array all filters share), which of them are outputs, and the reference outputs of
    the numba kernel, filter by filter."""

    def __init__(self, phase: str, lanes: list[int], features: int):
        self.phase, self.lanes = phase, lanes
        n, rng = max(lanes), np.random.default_rng(1)
        fn = {"prediction": propagate_covariance.py_func, "gain": kernel_gain_downdate(), "solve": solve.py_func,
              "innovations": feature_innovations_into.py_func}[phase]
        with slp_vectorize(True):
            self.kernel = kernel_jit(fn, cache=False)  # the kernel's compile, uncached: its assembly can be read
        self.shared: set[str] = set()
        if phase == "prediction":
            P, Phi, Qd = _inputs(n)
            self.args = {"P": P, "Phi": Phi, "Qd": Qd, "T": np.zeros((n, 15, 27)), "U": np.zeros((n, 15, 15))}
            self.shared, self.outputs = {"Qd"}, ["P"]
        elif phase == "gain":
            P = rng.normal(size=(n, 27, 27))
            self.args = {"P": P + P.transpose(0, 2, 1), "PCt": rng.normal(size=(n, 27, 12)),
                         "X": rng.normal(size=(n, 12, 13)), "CP": 0.01 * rng.normal(size=(n, 12, 27)),
                         "K": np.zeros((n, 27, 12))}
            self.outputs = ["P"]
        elif phase == "solve":
            A, B = _systems(n)
            self.args, self.outputs = {"A": A, "B": B}, ["A", "B"]
        else:
            F, m, d = features, 3, 12
            J = rng.normal(size=(24, d))
            G = rng.normal(size=(F, m, 6))
            self.args = {"r": rng.normal(size=(1, m, F)), "H": rng.normal(size=(1, m, d, F)),
                         "P": (J.T @ J / 24 + 0.1 * np.eye(d))[None], "Rm": np.einsum("fac,fbc->abf", G, G)[None],
                         "B": np.zeros((1, m, d, F)), "z": np.zeros((1, m, F)), "logdet": np.zeros((1, F)),
                         "Lp": np.zeros((1, d, d)), "S": np.zeros((1, m, m, F)), "L": np.zeros((1, m, m, F)),
                         "y": np.zeros((1, m, F))}
            self.outputs, self.lanes = ["B", "z", "logdet"], []  # it runs across a frame's features already
        self.reference = {}
        for i in range(len(next(iter(self.args.values())))):
            one = self._filter(i)
            self._numba(one, 1)
            for name in self.outputs:
                self.reference.setdefault(name, []).append(one[name])

    def _filter(self, i: int) -> dict:
        """Filter i's arguments, aligned copies."""
        return {k: aligned(v if k in self.shared else v[i]) for k, v in self.args.items()}

    def _numba(self, args: dict, n: int, fresh=None):
        arrays = list(args.values())
        fresh = tuple(fresh if fresh is not None else [a.copy() for a in arrays])
        with slp_vectorize(True):
            if self.phase == "solve":
                _numba_solve_calls(self.kernel, n, fresh, *arrays)
            elif self.phase == "innovations":
                _numba_innov_calls(self.kernel, n, fresh, *arrays)
            else:
                _numba_calls(self.kernel, n, fresh, *arrays)

    def variants(self) -> list[tuple[str, int]]:
        """(name, lanes): numba per filter, numba lanes (benchmarks/bench_layout.py's, where it has them), C per
        filter, C lanes."""
        numba_lanes = self.lanes if self.phase in ("prediction", "solve") else []
        return [("numba", 1), *((f"numba lanes {L}", L) for L in numba_lanes), ("C", 1),
                *((f"C lanes {L}", L) for L in self.lanes)]

    def _numba_lanes(self, L: int):
        """bench_layout.py's lock-step variant of the phase, compiled with both switches, on aligned lanes-last
        arrays: (run(n), same bits, the dispatcher)."""
        with slp_vectorize(True):
            if self.phase == "prediction":
                kernel = lanes_kernel(L, packed=True)
                P, Phi = _lanes(self.args["P"], L), _lanes(self.args["Phi"], L)
                args = (P, Phi, aligned(self.args["Qd"]), aligned(np.zeros((15, 27, L))), aligned(np.zeros((15, 15, L))))
                _layout_calls(kernel, *args, 1)
                same = np.array_equal(np.moveaxis(P, -1, 0), np.asarray(self.reference["P"][:L]))
                P[...] = _lanes(self.args["P"], L)
                return (lambda n: _layout_calls(kernel, *args, n)), same, kernel
            kernel = solve_lanes_kernel(L)
            A0, B0 = _lanes(self.args["A"], L), _lanes(self.args["B"], L)
            args = (A0, B0, A0.copy(), B0.copy(), np.zeros(L, np.int64), *(aligned(np.zeros(L)) for _ in range(3)),
                    aligned(np.zeros((12, L))), aligned(np.zeros((13, L))))
            _solve_lane_calls(kernel, *args, 1)
        same = all(np.array_equal(np.moveaxis(args[2 + i], -1, 0), np.asarray(self.reference[k][:L]))
                   for i, k in enumerate(("A", "B")))
        return (lambda n: _solve_lane_calls(kernel, *args, n)), same, kernel

    def prepare(self, lib, asm: str, variant: str, L: int):
        """(run(n): time n filter-calls, same bits after one call, FP64 counts) for one variant, its arrays
        made once."""
        prefix = _PREFIX[self.phase]
        if variant == "numba lanes":
            run, same, kernel = self._numba_lanes(L)
            return run, same, fp_counts(kernel)
        if variant == "numba":
            args = self._filter(0)
            fresh = tuple(a.copy() for a in args.values())
            self._numba(args, 1, fresh)
            return (lambda n: self._numba(args, n, fresh)), True, fp_counts(self.kernel)
        lanes = variant == "C lanes"
        if lanes:
            args = {k: aligned(v) if k in self.shared else _lanes(v, L) for k, v in self.args.items()}
        else:
            args = self._filter(0)
        fresh = {k: a.copy() for k, a in args.items()}
        fn = getattr(lib, f"{prefix}_lanes_calls_{L}" if lanes else f"{prefix}_calls")
        fn.restype = None
        ptrs = [a.ctypes.data_as(ctypes.c_void_p) for a in args.values()]
        if self.phase == "solve":  # solve_calls(A0, B0, A, B[, ra, rb], n): fresh copies each call
            scratch = [aligned(np.zeros((12, L))), aligned(np.zeros((13, L)))] if lanes else []
            ptrs = [fresh["A"].ctypes.data_as(ctypes.c_void_p), fresh["B"].ctypes.data_as(ctypes.c_void_p), *ptrs,
                    *(s.ctypes.data_as(ctypes.c_void_p) for s in scratch)]
        elif self.phase == "innovations":
            ptrs.append(ctypes.c_long(args["r"].shape[-1]))
        fn(*ptrs, ctypes.c_long(1))
        same = all(np.array_equal(np.moveaxis(args[k], -1, 0) if lanes else args[k],
                                  np.asarray(self.reference[k][:L]) if lanes else self.reference[k][0])
                   for k in self.outputs)
        for k, a in args.items():
            a[...] = fresh[k]
        return (lambda n: fn(*ptrs, ctypes.c_long(n))), same, c_counts(asm, fn.__name__)


def measure(phase: Phase, lib, asm: str, repeats: int, calls: int, seed: int = 0):
    """(variant, median CPU us per filter, median paired ratio against numba, same bits, FP64 counts)
    of every variant of the phase."""
    variants = phase.variants()
    kinds = {name: name if name in ("numba", "C") else name.rsplit(" ", 1)[0] for name, _ in variants}
    runs = {name: phase.prepare(lib, asm, kinds[name], L) for name, L in variants}
    times = {name: [] for name, _ in variants}
    rng = np.random.default_rng(seed)
    for _ in range(repeats):  # paired: every variant once per repeat, in a new order each
        for i in rng.permutation(len(variants)):
            name, L = variants[i]
            n = max(1, calls // L)
            t = time.process_time()
            runs[name][0](n)
            times[name].append((time.process_time() - t) / (n * L))
    base = np.asarray(times["numba"])
    return [(name, 1e6 * float(np.median(times[name])), float(np.median(base / np.asarray(times[name]))),
             runs[name][1], runs[name][2]) for name, _ in variants]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--phase", nargs="+", choices=PHASES, default=list(PHASES))
    p.add_argument("--lanes", type=int, nargs="+", default=[4, 8], choices=[4, 8])
    p.add_argument("--repeats", type=int, default=15)
    p.add_argument("--calls", type=int, default=20000, help="filter-calls per timing")
    p.add_argument("--features", type=int, default=50, help="innovations: a frame's features (kitti00: 50)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        lib, asm = build(Path(tmp))
        cc = subprocess.run([compiler(), "--version"], capture_output=True, text=True).stdout.splitlines()[0]
        print(f"C: {cc}, {' '.join(FLAGS[:4])}; numba {numba.__version__}; median of {args.repeats} x {args.calls} "
              "filter-calls, CPU time; x: paired ratio against the numba kernel's own code")
        for name in args.phase:
            print(f"{name}:")
            phase = Phase(name, sorted(set(args.lanes)), args.features)
            for variant, us, ratio, same, counts in measure(phase, lib, asm, args.repeats, args.calls):
                print(f"  {variant:13s} {us:7.3f} us/filter  {ratio:5.2f}x  bit-identical={same}  "
                      f"({counts['scalar']:4d} scalar / {counts['packed']:4d} packed FP64)", flush=True)


if __name__ == "__main__":
    main()
