"""Where the filter's first-run compile goes: numba's compile events of one cold run, per function,
exclusive (the function's own typing, lowering, LLVM optimisation and code generation, which include
re-optimising and re-generating the code of every callee linked into it) and inclusive (its callees'
compiles too).

    python benchmarks/kernel/compile_profile.py [--block 1|2|4|8] [--batch N] [--top 25] [--cache DIR]

Runs kitti00 frames 15-60 once with an empty numba cache (a temporary folder unless ``--cache``
names one: a second run into the same folder shows what the other kernel adds once the shared stages
are cached). ``--block 1`` (a batch of 1 by default) compiles numba's per-filter kernel, 2, 4 or 8 the
lock-step kernel (a batch of 8 by default).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--block", type=int, default=1, choices=(1, 2, 4, 8))
    p.add_argument("--batch", type=int, help="calibrations (default 1 for --block 1, else 8)")
    p.add_argument("--top", type=int, default=25)
    p.add_argument("--cache", help="numba cache folder (default: a new temporary one)")
    p.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    args = p.parse_args(argv)
    cache = args.cache or tempfile.mkdtemp(prefix="avio_compile_")
    os.environ["NUMBA_CACHE_DIR"] = cache  # read when numba is imported, below
    sys.path.insert(0, str(REPO))
    from numba.core import event

    from avio.datasets.kitti00 import load_kitti00
    from avio.filter import FilterConfig, prepare, run
    from avio.filter.batch import set_block

    set_block(args.block)
    n = args.batch or (1 if args.block == 1 else 8)
    seq = load_kitti00(str(Path(args.data) / "kitti00"), 15, 60, seed=0)
    cal = seq.truth_calibration.repeat(n) if n > 1 else seq.truth_calibration
    prep = prepare(seq, FilterConfig())
    stack, done = [], []

    class Timer(event.Listener):
        def on_start(self, ev):
            stack.append([ev.data["dispatcher"].py_func.__qualname__, time.perf_counter(), 0.0])

        def on_end(self, ev):
            name, t0, inner = stack.pop()
            took = time.perf_counter() - t0
            if stack:
                stack[-1][2] += took
            done.append((name, took - inner, took))

    event.register("numba:compile", Timer())
    t0 = time.perf_counter()
    run(seq, cal, FilterConfig(), prep)
    wall = time.perf_counter() - t0
    print(f"block {args.block}, batch {n}: first run {wall:.1f} s wall (cache {cache}); "
          f"{len(done)} numba compiles, {sum(d[1] for d in done):.1f} s in all")
    print(f"{'exclusive s':>12} {'inclusive s':>12}  function")
    for name, own, took in sorted(done, key=lambda d: -d[1])[:args.top]:
        print(f"{own:12.2f} {took:12.2f}  {name}")


if __name__ == "__main__":
    main()
