"""Does a compiled C kernel pay where numba's lock-step lanes did not, per filter or in lock-step? Issue
30 leaves the route of a lock-step kernel open, "numba with non-aliasing arguments and SLP, or a compiled
C/C++ kernel, chosen by a fair side-by-side measurement"; benchmarks/bench_layout.py measures the numba
side. Here the phases of the update frame (avio/filter/lanes/covariance.c and update.c, the C of the
kernel's lock-step blocks) run as

- ``numba``: the kernel's own code and compile (non-aliasing arguments, SLP; avio/filter/_simd.py);
- ``numba lanes L``: bench_layout.py's L filters in lock-step, where it has them;
- ``C``: the same operations per filter in C;
- ``C lanes L``: L filters in lock-step in C (every array lanes-last, the lane loop innermost, ``restrict``),

compiled by the system's C compiler (``$CC``, else ``cc``) with ``-O3 -march=native -ffp-contract=off
-fno-trapping-math`` and no fast-math, so every variant must give the kernel's bits (checked). Timed side by side: CPU time
per filter, every variant once per repeat in a new random order, ratios paired per repeat, every array
64-byte aligned; scalar and packed FP64 instructions counted in the compiler's assembly (numba's:
benchmarks/simd.py: fp_counts).

    python benchmarks/native/bench_native.py [--phase prediction project ...] [--lanes 4 8] [--repeats 15]

``prediction``: P <- F P F^T + Q (avio.filter.kernels.propagate_covariance); ``project``: C P, P C^T and
Sigma = C P C^T (avio.filter.update.update), C with the zeros of the kernel's own measurement chain;
``information``: the information sum over a frame's inliers (update), a third of the features inliers, in
each lane others; ``gain``: K = P C^T X and the downdate P -= K C P (update); ``solve``: the 12x12 solve
with 13 right-hand sides (avio.filter._linalg.solve), a pivot per lane, on systems whose lanes pivot
differently; ``innovations``: the feature innovations (avio.filter.outliers). The phases of update() are
taken from the kernel's source (:func:`kernel_phase`), so the code timed is the kernel's own.
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

from avio.filter import measurement
from avio.filter import update as update_module
from avio.filter._linalg import matmul, matmul12, solve
from avio.filter.kernels import propagate_covariance
from avio.filter.outliers import feature_innovations_into
from avio.geometry import so3_exp

#: -fno-trapping-math: no FP exception is ever read, as LLVM (numba) assumes by default; without it gcc will not
#: turn a lane's select into a blend. Neither it nor the others change a result's bits (no contraction into FMA,
#: no reassociation: the tests compare every variant's bits with the kernel's).
FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fno-fast-math", "-fno-trapping-math", "-shared", "-fPIC")
PHASES = ("prediction", "project", "information", "gain", "solve", "innovations")
_PREFIX = {"prediction": "pred", "project": "proj", "information": "info", "gain": "gain", "solve": "solve",
           "innovations": "innov"}  # the phases' names in the C sources
SOURCES = ("covariance.c", "update.c")
SOURCE_DIR = HERE.parents[1] / "avio" / "filter" / "lanes"  # the kernel's own C (its lock-step blocks)
#: update()'s statements of each phase: (parameters, the first statement's start, the last one's text, what the
#: phase's function returns).
UPDATE_PHASES = {
    "project": ("project", "C, P, CP, PCt, Sig", "matmul(C, P, CP)", "0.5 * (Sig[a, b] + Sig[b, a])", ""),
    "information": ("update_information", "A, beta, X, rw, Jw, jw_f, inl, ldR, record, decided", "A[:] = 0.0",
                    "X[b, d] = beta[b]", "used, rr, log_det_R"),
    "gain": ("downdate", "P, PCt, X, CP, K", "for a in range(27):\n    for b in range(12):\n        K[a, b] = 0.0",
             "acc -= K[a, b] * CP[b, c]", ""),
}


def kernel_phase(name: str, source: str | None = None):
    """Phase ``name`` of the update (UPDATE_PHASES: the stage function of avio/filter/update.py it is in) as a
    Python function: its statements, from the first that starts with the phase's first text to the next that
    holds its last, taken from the kernel's source (``source``: that module's text) with d = 12, M = 3, F the
    features and the kernel's helpers in scope. SystemExit when the kernel no longer has them."""
    function, params, first, last, returns = UPDATE_PHASES[name]
    tree = ast.parse(source if source is not None else Path(update_module.__file__).read_text())
    body = next((n.body for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == function), [])
    code = [ast.unparse(n) for n in body]
    start = next((i for i, c in enumerate(code) if c.startswith(first)), None)
    end = None if start is None else next((i for i in range(start, len(code)) if last in code[i]), None)
    if end is None:
        raise SystemExit(f"bench_native.py: avio/filter/update.py's {function}() no longer has the phase {name!r} (from "
                         f"{first.splitlines()[0]!r} to {last!r}): update UPDATE_PHASES here")
    lines = ["d, M = 12, 3", "F = inl.shape[0]" if "inl" in params else "", *code[start:end + 1],
             f"return {returns}" if returns else ""]
    text = f"def {name}({params}):\n" + textwrap.indent("\n".join(line for line in lines if line), "    ")
    namespace = {"matmul": matmul, "matmul12": matmul12}
    exec(compile(text, f"<avio.filter.update.update: {name}>", "exec"), namespace)
    return namespace[name]


