"""A default job at two commits, side by side: wall and CPU seconds of ``python -m bench optimizer=psoga
instance=0 budget.evals=500 report=false`` (issue 30's "default job"), the base commit's tree and the working
tree alternately, in a new order each pair, so both see the same machine (a shared 2-vCPU machine's speed
drifts by 20 % within minutes; a ratio per pair does not).

    python benchmarks/kernel/ab_job.py [--base 5493c7b] [--pairs 9] [--keep DIR]

The base's files (``git archive``) are unpacked into a temporary folder (``--keep DIR``: that folder, kept,
with its numba cache) and its job runs there, so it imports its own ``avio`` and ``bench``; a first
untimed job per tree loads, or compiles, its kernels. Prints each tree's median wall and CPU (user + system)
seconds and the medians and quartiles of the per-pair ratios base / working tree (above 1: the working tree
is faster); with ``--cold``, one job per tree first with an empty numba cache, timed.
"""

from __future__ import annotations

import argparse
import io
import os
import random
import resource
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
from default_job import DEFAULT_JOB

REPO = Path(__file__).resolve().parents[2]


def _unpack(commit: str, into: Path) -> None:
    tar = subprocess.run(["git", "archive", commit], cwd=REPO, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as archive:
        archive.extractall(into, filter="data")


def _job(tree: Path, env: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of one default job run in ``tree``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "bench", *DEFAULT_JOB, f"hydra.sweep.dir={out}/sweep"], cwd=tree,
                              capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
    if done.returncode:
        raise SystemExit(f"the job failed in {tree}:\n{done.stderr[-2000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _quartiles(x) -> str:
    q1, med, q3 = np.percentile(x, [25, 50, 75])
    return f"{med:.3f}x ({q1:.3f}-{q3:.3f})"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--base", default="HEAD")
    p.add_argument("--pairs", type=int, default=9)
    p.add_argument("--keep", help="unpack the base here and keep it (with its numba cache) for the next run")
    p.add_argument("--cold", action="store_true", help="first one job per tree with an empty numba cache")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(args.keep) if args.keep else Path(tmp) / "base"
        if not (base / "bench").is_dir():
            base.mkdir(parents=True, exist_ok=True)
            _unpack(args.base, base)
        trees = {"base": base, "tree": REPO}
        if args.cold:
            for name, tree in trees.items():
                with tempfile.TemporaryDirectory() as cache:
                    wall, cpu = _job(tree, dict(os.environ, NUMBA_CACHE_DIR=cache))
                print(f"{name}: cold job (empty NUMBA_CACHE_DIR, the C built too) {wall:.1f} s wall, {cpu:.1f} s CPU",
                      flush=True)
        for tree in trees.values():
            _job(tree)  # loads (or compiles) the kernels: not timed
        runs = {name: [] for name in trees}
        rng = random.Random(0)
        for _ in range(args.pairs):
            for name in rng.sample(list(trees), 2):
                runs[name].append(_job(trees[name]))
    b, t = np.array(runs["base"]), np.array(runs["tree"])
    for name, r in (("base " + args.base, b), ("working tree", t)):
        print(f"{name}: wall median {np.median(r[:, 0]):.2f} s ({', '.join(f'{w:.2f}' for w in r[:, 0])}); "
              f"CPU median {np.median(r[:, 1]):.2f} s")
    print(f"base / working tree, per pair ({args.pairs} pairs): wall {_quartiles(b[:, 0] / t[:, 0])}, "
          f"CPU {_quartiles(b[:, 1] / t[:, 1])}; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
