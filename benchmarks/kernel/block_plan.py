"""How a batch's lock-step blocks are laid over the threads (avio.filter.batch.block_plan), timed on a
default job's batches: the default plan (near-equal shares per thread, each share's rest in a block of 2 or 4)
against consecutive blocks of 8 (``set_block(8)``, the rule before it), paired and in a new random order
each pair, with the same bits checked.

    python benchmarks/kernel/block_plan.py [--evals JOB/evals.jsonl] [--pairs 7] [--threads 2]

Without ``--evals`` it runs the default job first (``python -m bench optimizer=psoga instance=0
budget.evals=500 report=false``) and takes its batches (psoga: 25 batches of 20). Prints per plan the
median wall time of all the batches, and the median and quartiles of the per-pair ratios (blocks of 8
/ default: above 1 means the default plan is faster).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from default_job import DEFAULT_JOB

from avio.filter import set_threads
from avio.filter.batch import block_plan, set_block
from bench.problems.synthetic import Synthetic

PLANS = {"default": None, "blocks of 8": 8}


def _batches(evals: str | None) -> list[np.ndarray]:
    with tempfile.TemporaryDirectory() as tmp:
        if evals:
            path = Path(evals)
        else:
            subprocess.run([sys.executable, "-m", "bench", *DEFAULT_JOB, f"hydra.sweep.dir={tmp}/sweep"], cwd=REPO,
                           check=True, capture_output=True)
            path, = (Path(tmp) / "sweep" / "synthetic" / "psoga").glob("*/evals.jsonl")
        return [np.asarray(json.loads(line)["X"], float) for line in path.read_text().splitlines()]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--evals", help="a job's evals.jsonl (default: run the default job first)")
    p.add_argument("--pairs", type=int, default=7)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    problem = Synthetic(holdout=None, space="paper")  # the default job's problem
    cals = [problem.calibration_space.decode(problem.space.check(X)) for X in _batches(args.evals)]
    set_threads(args.threads)
    n = len(cals[0])
    print(f"{len(cals)} batches of {n} on {args.threads} threads; default plan {block_plan(n, args.threads)}")
    rng = np.random.default_rng(0)
    walls = {k: [] for k in PLANS}
    bits = {}
    for rep in range(args.pairs + 1):  # the first round compiles or loads the kernels: not timed
        for name in rng.permutation(list(PLANS)):
            set_block(PLANS[name])
            t0 = time.perf_counter()
            fs = [problem.score(c)[0] for c in cals]  # a job's evaluations: the filter on every drive
            if rep:
                walls[name].append(time.perf_counter() - t0)
            bits[name] = b"".join(f.tobytes() for f in fs)
    set_block(None)
    set_threads(None)
    ratio = np.array(walls["blocks of 8"]) / np.array(walls["default"])
    q1, med, q3 = np.percentile(ratio, [25, 50, 75])
    print(", ".join(f"{k}: {np.median(v):.3f} s" for k, v in walls.items())
          + f"; blocks of 8 / default per pair: median {med:.3f}x (quartiles {q1:.3f}-{q3:.3f}, {args.pairs} pairs); "
          f"same bits: {bits['default'] == bits['blocks of 8']}")


if __name__ == "__main__":
    main()
