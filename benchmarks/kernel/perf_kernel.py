"""Where the filter kernel's time goes, by compiled function, from Linux ``perf``: the kernel runs at
batch 64 on kitti00 frames 15-796 while ``perf record`` samples it, with a perf map of numba's JIT code
so that each sample is named by its function (numba's own ``NUMBA_ENABLE_PROFILING`` fails to compile a
function that calls a ctypes pointer, as the lock-step kernel does).

    python benchmarks/kernel/perf_kernel.py [--block 8] [--seconds 30] [--out perf.data]
    perf report -i perf.data --no-children --sort sym      # the table, as this script prints it

How the map is made: numba keeps a function's object code only when it compiles it (not when it loads
it from its cache), so the script compiles the kernel afresh into a temporary ``NUMBA_CACHE_DIR``
(~1-2 min). For every compiled function of avio.filter it reads the object's symbols (``nm``) and
places them at the address where numba loaded the code (the entry point's address less its offset),
then writes ``/tmp/perf-<pid>.map``, which ``perf report`` reads. A function's samples include the
callees LLVM inlined into it; a callee numba linked but LLVM did not inline runs from its own library
and counts under its own name. Found with it (2026-12-07): 13 % of the lock-step kernel's time went to
storing call arguments on the stack (benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _perf_map(path: str) -> int:
    """Write the perf map of every compiled function of avio.filter; returns the symbols written."""
    from numba.core.registry import CPUDispatcher

    import avio.filter

    lines, seen = [], set()
    for info in pkgutil.walk_packages(avio.filter.__path__, "avio.filter."):
        for disp in vars(importlib.import_module(info.name)).values():
            if not isinstance(disp, CPUDispatcher):
                continue
            for cres in disp.overloads.values():
                lib = cres.library
                if id(lib) in seen or lib._compiled_object is None:  # loaded from the cache: no object
                    continue
                seen.add(id(lib))
                with tempfile.NamedTemporaryFile(suffix=".o") as obj:
                    obj.write(lib._compiled_object)
                    obj.flush()
                    nm = subprocess.run(["nm", "-S", "--defined-only", obj.name], capture_output=True, text=True,
                                        check=True).stdout
                symbols = {p[3]: (int(p[0], 16), int(p[1], 16)) for p in map(str.split, nm.splitlines())
                           if len(p) == 4 and p[2] in "tTwW"}
                entry = cres.fndesc.llvm_func_name
                base = lib.get_pointer_to_function(entry) - symbols[entry][0]
                for name, (offset, size) in symbols.items():
                    short = name.split("B2v")[0].split("B3v")[0].split("B4v")[0]  # the mangled name less its ABI tags
                    lines.append(f"{base + offset:x} {size:x} {short}@{disp.py_func.__name__}")
    Path(path).write_text("\n".join(lines) + "\n")
    return len(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--block", type=int, default=8, choices=(1, 2, 4, 8), help="avio.filter.batch.set_block")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--out", default="perf.data")
    p.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    args = p.parse_args(argv)
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="avio_perf_")  # a fresh compile keeps the objects
    sys.path.insert(0, str(REPO))
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_filter import _candidates

    from avio.datasets.kitti00 import load_kitti00
    from avio.filter import FilterConfig, prepare, run, set_threads
    from avio.filter.batch import set_block

    set_threads(1)
    set_block(args.block)
    seq = load_kitti00(str(Path(args.data) / "kitti00"), 15, 796, seed=0)
    cfg = FilterConfig()
    prep = prepare(seq, cfg)
    cals = _candidates(seq.truth_calibration, 64, seed=1)
    run(seq, cals, cfg, prep)  # compiles
    n = _perf_map(f"/tmp/perf-{os.getpid()}.map")
    perf = subprocess.Popen(["perf", "record", "-q", "-F", "2000", "-o", args.out, "-p", str(os.getpid())])
    time.sleep(1.0)
    t0, runs = time.perf_counter(), 0
    while time.perf_counter() - t0 < args.seconds:
        run(seq, cals, cfg, prep)
        runs += 1
    rate = 64 * runs / (time.perf_counter() - t0)
    perf.send_signal(2)
    perf.wait()
    print(f"block {args.block}, batch 64, 1 thread: {rate:.1f} evaluations/s under perf; {n} symbols mapped")
    report = subprocess.run(["perf", "report", "-i", args.out, "--no-children", "--sort", "sym", "--stdio"],
                            capture_output=True, text=True).stdout
    rows = [line[:120] for line in report.splitlines() if line.strip() and not line.startswith("#")]
    print("\n".join(rows[:40]))


if __name__ == "__main__":
    main()
