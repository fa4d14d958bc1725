"""Median best f over seeds at a fixed evaluation budget, per analytic problem and optimiser.

Also the optimiser's own overhead: seconds per run spent inside ask() and tell() (the
evaluations themselves are excluded). Two extra studies back the defaults in conf/optimizer/:
``--stop-rules`` (psoga's paper rule vs patience) and ``--tpe-batches`` (TPE batch 1 vs 8).

    python benchmarks/bench_optimizers.py                      # all optimisers, 10 seeds, 1,000 evaluations
    python benchmarks/bench_optimizers.py --optimizers psoga cmaes --seeds 5
    python benchmarks/bench_optimizers.py --stop-rules
    python benchmarks/bench_optimizers.py --tpe-batches
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import problems
from optimizers import registry

PROBLEMS = ("sphere", "rastrigin", "rosenbrock")
DEFAULT_OPTIMIZERS = ("random", "psoga", "pso", "ga", "cmaes", "tpe", "nevergrad", "nelder_mead", "lbfgsb")


def run_once(name: str, params: dict, problem, seed: int, max_evals: int) -> tuple[float, int, float, str | None]:
    """One run: (best f, evaluations used, seconds inside the optimiser, stop reason).

    The last batch is trimmed to the budget and not told, as the harness does.
    """
    space = problem.space
    t0 = time.perf_counter()
    opt = registry.get(name)(space.lower, space.upper, seed=seed, x0=space.reference, **params)
    overhead, n_evals, best = time.perf_counter() - t0, 0, np.inf
    while n_evals < max_evals and opt.stop is None:
        t0 = time.perf_counter()
        X = opt.ask()
        overhead += time.perf_counter() - t0
        X_eval = X[: max_evals - n_evals]
        f, _ = problem.evaluate(X_eval)
        n_evals += len(X_eval)
        best = min(best, float(np.min(f)))
        if len(X_eval) == len(X):
            t0 = time.perf_counter()
            opt.tell(X, f)
            overhead += time.perf_counter() - t0
    return best, n_evals, overhead, opt.stop


def table(configs: list[tuple[str, str, dict]], seeds: int, max_evals: int) -> None:
    """Print one row per (problem, label): median best f, median evaluations, seconds per run."""
    print(f"{'problem':<11} {'optimizer':<22} {'median best f':>14} {'median evals':>12} {'s/run':>8}  stops")
    for problem_name in PROBLEMS:
        problem = problems.get(problem_name)()
        for label, name, params in configs:
            runs = [run_once(name, params, problem, s, max_evals) for s in range(seeds)]
            f, n, sec, stops = zip(*runs)
            n_stopped = sum(s is not None for s in stops)
            print(f"{problem_name:<11} {label:<22} {np.median(f):>14.4g} {np.median(n):>12.0f} "
                  f"{np.mean(sec):>8.3f}  {n_stopped}/{seeds}", flush=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--optimizers", nargs="+", default=list(DEFAULT_OPTIMIZERS))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--evals", type=int, default=1000)
    parser.add_argument("--stop-rules", action="store_true", help="psoga: paper vs patience vs no stop rule")
    parser.add_argument("--tpe-batches", action="store_true", help="tpe: batch_size 1 vs 8")
    args = parser.parse_args(argv)
    if args.stop_rules:
        configs = [(f"psoga stop_rule={r}", "psoga", {"stop_rule": r}) for r in ("paper", "patience", "none")]
    elif args.tpe_batches:
        configs = [(f"tpe batch_size={b}", "tpe", {"batch_size": b}) for b in (1, 8)]
    else:
        configs = [(name, name, {}) for name in args.optimizers]
    table(configs, args.seeds, args.evals)


if __name__ == "__main__":
    main()