def compiler() -> str:
    """The C compiler to use: ``$CC``, else ``cc``; SystemExit naming what is missing."""
    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise SystemExit(f"bench_native.py needs a C compiler: {cc!r} is not on PATH (set CC)")
    return cc


def build(out_dir: Path) -> tuple[ctypes.CDLL, str]:
    """The C sources compiled into out_dir: the loaded library and the compiler's assembly."""
    cc = compiler()
    lib, sources = out_dir / "native.so", [str(SOURCE_DIR / name) for name in SOURCES]
    commands = [[cc, *FLAGS, "-o", str(lib), *sources, "-lm"],
                *([cc, *FLAGS[:-2], "-S", "-o", str(out_dir / f"{Path(src).stem}.s"), src] for src in sources)]
    for command in commands:
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"bench_native.py: {' '.join(command)} failed:\n{done.stderr}")
    asm = "".join((out_dir / f"{Path(src).stem}.s").read_text() for src in sources)
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
def _numba_calls(kernel, n, fresh, *args):
    for _ in range(n):
        kernel(*args)


@numba.njit
def _numba_solve_calls(kernel, n, fresh, A, B):
    for _ in range(n):
        A[:] = fresh[0]
        B[:] = fresh[1]
        kernel(A, B)


@numba.njit
def _numba_info_calls(kernel, n, fresh, A, beta, X, rw, Jw, jw_f, inl, ldR, stats):
    decided = np.zeros(inl.shape[0], np.uint8)
    for _ in range(n):
        used, rr, log_det_R = kernel(A, beta, X, rw, Jw, jw_f, inl, ldR, False, decided)
    stats[0], stats[1], stats[2] = used, rr, log_det_R


def _measurement_chains(n: int, rng) -> np.ndarray:
    """n maps C (12, 27) from the kernel's own measurement chain (avio.filter.measurement.measure) at
    poses along a drive: the zeros of Eq. 24's structure, the values of each filter its own."""
    ws, F = measurement.measure_workspace(), 8
    out = np.zeros((n, 12, 27))
    r, J, Gp, t12, t13 = np.zeros((4, F)), np.zeros((4, 12, F)), np.zeros((4, 6, F)), np.zeros(3), np.zeros(3)
    Rci = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera z forward, x right
    for i in range(n):
        R, cR0, cR1 = (so3_exp(rng.normal(0, 0.05, 3)) for _ in range(3))
        uv = rng.uniform(100, 600, (F, 3, 2))
        measurement.measure(R, np.array([2.0, 0, 0]), np.array([10.0, 0, 0]), np.zeros(3), cR0, np.array([1.0, 0, 0]), cR1,
                            rng.normal(0, 0.01, 3), 0.0, 718.0 + rng.normal(), 718.0, 607.0, 185.0, Rci,
                            rng.normal(0, 0.1, 3), uv, r, J, Gp, out[i], t12, t13, ws, False)
    return out


