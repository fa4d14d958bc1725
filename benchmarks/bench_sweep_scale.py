"""Preflight of a large sweep: CPU and wall seconds to validate N jobs of sphere x 6 optimisers (issue 34).

    python benchmarks/bench_sweep_scale.py --jobs 600      # 6 optimisers x 100 seeds

Prints one line: jobs, wall s, CPU s, ms per job. Nothing is run or written but a temporary folder.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.run.preflight import plan

OPTIMIZERS = "psoga,pso,ga,cmaes,tpe,random"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=600, help="jobs in all (a multiple of 6)")
    parser.add_argument("--evals", type=int, default=20)
    args = parser.parse_args()
    seeds = max(1, args.jobs // 6)
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["problem=sphere", f"optimizer={OPTIMIZERS}", f"instance=range({seeds})", f"budget.evals={args.evals}",
                f"hydra.sweep.dir={tmp}/s"]
        wall0, cpu0 = time.perf_counter(), time.process_time()
        result = plan(argv)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    print(f"preflight: {result.n_jobs} jobs, wall {wall:.1f} s, CPU {cpu:.1f} s, "
          f"{1000 * cpu / result.n_jobs:.1f} ms CPU per job")


if __name__ == "__main__":
    main()
