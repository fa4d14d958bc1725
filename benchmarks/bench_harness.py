"""Harness overhead: wall time of a whole job against the time spent inside ``evaluate``.

    python benchmarks/bench_harness.py [--repeats 5] [--delay 0.01] [--evals 2000]

Runs the analytic sphere with a fixed delay per batch (imitating an objective that costs
``--delay`` seconds per batch) under random search (batch 32), several times, and prints the
median overhead ``wall / eval - 1``. The target is below 5%.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from bench.problems.analytic import AnalyticProblem
from bench.run.loop import Budget, run_job
from optimizers.random_search import RandomSearch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--delay", type=float, default=0.01, help="seconds per evaluate() call")
    parser.add_argument("--evals", type=int, default=2000)
    parser.add_argument("--batch", type=int, default=32)
    args = parser.parse_args()
    problem = AnalyticProblem("sphere", delay_s_per_batch=args.delay)
    overheads = []
    for repeat in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            def make():
                return RandomSearch(problem.space.lower, problem.space.upper, seed=repeat,
                                                    batch_size=args.batch)
            record = run_job(problem, make, Budget(evals=args.evals), Path(tmp) / "job",
                             {"problem": "sphere", "seed": repeat}, progress_every_s=1e9)
        overhead = record["wall_s"] / record["eval_s"] - 1.0
        overheads.append(overhead)
        print(f"run {repeat}: {record['n_batches']} batches, wall {record['wall_s']:.3f} s, "
              f"inside evaluate {record['eval_s']:.3f} s, overhead {100 * overhead:.2f}%")
    print(f"median harness overhead over {args.repeats} runs: {100 * statistics.median(overheads):.2f}% "
          f"(target < 5%)")


if __name__ == "__main__":
    main()
