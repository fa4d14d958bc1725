"""Where the filter kernel's time goes: the cost of each phase of a frame, measured by running
that phase twice (issue 13's side-by-side profile).

    python benchmarks/profile_kernel.py [--batch 16] [--rounds 7] [--data ../shared/data]

Why this way: numba's compiled code carries no symbols that ``perf`` can resolve, and timers
cannot be called inside a nopython kernel. So the script copies ``avio/`` into a temporary
folder, wraps each phase of the kernel (the update in avio/filter/update.py, the prediction and
the slide in avio/filter/kernels.py) in ``for _q in range(rep[i])`` (``rep`` a new argument,
passed down from avio/filter/batch.py; all ones = the unchanged kernel), compiles that copy once (empty NUMBA_CACHE_DIR,
~40 s) and times the kitti00 15-796 batch with one phase doubled at a time, all variants
interleaved: every round runs them in a new random order, each right after a baseline run. The
cost of a phase is the median over the rounds of its time minus that of the baseline run just
before it. Phases that change the state cannot simply
run twice: the covariance prediction and the window slide run once more on a scratch copy
(the copy, 729 numbers, is counted with them), the downdate runs -K, +K, -K (three times:
half the difference is its cost). Results of the doubled runs are not used.

The edits are anchored on the kernel's source text; when the kernel changes, an anchor that is
no longer found is an error naming it and its file (update PATCHES below).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PHASES = ("measurement (residuals, Jacobians)", "C P, Sigma = C P C^T", "feature innovations (B, S_j, z_j)",
          "1-point RANSAC", "information sum (whitening, A, beta)", "gain K = P C^T X", "covariance downdate",
          "state prediction", "covariance prediction", "window slide", "NIS / log det S / NLL statistics",
          "residual rows, finiteness, noise model R_f", "(I + A Sigma)^-1 [A | beta] solve")


def _indent(block: str, by: str = "    ") -> str:
    return "".join(by + line + "\n" if line else "\n" for line in block.rstrip("\n").split("\n"))


def _wrap(src: str, start: str, end: str | None, i: int, where: str = "avio/filter/update.py") -> str:
    """Wrap the lines from anchor ``start`` up to anchor ``end`` (None: the end of the file) in
    ``for _q in range(rep[i])``."""
    a = _find(src, start, where=where)
    b = len(src) if end is None else _find(src, end, a + 1, where=where)
    block = src[a:b]
    head = block[:len(block) - len(block.lstrip(" "))]
    return src[:a] + f"{head}for _q in range(rep[{i}]):\n" + _indent(block) + src[b:]


def _find(src: str, anchor: str, after: int = 0, where: str = "avio/filter/update.py") -> int:
    at = src.find(anchor, after)
    if at < 0:
        raise SystemExit(f"profile_kernel: anchor not found in {where} (the kernel changed; update "
                         f"benchmarks/profile_kernel.py): {anchor.strip()[:80]!r}")
    return at


def _replace(src: str, old: str, new: str, where: str = "avio/filter/update.py") -> str:
    _find(src, old, where=where)
    return src.replace(old, new, 1)


def patch_update(src: str) -> str:
    """avio/filter/update.py with every phase of the update wrapped in a repeat loop (module docstring):
    update() and its stages take ``rep``."""
    src = _replace(src, "cfg, ws, record, decided):", "cfg, ws, record, decided, rep):")
    # the stages' calls in update() and their definitions: (text, times it occurs)
    for text, times in (("update_measure(x, omega, cal, i, uv, valid, cfg, ws", 2),
                        ("update_information(valid, cfg, ws, record, decided", 2),
                        ("downdate(x.P, u_.PCt, u_.X, u_.CP, u_.K", 1), ("def downdate(P, PCt, X, CP, K", 1)):
        for _ in range(times):
            src = _replace(src, f"{text})", f"{text}, rep)")
    src = _wrap(src, "    project(u_.C, x.P", "    used, rr, log_det_R, nll = update_information(", 1)
    # the solve overwrites Mx and X: each extra pass rebuilds them from A, Sigma and beta first
    src = _replace(src, "    solve(u_.Mx, u_.X)",
                   "    for _q in range(rep[12] - 1):\n        matmul(u_.A, u_.Sig, u_.Mx)\n        for a in range(12):\n"
                   "            u_.Mx[a, a] += 1.0\n            u_.X[a, 12] = ws.noise.beta[a]\n"
                   "            for b in range(12):\n                u_.X[a, b] = u_.A[a, b]\n"
                   "        solve(u_.Mx, u_.X)\n    solve(u_.Mx, u_.X)")
    src = _wrap(src, "    nis, log_det_S, pose_trace = update_statistics(", "    downdate(x.P", 10)
    src = _wrap(src, "    measure(x.R, x.p, x.v, x.cp0", "    # Eq. (36): without baseline", 0)
    src = _wrap(src, "    n_valid = 0\n    gain_limit2", "    return n_ok, n_valid", 11)
    src = _wrap(src, "    feature_innovations_into(", "    # The score (avio/objectives.py", 2)
    src = _wrap(src, "    nll = 0.0\n", "    if mode == MODE_RANSAC or mode == MODE_BOTH:", 10)
    src = _wrap(src, "        one_point_ransac_into(", "    if mode == MODE_GATE or mode == MODE_BOTH:", 3)
    src = _wrap(src, "    # Information form over the inliers", "    for b in range(d):\n        X[b, d] = beta[b]\n", 4)
    src = _wrap(src, "    for a in range(27):\n        for b in range(12):\n            K[a, b] = 0.0",
                "    # Each entry's 12 terms are summed in a register", 5)
    # the downdate runs -K, +K, -K (module docstring)
    src = _replace(src, "            acc -= K[a, b] * CP[b, c]\n",
                   "            acc += ((-1.0 if _q % 2 == 0 else 1.0) * K[a, b]) * CP[b, c]\n")
    return _wrap(src, "    for a in range(27):\n        n = min(27", None, 6)


def patch_kernels(src: str) -> str:
    """avio/filter/kernels.py: run_filters takes ``rep`` and passes it down to the update; the state
    prediction wrapped, the covariance prediction and the slide run again on scratch copies."""
    at = "avio/filter/kernels.py"
    src = _replace(src, "def run_filters(lo, hi, seq, cal, cfg, out):", "def run_filters(lo, hi, seq, cal, cfg, out, rep):", at)
    src = _replace(src, "record, decided)\n", "record, decided, rep)\n", at)
    # the frame loop (_run_range, which may not allocate: no slice assignment, which needs numba's
    # reference counting, so the copies go through _linalg.copy2) gets rep and the scratch copies from run_filters
    src = _replace(src, "zero_velocity_workspace(), fws)\n",
                   "zero_velocity_workspace(), fws, rep, np.empty((27, 27)), np.empty((27, 27)),\n"
                   "               np.empty((2, 3)), np.empty((2, 3, 3)))\n", at)
    src = _replace(src, "def _run_range(lo, hi, seq, cal, cfg, out, uws, pws, zws, fws):",
                   "def _run_range(lo, hi, seq, cal, cfg, out, uws, pws, zws, fws, rep, Ps, Ps2, cps, cRs):", at)
    src = _wrap(src, "                propagate_one(", "                propagate_covariance(P, Phi", 7, at)
    src = _replace(src, "                propagate_covariance(P, Phi, seq.Qd[k], Tq, U)\n",
                   "                for _q in range(rep[8] - 1):\n                    copy2(Ps, P)\n"
                   "                    propagate_covariance(Ps, Phi, seq.Qd[k], Tq, U)\n"
                   "                propagate_covariance(P, Phi, seq.Qd[k], Tq, U)\n", at)
    src = _replace(src, "            slide(R_new, p_new, v_new, omega, cal.td_s[i], cp, cR, P, R3, p3, Jsh, E, NR)\n",
                   "            for _q in range(rep[9] - 1):\n                copy2(Ps2, P)\n                copy2(cps, cp)\n"
                   "                copy2(cRs[0], cR[0])\n                copy2(cRs[1], cR[1])\n"
                   "                slide(R_new, p_new, v_new, omega, cal.td_s[i], cps, cRs, Ps2, R3, p3, Jsh, E, NR)\n"
                   "            slide(R_new, p_new, v_new, omega, cal.td_s[i], cp, cR, P, R3, p3, Jsh, E, NR)\n", at)
    return src


def patch_batch(src: str) -> str:
    """avio/filter/batch.py: a module-level REP (all ones) passed to every run_filters call."""
    at = "avio/filter/batch.py"
    src = _replace(src, "def run(sequence", f"REP = np.ones({len(PHASES)}, np.int64)\n\n\ndef run(sequence", at)
    src = _replace(src, "settings, out)", "settings, out, REP)", at)  # the one-thread call
    return _replace(src, "settings, out)", "settings, out, REP)", at)  # the threads' calls


#: file under avio/ -> its patch
PATCHES = {"filter/update.py": patch_update, "filter/kernels.py": patch_kernels, "filter/batch.py": patch_batch}


_TIMING = """import sys, time
sys.path.insert(0, {tmp!r})
import numpy as np
import avio.filter.batch as af
from avio.datasets.kitti00 import load_kitti00
from avio.filter import FilterConfig, prepare, run, set_threads
sys.path.insert(0, {scripts!r})
from bench_filter import _candidates
PHASES = {phases!r}
seq = load_kitti00({data!r}, 15, 796, seed=0)
cfg = FilterConfig(); prep = prepare(seq, cfg)
set_threads(1)
af.set_block(1)  # the patched kernel: numba's per-filter one (lock-step blocks run it per lane)
n = {batch}
cals = _candidates(seq.truth_calibration, n, seed=n)
t = time.perf_counter(); run(seq, cals, cfg, prep)
print(f"compiled the patched kernel in {{time.perf_counter() - t:.1f}} s", flush=True)
def timed(i):
    af.REP[:] = 1
    if i >= 0:
        af.REP[i] = 3 if i == 6 else 2
    t = time.perf_counter(); run(seq, cals, cfg, prep)
    return 1e3 * (time.perf_counter() - t) / n


