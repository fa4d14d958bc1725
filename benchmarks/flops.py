"""FP64 operations of the filter kernel counted from its code, per phase of a frame (issue 30).

Why here and not in avio/filter/: this is a measuring tool, like the other scripts of
benchmarks/, and reads the kernel without changing it (avio never imports benchmarks).

How it counts (:func:`count_run`): the kernel's numba functions are plain Python underneath
(``dispatcher.py_func``). Each is rebuilt as a Python twin whose globals point to the twins of the
functions it calls and to a numpy whose float arrays hold :class:`Flop` numbers, a float that
counts every add, subtract, multiply, divide and square root done with it (negation, abs and
comparisons are not FLOPs; log, sin and cos are counted apart as ``transcendental``). The filter
of :func:`avio.filter.run` then runs as Python on the same inputs, with the same branches (a Flop
is the same float), so the counts are those of the compiled kernel's source, skipped zeros,
dropped features and RANSAC inliers included. Each FLOP goes to the innermost function of
:data:`PHASES`; inside ``update`` the lines between the anchors of :data:`UPDATE_ANCHORS` (the
comments that open each step) split its own body. Slow (~0.3 s a frame): for a few frames, not a
drive.

The constants (:data:`PER_UPDATE_FRAME`) are FLOPs of one update frame at the kernel's loop
bounds as a function of F, the features per update (FilterConfig.max_update_features: the
measurement, noise model and whitening per feature, RANSAC's F hypotheses x F features), with
every feature used: ``per_update_frame(F)`` evaluates them.
tests/benchmarks/test_flops.py counts a frame with :func:`count_run` and checks them, so an
edit of a loop bound fails there and says the new numbers.

    python benchmarks/flops.py [--frames 12] [--features 8 16]   # counts, per phase
"""

from __future__ import annotations

import argparse
import math
import sys
import types
from pathlib import Path

import numpy as np
from numba.core.registry import CPUDispatcher

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

_COUNT: dict[str, int] = {}
_CALLS: dict[str, int] = {}
_ALLOCATED = [0]  # bytes the kernel allocated (np.empty, np.zeros) in the counted run
_STACK: list[str] = []

#: The kernel's functions that open a phase (innermost wins).
PHASES = {"propagate_one": "propagation", "propagate_covariance": "covariance prediction",
          "measure": "measurement", "_noise_model": "noise model", "feature_innovations_into": "innovations",
          "one_point_ransac_into": "RANSAC", "mahalanobis_gate": "gate", "inject": "injection",
          "slide": "slide", "zero_velocity_update_into": "zero-velocity update", "_bad": "divergence test",
          "update": "update, selection", "project": "C P and Sigma", "update_statistics": "gain",
          "downdate": "downdate"}
#: Lines of avio/filter/update.py's stage functions that open a step of their own body (by function; the
#: text a line starts with): the rest of update() and update_information() is "update, selection".
UPDATE_ANCHORS = {"update_information": {"# The score (avio/objectives.py": "score",
                                         "# Information form over the inliers": "information sum",
                                         "# X = (I + A Sigma)^-1": "gain"},
                  "update": {"solve(u_.Mx, u_.X)": "gain"}}


#: FLOPs per call of each phase: (fixed, per feature, per feature squared), F the features per
#: update (the loop bound of the update's per-feature loops, FilterConfig.max_update_features),
#: every feature valid, linearisable and a RANSAC inlier (a noise-free drive). Counted by
#: :func:`count_run` at F = 4, 8, 12 (``python benchmarks/flops.py``) and checked by
#: tests/benchmarks/test_flops.py. Every frame: prediction (propagation and covariance, from
#: the second frame on), slide, divergence test; an update frame adds the rest.
EVERY_FRAME = {"propagation": (699, 0, 0), "covariance prediction": (7308, 0, 0), "slide": (1515, 0, 0),
               "divergence test": (750, 0, 0)}
