"""Where a default job's wall time goes: ``python -m bench optimizer=psoga instance=0 budget.evals=500
report=false`` run in this process with timers around a few functions of the harness, Hydra and the filter.

    python benchmarks/kernel/job_phases.py [--repeats 3] [module:Class.function ...]

For each timed function: when it was first entered (seconds from the start of this script, imports
included), how often it ran and its total wall seconds (nested functions overlap). The default set: the
preflight (the sweep's compose, the problem built with its two anchor scores, the optimiser asked once),
the problem build, Hydra's compositions, the job, its batches, the filter's ``run`` and the scoring of its
results; the end is the job's last line, before the interpreter exits. A timer costs ~1 us a call.
"""

from __future__ import annotations

import argparse
import collections
import functools
import importlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from default_job import DEFAULT_JOB

REPO = Path(__file__).resolve().parents[2]
DEFAULT = ("bench.run.preflight:preflight_plan", "bench.problems.base:build_problem",
           "hydra._internal.hydra:Hydra.compose_config", "hydra._internal.hydra:Hydra.multirun",
           "bench.run.job:run_configured_job", "bench.run.loop:_run_batches", "bench.problems.vio:run",
           "bench.problems.vio:VioProblem.score_results")


def _timed(spec: str, start: float, table: dict) -> None:
    """Replace ``module:[Class.]function`` by a wrapper that adds its calls and wall time to ``table``."""
    module, _, path = spec.partition(":")
    owner_name, _, name = path.rpartition(".")
    mod = importlib.import_module(module)
    owner = getattr(mod, owner_name) if owner_name else mod
    inner = getattr(owner, name)

    @functools.wraps(inner)
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            entry = table[spec]
            entry[0] = t - start if entry[0] is None else entry[0]
            entry[1] += 1
            entry[2] += time.perf_counter() - t

    setattr(owner, name, wrapper)


def _one(specs: list[str], sweep: str) -> None:
    start = time.perf_counter()
    sys.path.insert(0, str(REPO))
    table = collections.defaultdict(lambda: [None, 0, 0.0])
    for spec in specs:
        _timed(spec, start, table)
    from bench.__main__ import cli

    sys.argv = ["bench", *DEFAULT_JOB, f"hydra.sweep.dir={sweep}"]
    try:
        cli()
    except SystemExit:
        pass
    end = time.perf_counter() - start
    for spec, (first, calls, total) in sorted(table.items(), key=lambda kv: kv[1][0] or 0.0):
        print(f"  {spec:48s} first at {first:6.3f} s  {calls:3d} calls  {total:6.3f} s")
    print(f"  end of the job at {end:.3f} s")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("specs", nargs="*", default=list(DEFAULT), help="module:[Class.]function to time")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--one", metavar="SWEEP", help=argparse.SUPPRESS)  # one job in this process (internal)
    args = p.parse_args(argv)
    if args.one:
        _one(args.specs, args.one)
        return
    for k in range(args.repeats):  # each job in a fresh process, as a user's
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            done = subprocess.run([sys.executable, __file__, *args.specs, "--one", f"{tmp}/sweep"], cwd=REPO,
                                  capture_output=True, text=True)
            wall = time.perf_counter() - t0
        if done.returncode:
            raise SystemExit(done.stderr[-2000:])
        ours = "\n".join(line for line in done.stdout.splitlines() if line.startswith("  "))  # not the job's own
        print(f"job {k + 1}: {wall:.2f} s wall for the whole process\n{ours}", flush=True)


if __name__ == "__main__":
    main()