def _phase_inputs(phase: str, n: int, features: int, rng) -> tuple[dict, set, list]:
    """(args, shared, outputs) of n filters: name -> (n, ...) array in the numba kernel's argument order (or
    one array all filters share, named in shared), and the names of the outputs."""
    if phase == "prediction":
        P, Phi, Qd = _inputs(n)
        return {"P": P, "Phi": Phi, "Qd": Qd, "T": np.zeros((n, 15, 27)), "U": np.zeros((n, 15, 15))}, {"Qd"}, ["P"]
    if phase == "project":
        A = rng.normal(size=(n, 27, 27))
        args = {"C": _measurement_chains(n, rng), "P": A @ A.transpose(0, 2, 1) * 1e-3, "CP": np.zeros((n, 12, 27)),
                "PCt": np.zeros((n, 27, 12)), "Sig": np.zeros((n, 12, 12))}
        return args, set(), ["CP", "PCt", "Sig"]
    if phase == "information":
        F = features
        args = {"A": np.zeros((n, 12, 12)), "beta": np.zeros((n, 12)), "X": np.zeros((n, 12, 13)),
                "rw": rng.normal(size=(n, 3, F)), "Jw": rng.normal(size=(n, 3, 12, F)), "jw_f": np.zeros((n, 3, 12)),
                "inl": rng.random((n, F)) < 1 / 3, "ldR": rng.normal(size=(n, F)), "stats": np.zeros((n, 3))}
        return args, set(), ["A", "X", "stats"]
    if phase == "gain":
        P = rng.normal(size=(n, 27, 27))
        return ({"P": P + P.transpose(0, 2, 1), "PCt": rng.normal(size=(n, 27, 12)), "X": rng.normal(size=(n, 12, 13)),
                 "CP": 0.01 * rng.normal(size=(n, 12, 27)), "K": np.zeros((n, 27, 12))}, set(), ["P"])
    if phase == "solve":
        A, B = _systems(n)
        return {"A": A, "B": B}, set(), ["A", "B"]
    F, m, d = features, 3, 12
    J = rng.normal(size=(24, d))
    G = rng.normal(size=(F, m, 6))
    args = {"r": rng.normal(size=(1, m, F)), "H": rng.normal(size=(1, m, d, F)),
            "P": (J.T @ J / 24 + 0.1 * np.eye(d))[None], "Rm": np.einsum("fac,fbc->abf", G, G)[None],
            "B": np.zeros((1, m, d, F)), "z": np.zeros((1, m, F)), "logdet": np.zeros((1, F)),
            "Lp": np.zeros((1, d, d)), "S": np.zeros((1, m, m, F)), "L": np.zeros((1, m, m, F)), "y": np.zeros((1, m, F))}
    return args, set(), ["B", "z", "logdet"]


class Phase:
    """One phase: n filters' arguments in the numba kernel's order (``args``: name -> (n, ...) array per
    filter, or one array all filters share), which of them are outputs, and the reference outputs of
    the numba kernel, filter by filter."""

    def __init__(self, phase: str, lanes: list[int], features: int):
        self.phase, self.features = phase, features
        self.lanes = [] if phase == "innovations" else lanes  # it runs across a frame's features already
        fn = (kernel_phase(phase) if phase in UPDATE_PHASES else
              {"prediction": propagate_covariance, "solve": solve, "innovations": feature_innovations_into}[phase].py_func)
        with slp_vectorize(True):
            self.kernel = kernel_jit(fn, cache=False)  # the kernel's compile, uncached: its assembly can be read
        self.args, self.shared, self.outputs = _phase_inputs(phase, max(lanes), features, np.random.default_rng(1))
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
            calls = {"solve": _numba_solve_calls, "information": _numba_info_calls}.get(self.phase, _numba_calls)
            calls(self.kernel, n, fresh, *arrays)

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
        elif self.phase in ("innovations", "information"):
            ptrs.append(ctypes.c_long(self.features))
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
    p.add_argument("--features", type=int, default=50, help="innovations, information: a frame's (kitti00: 50)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        lib, asm = build(Path(tmp))
        cc = subprocess.run([compiler(), "--version"], capture_output=True, text=True).stdout.splitlines()[0]
        print(f"C: {cc}, {' '.join(FLAGS[:5])}; numba {numba.__version__}; median of {args.repeats} x {args.calls} "
              "filter-calls, CPU time; x: paired ratio against the numba kernel's own code")
        for name in args.phase:
            print(f"{name}:")
            phase = Phase(name, sorted(set(args.lanes)), args.features)
            for variant, us, ratio, same, counts in measure(phase, lib, asm, args.repeats, args.calls):
                print(f"  {variant:13s} {us:7.3f} us/filter  {ratio:5.2f}x  bit-identical={same}  "
                      f"({counts['scalar']:4d} scalar / {counts['packed']:4d} packed FP64)", flush=True)


if __name__ == "__main__":
    main()