# Each round runs the variants in a new random order, each right after a baseline run; a
# phase's cost is the median over the rounds of (variant - its baseline): the machine's slow
# drifts cancel in the pairs.
rng = np.random.default_rng(0)
diffs, bases = {{i: [] for i in range(len(PHASES))}}, []
for _ in range({rounds}):
    for i in rng.permutation(len(PHASES)):
        b = timed(-1)
        bases.append(b)
        diffs[int(i)].append(timed(int(i)) - b)
base = float(np.median(bases))
print(f"kitti00 15-796 ({{seq.n_frames}} frames), batch {{n}}, 1 thread, {rounds} rounds: {{base:.2f}} ms per "
      f"evaluation (median of the {{len(bases)}} baseline runs; quartiles {{np.percentile(bases, 25):.2f}}-"
      f"{{np.percentile(bases, 75):.2f}})")
total = 0.0
for i, name in enumerate(PHASES):
    ms = float(np.median(diffs[i])) / (2 if i == 6 else 1)
    total += ms
    print(f"  {{name:>38}}: {{ms:6.2f}} ms  {{100 * ms / base:5.1f}} %")
print(f"  {{'sum of the phases':>38}}: {{total:6.2f}} ms  {{100 * total / base:5.1f}} % (the rest: loop, copies, "
      f"outputs, zero-velocity updates, divergence tests, and the noise of the differences)")
"""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.environ.get("AVIO_DATA", str(ROOT.parent / "shared" / "data")))
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args(argv)
    kitti = Path(args.data) / "kitti00"
    if not kitti.is_dir():
        print(f"profile_kernel: no KITTI 00 data at {kitti} (--data or AVIO_DATA)", file=sys.stderr)
        raise SystemExit(2)
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(ROOT / "avio", Path(tmp) / "avio", ignore=shutil.ignore_patterns("__pycache__"))
        for name, patch in PATCHES.items():
            path = Path(tmp) / "avio" / name
            path.write_text(patch(path.read_text()))
        code = _TIMING.format(tmp=tmp, scripts=str(ROOT / "benchmarks"), phases=PHASES, data=str(kitti),
                              batch=args.batch, rounds=args.rounds)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        raise SystemExit(subprocess.run([sys.executable, "-c", code], env=env).returncode)


if __name__ == "__main__":
    main()