UPDATE = {"measurement": (2178, 963, 0), "noise model": (1, 105, 0), "C P and Sigma": (8556, 0, 0),
          "innovations": (662, 657, 0), "score": (0, 10, 0), "RANSAC": (0, 75, 63), "gate": (0, 6, 0),
          "information sum": (0, 1060, 0), "gain": (9418, 0, 0), "downdate": (18936, 0, 0),
          "injection": (324, 0, 0), "update, selection": (19, 0, 0)}


#: Phases that run whole blocks of avio.filter.trifocal.LANES features (a partial block's spare
#: lanes compute too): their per-feature terms count F rounded up to whole blocks.
IN_BLOCKS = ("measurement",)


def per_update_frame(F: int) -> dict[str, int]:
    """FLOPs of each phase of one update frame (prediction, update, slide, divergence test) with F
    features per update (:data:`UPDATE`, :data:`EVERY_FRAME`; :data:`IN_BLOCKS`)."""
    from avio.filter.trifocal import LANES

    blocks = -(-F // LANES) * LANES
    return {k: a + b * (blocks if k in IN_BLOCKS else F) + c * F * F
            for k, (a, b, c) in {**EVERY_FRAME, **UPDATE}.items()}


def per_evaluation(result, F: int) -> float:
    """Mean FLOPs of one filter's run (one evaluation) of a FilterResult: every frame up to its
    divergence pays :data:`EVERY_FRAME` (the first no prediction), every frame with a trifocal update
    (``dof > 0``) :data:`UPDATE` at F features (an upper bound where fewer features are used: the
    information sum runs over the inliers only). Zero-velocity updates (standing still) are left out."""
    N = result.p_world_imu_m.shape[1]
    alive = np.where(result.diverged_at_frame >= 0, result.diverged_at_frame, N)
    updates = np.count_nonzero(np.asarray(result.dof) > 0, axis=1)
    every = sum(a for a, _, _ in EVERY_FRAME.values())
    prediction = EVERY_FRAME["propagation"][0] + EVERY_FRAME["covariance prediction"][0]
    upd = sum(v for k, v in per_update_frame(F).items() if k in UPDATE)
    return float(np.mean(alive * every - np.minimum(alive, 1) * prediction + updates * upd))


def flop_per_cycle() -> tuple[int, int, str]:
    """(scalar, SIMD) FP64 FLOP per cycle of one core of this CPU, and the ISA assumed: two FMA
    pipes, an FMA counted as 2 FLOPs (as vendors quote peaks); lanes of 8 with AVX-512 (4 on
    Zen 4, which splits 512-bit operations in two), 4 with AVX2, 2 with SSE2. The kernel is
    compiled without FMA contraction (no fastmath), so half of either is its real ceiling."""
    from llvmlite import binding as llvm

    feats, cpu = llvm.get_host_cpu_features(), llvm.get_host_cpu_name()
    if feats.get("avx512f", False):
        lanes, isa = (4, "AVX-512 (double-pumped)") if cpu.startswith("znver4") else (8, "AVX-512")
    elif feats.get("avx2", False) and feats.get("fma", False):
        lanes, isa = 4, "AVX2+FMA"
    else:
        lanes, isa = 2, "SSE2"
    return 4, 4 * lanes, f"{cpu}, {isa}, 2 FMA pipes"


def cpu_ghz() -> float:
    """The core clock in GHz as /proc/cpuinfo reports it (the highest ``cpu MHz``; a VM reports
    its nominal clock), 0 when unknown."""
    try:
        mhz = [float(ln.split(":")[1]) for ln in Path("/proc/cpuinfo").read_text().splitlines()
               if ln.startswith("cpu MHz")]
    except OSError:
        return 0.0
    return max(mhz, default=0.0) / 1e3


def rate_line(flops_per_eval: float, cpu_s_per_eval: float) -> str:
    """Achieved GFLOP/s per core (FLOPs counted from the code over CPU seconds) and its fraction
    of one core's scalar and SIMD FP64 peak."""
    gflops = flops_per_eval / cpu_s_per_eval / 1e9
    scalar, simd, isa = flop_per_cycle()
    ghz = cpu_ghz()
    if ghz <= 0:
        return f"{gflops:.2f} GFLOP/s per core (peak unknown: no CPU clock)"
    return (f"{gflops:.2f} GFLOP/s per core = {gflops / (scalar * ghz):.0%} of scalar, {gflops / (simd * ghz):.0%} of "
            f"SIMD FP64 peak ({scalar}/{simd} FLOP/cycle x {ghz:.2f} GHz; {isa})")


def _add(n: int = 1, kind: str | None = None) -> None:
    phase = kind or _phase()
    _COUNT[phase] = _COUNT.get(phase, 0) + n


_UPDATE_LINES: dict[str, list[tuple[int, str]]] = {}  # function: (first line, step) of UPDATE_ANCHORS


def _phase() -> str:
    phase = _STACK[-1] if _STACK else "other"
    if phase == "update, selection" and _UPDATE_LINES:
        f = sys._getframe(2)
        while f is not None and f.f_code.co_name not in _UPDATE_LINES:
            f = f.f_back
        if f is not None:
            for line, name in reversed(_UPDATE_LINES[f.f_code.co_name]):
                if f.f_lineno >= line:
                    return name
    return phase


class Flop(float):
    """A float that counts the FP64 arithmetic done with it (the result is a Flop again)."""

    def _op(op):  # builds the methods below
        def method(self, other):
            out = getattr(float, op)(self, other)
            if out is NotImplemented:
                return out
            _add()
            return Flop(out)

        return method

    __add__, __radd__, __sub__, __rsub__ = _op("__add__"), _op("__radd__"), _op("__sub__"), _op("__rsub__")
    __mul__, __rmul__, __truediv__, __rtruediv__ = _op("__mul__"), _op("__rmul__"), _op("__truediv__"), _op("__rtruediv__")
    __pow__ = _op("__pow__")  # x ** 2: one multiply

    def __neg__(self):
        return Flop(-float(self))

    def __abs__(self):
        return Flop(abs(float(self)))


def _count_sqrt(x):
    _add()
    return Flop(math.sqrt(x))


def _transcendental(fn):
    def apply(x):
        _add(1, "transcendental (log, sin, cos)")
        return Flop(fn(x))

    return apply


class _Numpy(types.SimpleNamespace):
    """numpy as the twins see it: float arrays of Flops, counted square roots."""

    def __getattr__(self, name):
        return getattr(np, name)

    @staticmethod
    def _floats(shape, fill):
        _ALLOCATED[0] += 8 * int(np.prod(shape))
        out = np.empty(shape, dtype=object)
        out.fill(Flop(fill))
        return out

    def empty(self, shape, dtype=float):
        return self._floats(shape, 0.0) if np.dtype(dtype) == np.float64 else self._other(np.empty, shape, dtype)

    def zeros(self, shape, dtype=float):
        return self._floats(shape, 0.0) if np.dtype(dtype) == np.float64 else self._other(np.zeros, shape, dtype)

    @staticmethod
    def _other(make, shape, dtype):
        out = make(shape, dtype)
        _ALLOCATED[0] += out.nbytes
        return out

    @staticmethod
    def sqrt(x):
        if isinstance(x, np.ndarray):
            return np.array([_count_sqrt(v) for v in x.ravel()], dtype=object).reshape(x.shape)
        return _count_sqrt(x)

    log = staticmethod(_transcendental(math.log))
    sin = staticmethod(_transcendental(math.sin))
    cos = staticmethod(_transcendental(math.cos))


def _twin(func, memo: dict):
    """The Python twin of a numba dispatcher (its callees and numpy replaced, see the module
    docstring), labelled with its phase when it opens one."""
    if func in memo:
        return memo[func]
    py = func.py_func
    env = dict(py.__globals__)
    twin = types.FunctionType(py.__code__, env, py.__name__, py.__defaults__, py.__closure__)
    phase = PHASES.get(py.__name__)
    if phase is not None:
        inner = twin

        def twin(*args, _inner=inner, _phase=phase):
            _CALLS[_phase] = _CALLS.get(_phase, 0) + 1
            _STACK.append(_phase)
            try:
                return _inner(*args)
            finally:
                _STACK.pop()

    memo[func] = twin
    for name, value in list(env.items()):
        if isinstance(value, CPUDispatcher):
            env[name] = _twin(value, memo)
    env["np"] = _Numpy()
    return twin


def _as_flops(x):
    if isinstance(x, np.ndarray) and x.dtype == np.float64:
        out = np.empty(x.shape, dtype=object)
        out.ravel()[:] = [Flop(v) for v in x.ravel()]
        return out
    if isinstance(x, tuple) and hasattr(x, "_fields"):  # the kernel's named structures (avio/filter/interface.py)
        return type(x)(*(_as_flops(v) for v in x))
    return Flop(x) if isinstance(x, float) else x


def count_run(sequence, calibration, config=None) -> dict[str, int]:
    """FLOPs per phase of one filter (``calibration``, a batch of one) over ``sequence``, counted
    from the kernel's code (module docstring); also ``"update frames"``: the frames with a
    trifocal update, ``"frames"``, and ``"workspace bytes"``: what the kernel allocated for the
    filter (its workspaces, once per call of run_filters; float64 counted as 8 bytes). The calls
    of each phase are in ``_CALLS`` afterwards."""
    return twin_run(sequence, calibration, config)[0]


def twin_run(sequence, calibration, config=None) -> tuple[dict[str, int], dict]:
    """:func:`count_run` and the kernel's arguments by name after the twin ran (its outputs
    ``out_p`` ... hold what the counted run computed)."""
    import inspect

    from avio.filter import FilterConfig, batch, kernels, set_threads, update

    config = config or FilterConfig()
    if len(calibration) != 1:
        raise ValueError(f"count_run counts one filter, got a batch of {len(calibration)}")
    args = []

    def capture(lo, hi, *a):
        args.extend(a)

    _UPDATE_LINES.clear()
    for function, anchors in UPDATE_ANCHORS.items():
        src, first = inspect.getsourcelines(getattr(update, function).py_func)
        _UPDATE_LINES[function] = sorted((first + next(i for i, s in enumerate(src) if s.strip().startswith(anchor)),
                                          name) for anchor, name in anchors.items())
    threads, block = set_threads(1), batch._BLOCK
    old = batch._kernels.run_filters
    try:  # the per-filter kernel's call (a lock-step block does the same operations per lane)
        batch.set_block(1)
        batch._kernels.run_filters = capture
        batch.run(sequence, calibration, config)
    finally:
        batch._kernels.run_filters = old
        set_threads(threads)
        batch.set_block(block)
    _COUNT.clear()
    _CALLS.clear()
    _ALLOCATED[0] = 0
    args = [_as_flops(a) for a in args]
    _twin(kernels.run_filters, {})(0, 1, *args)
    out = dict(_COUNT)
    out["update frames"] = _CALLS.get("update, selection", 0)
    out["frames"] = sequence.n_frames
    out["workspace bytes"] = _ALLOCATED[0]
    names = list(inspect.signature(kernels.run_filters.py_func).parameters)[2:]
    return out, dict(zip(names, args, strict=True))

def main(argv=None) -> None:
    """Count the kernel's FLOPs per phase on a short noise-free circle drive (the tests' drive) at
    each --features, per call of the phase, beside :func:`per_update_frame`."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--features", type=int, nargs="+", default=[4, 8, 12])
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "avio" / "filter"))
    from test_filter import make_circle_sequence

    from avio.filter import FilterConfig

    seq = make_circle_sequence(args.frames, seed=3, pixel_noise_px=0.0, n_feat=30)
    for F in args.features:
        counted = count_run(seq, seq.truth_calibration, FilterConfig(max_update_features=F))
        calls = dict(_CALLS)
        model = per_update_frame(F)
        print(f"F = {F}: {counted['update frames']} update frames of {counted['frames']}")
        for phase, n in counted.items():
            if phase in model:
                per_call = n / (calls.get(phase) or calls["update, selection"])  # steps of update's body: per update
                print(f"  {phase:24s} {per_call:10.1f} per call   constants: {model[phase]}")
        print(f"  one update frame: {sum(model.values())} FLOPs by the constants; workspace of one filter "
              f"{counted['workspace bytes']} bytes")


if __name__ == "__main__":
    main()
