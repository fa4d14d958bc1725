"""Accuracy and speed figures of the batched trifocal VIO filter (avio/filter/).

    python benchmarks/bench_filter.py accuracy [--seeds 0 1 2] [--set key=value ...]
    python benchmarks/bench_filter.py outliers [--seeds 0 1 2]
    python benchmarks/bench_filter.py speed [--batches 1 8 64 256] [--threads 1 2] [--repeats 5]
                                         [--skip scaling harness job compile]
    python benchmarks/bench_filter.py profile [--batch 64]
    python benchmarks/bench_filter.py schedule [--evals JOB/evals.jsonl]

accuracy: position/velocity/attitude RMSE, mean, std (avio.metrics) with the truth calibration
    on the simulated paper drives (avio.sim.simulator, SimConfig.paper_540m / paper_928m) and on the
    kitti00 windows (real IMU, simulated camera; frames 15–796 and 2404–3553), one line per seed.
outliers: the same for each outlier_rejection mode (how the default was chosen).
speed: complete evaluations per second on kitti00 frames 15–796 (782 frames) for each batch
    size and kernel thread count (the same 64 calibrations, an optimiser-like population around
    the truth, in batches of each size up to 64; avio.filter.set_threads; median of --repeats runs, wall and
    process CPU; the calibration-independent preparation and the first call's numba cache load
    excluded and reported separately), the per-evaluation gain of batch 64 on all threads over
    batch 1 on one, the peak memory, a scaling line (ms per evaluation against frames and
    features per update), the harness overhead (benchmarks/bench_harness.py), the default job's
    wall time (psoga, 500 evaluations on ``synthetic``) and the first-run compile time (a
    subprocess with an empty NUMBA_CACHE_DIR).
profile: cProfile of one batch, top functions by own time.
schedule: how the batch is split over two threads: the batches a default job asked (psoga instance 0
    on ``synthetic``, run first unless --evals names a job's evals.jsonl) replayed filter by
    filter on one thread, and the two-thread time each split would take from those times (one
    task per filter, as avio.filter runs them; four contiguous ranges per thread, as it did),
    beside the ideal and the measured two-thread time.
The data folder is --data (default ../shared/data relative to the repository root).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from flops import per_evaluation, rate_line
from kernel.default_job import DEFAULT_JOB

from avio.calibration import Calibration
from avio.filter.batch import run, set_threads
from avio.filter.config import FilterConfig
from avio.filter.prepare import prepare
from avio.geometry import so3_exp
from avio.metrics import pose_errors


def _sequences(names, seed, data_dir):
    for name in names:
        if name.startswith("sim"):
            from avio.sim.simulator import SimConfig, simulate

            cfg = SimConfig.paper_540m() if name == "sim540" else SimConfig.paper_928m()
            yield name, simulate(cfg, seed)
        else:
            from avio.datasets.kitti00 import WINDOWS, load_kitti00

            first, last = WINDOWS["paper_540m" if name == "kitti540" else "paper_928m"]
            yield name, load_kitti00(Path(data_dir) / "kitti00", first, last, seed=seed)


def _parse_set(items) -> dict:
    out = {}
    for item in items or []:
        k, v = item.split("=", 1)
        out[k] = type(getattr(FilterConfig(), k))(v) if not isinstance(getattr(FilterConfig(), k), bool) \
            else v.lower() in ("1", "true", "yes")
    return out


def accuracy(args, config: FilterConfig, label: str = "") -> dict:
    rows = {}
    for seed in args.seeds:
        for name, seq in _sequences(args.sequences, seed, args.data):
            res = run(seq, seq.truth_calibration, config)
            e = pose_errors(res, seq.truth)
            rows.setdefault(name, []).append(e["position_rmse"][0])
            print(f"{label}{name:9s} seed {seed}: {seq.n_frames} frames {seq.path_length_m():6.0f} m | "
                  + " | ".join(f"{q[:3]} rmse {e[q + '_rmse'][0]:7.3f} mean {e[q + '_mean'][0]:7.3f} "
                               f"std {e[q + '_std'][0]:7.3f}" for q in ("position", "velocity", "attitude"))
                  + f" | diverged {bool(res.diverged[0])}", flush=True)
    for name, v in rows.items():
        print(f"{label}{name:9s} position RMSE over {len(v)} seeds: median {np.median(v):.3f} m, "
              f"mean {np.mean(v):.3f} m, max {np.max(v):.3f} m", flush=True)
    return rows


def _candidates(cal: Calibration, n: int, seed: int) -> Calibration:
    """n calibrations spread like an optimiser's population around ``cal``."""
    rng = np.random.default_rng(seed)
    out = cal.repeat(n)
    return Calibration(
        fx_px=out.fx_px + rng.normal(0, 5, n), fy_px=out.fy_px + rng.normal(0, 5, n),
        cx_px=out.cx_px + rng.normal(0, 5, n), cy_px=out.cy_px + rng.normal(0, 5, n),
        R_cam_imu=so3_exp(rng.normal(0, 0.01, (n, 3))) @ out.R_cam_imu,
        p_imu_cam_m=out.p_imu_cam_m + rng.normal(0, 0.05, (n, 3)),
        time_offset_s=np.zeros(n),
    )


def _kitti(args, first=15, last=796):
    from avio.datasets.kitti00 import load_kitti00

    return load_kitti00(Path(args.data) / "kitti00", first, last, seed=0)


def _time_batch(seq, batches, config, prep, repeats):
    """Median wall and process-CPU seconds of ``repeats`` runs of the batches (Calibration each),
    one after the other."""
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        for cals in batches:
            run(seq, cals, config, prep)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)), float(np.median(cpu))


#: Every batch size up to this one evaluates the same calibrations (in batches of its size), so
#: that the per-evaluation times compare batching, not the cost of different calibrations (a
#: filter whose calibration loses features or diverges costs less).
SAME_WORK = 64


def _subprocess_s(cmd, env=None, cwd=REPO):
    """Wall seconds of a command (its output kept for the error message)."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr[-2000:]}")
    return time.perf_counter() - t0, done


_COLD = """import sys, time
sys.path.insert(0, {repo!r})
from avio.filter import FilterConfig, prepare, run
from avio.datasets.kitti00 import load_kitti00
seq = load_kitti00({data!r}, 15, 60, seed=0)
prep = prepare(seq, FilterConfig())
t0 = time.perf_counter()
run(seq, seq.truth_calibration, FilterConfig(), prep)
print(f"{{time.perf_counter() - t0:.2f}}")
"""


@numba.njit(nogil=True)
def _burn(n):
    s = 0.0
    for i in range(n):
        s += np.sin(i * 1e-3)
    return s


def _thread_ceiling(n=20_000_000) -> float:
    """Speed-up of two threads over one on pure arithmetic now: what the machine's load leaves
    for the filter's threads (2.0 on two idle cores)."""
    from concurrent.futures import ThreadPoolExecutor

    _burn(10)
    t0 = time.perf_counter()
    _burn(n)
    _burn(n)
    serial = time.perf_counter() - t0
    with ThreadPoolExecutor(2) as pool:
        t0 = time.perf_counter()
        list(pool.map(_burn, [n, n]))
        return serial / (time.perf_counter() - t0)


def speed(args, config: FilterConfig) -> None:
    """Evaluations/s on kitti00 15-796 per batch size and thread count, the batching gain, memory,
    scaling in frames and features, the harness overhead, the default job and the cold compile."""
    seq = _kitti(args)
    t0 = time.perf_counter()
    prep = prepare(seq, config)
    t_prep = time.perf_counter() - t0
    print(f"kitti00 15-796: {seq.n_frames} frames, {seq.tracks.n_features.mean():.1f} tracked features per "
          f"triplet, {prep.valid.sum(1).mean():.1f} used per update; prepare() {t_prep:.2f} s (once per sequence)")
    print(f"machine: {os.cpu_count()} cores, numba {numba.__version__}, NUMBA_NUM_THREADS "
          f"{numba.config.NUMBA_NUM_THREADS}, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    t0 = time.perf_counter()
    run(seq, _candidates(seq.truth_calibration, 2, seed=0), config, prep)
    print(f"first call (numba cache load, or compile on a cold cache): {time.perf_counter() - t0:.2f} s", flush=True)
    print(f"2-thread ceiling now (a pure numba nogil loop, 2 threads vs 1): {_thread_ceiling():.2f}x", flush=True)
    # Thread counts interleaved run by run, so that they see the same machine load.
    for n_threads in args.threads:
        set_threads(n_threads)
        run(seq, _candidates(seq.truth_calibration, 2, seed=0), config, prep)  # starts the threads
    per_eval = {}
    pool = _candidates(seq.truth_calibration, max(max(args.batches), SAME_WORK), seed=0)
    print(f"every batch size up to {SAME_WORK} evaluates the same {SAME_WORK} calibrations (larger ones the "
          f"first n of the same draw)", flush=True)
    flop = per_evaluation(run(seq, pool[:SAME_WORK], config, prep), config.max_update_features)
    print(f"{flop / 1e6:.1f} MFLOP per evaluation (benchmarks/flops.py: counted from the code)", flush=True)
    work = {n: max(n, SAME_WORK) for n in args.batches}
    batches = {n: [pool[i:min(i + n, work[n])] for i in range(0, work[n], n)] for n in args.batches}
    walls = {(t, n): [] for n in args.batches for t in args.threads}
    cpus = {key: [] for key in walls}
    # Batch sizes and thread counts interleaved within each repeat: this VM's speed drifts by tens
    # of percent within a minute, so only measurements taken side by side compare.
    for _ in range(args.repeats):
        for n in args.batches:
            for n_threads in args.threads:
                set_threads(n_threads)
                wall, cpu = _time_batch(seq, batches[n], config, prep, 1)
                walls[n_threads, n].append(wall / work[n])
                cpus[n_threads, n].append(cpu / work[n])
    for n in args.batches:
        for n_threads in args.threads:
            wall, cpu = float(np.median(walls[n_threads, n])), float(np.median(cpus[n_threads, n]))
            per_eval[n_threads, n] = np.array(walls[n_threads, n])
            print(f"threads {n_threads} batch {n:4d}: {1 / wall:7.1f} evaluations/s ({1e3 * wall:6.2f} ms "
                  f"per evaluation, CPU {1e3 * cpu:6.2f} ms; median of {args.repeats}, {len(batches[n])} "
                  f"batch(es) of {work[n]} evaluations); {rate_line(flop, cpu)}", flush=True)
    print(f"  load average {os.getloadavg()[0]:.2f}", flush=True)
    set_threads(None)
    t_lo, t_hi = min(args.threads), max(args.threads)
    if (t_lo, 1) in per_eval and (t_hi, 64) in per_eval:
        def paired(a, b):  # median and range of the per-repeat ratios
            r = per_eval[a] / per_eval[b]
            return f"{np.median(r):.2f}x ({r.min():.2f}-{r.max():.2f})"

        # per repeat the first ratio is the product of the other two: what batching buys one thread, and the threads
        print(f"batch 64 x {t_hi} threads vs batch 1 x {t_lo} thread, per evaluation, paired by repeat: "
              f"{paired((t_lo, 1), (t_hi, 64))}; batch 64 vs batch 1 at {t_lo} thread: "
              f"{paired((t_lo, 1), (t_lo, 64))}; batch 64 at {t_hi} vs {t_lo} thread: "
              f"{paired((t_lo, 64), (t_hi, 64))}", flush=True)
    n = args.memory_batch
    tracemalloc.start()
    run(seq, _candidates(seq.truth_calibration, n, seed=1), config, prep)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak traced numpy/python memory at batch {n}: {peak / 2**20:.1f} MiB; process max RSS {rss:.0f} MiB",
          flush=True)
    if "scaling" not in args.skip:
        _scaling(args, config)
    if "harness" not in args.skip:
        harness = REPO / "benchmarks" / "bench_harness.py"
        _, done = _subprocess_s([sys.executable, str(harness), "--repeats", str(args.repeats)])
        print(f"harness overhead (benchmarks/bench_harness.py): {done.stdout.strip().splitlines()[-1]}", flush=True)
    if "job" not in args.skip:
        walls = []
        for i in range(args.job_repeats):
            with tempfile.TemporaryDirectory() as tmp:
                walls.append(_subprocess_s([sys.executable, "-m", "bench", *DEFAULT_JOB, f"hydra.sweep.dir={tmp}/sweep"])[0])
        print(f"default job (python -m bench {' '.join(DEFAULT_JOB)}, synthetic, "
              f"kernel cached): {np.median(walls):.1f} s wall (median of {len(walls)}: "
              f"{', '.join(f'{w:.1f}' for w in walls)})", flush=True)
    if "compile" not in args.skip:
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            code = _COLD.format(repo=str(REPO), data=str(Path(args.data) / "kitti00"))
            wall, done = _subprocess_s([sys.executable, "-c", code], env=env)
        print(f"first-run compile (empty NUMBA_CACHE_DIR, one short run): {float(done.stdout.split()[-1]):.1f} s "
              f"in the kernel call, {wall:.1f} s for the whole process; load average {os.getloadavg()[0]:.2f}",
              flush=True)
    print(f"load average at end {os.getloadavg()[0]:.2f}")


def _scaling(args, config: FilterConfig, lasts=(114, 214, 414, 796), features=(8, 16, 24), n: int = 64) -> None:
    """ms per evaluation at batch n (default threads) against frames (kitti00 from frame 15 to
    each of ``lasts``) and, on the last window, against the features per update."""
    reps = max(3, args.repeats // 2)
    cals = None
    parts = []
    for last in lasts:
        seq = _kitti(args, 15, last)
        cals = _candidates(seq.truth_calibration, n, seed=n)
        wall, _ = _time_batch(seq, [cals], config, prepare(seq, config), reps)
        parts.append(f"{seq.n_frames} frames {1e3 * wall / n:.2f}")
    print(f"scaling, batch {n}, ms per evaluation: " + ", ".join(parts), flush=True)
    parts = []
    for F in features:
        cfg = replace(config, max_update_features=F)
        prep = prepare(seq, cfg)
        wall, _ = _time_batch(seq, [cals], cfg, prep, reps)
        parts.append(f"<= {F} features ({prep.valid.sum(1).mean():.1f} used) {1e3 * wall / n:.2f}")
    print(f"scaling, batch {n}, {seq.n_frames} frames, ms per evaluation: " + ", ".join(parts), flush=True)


def profile(args, config: FilterConfig) -> None:
    from avio.datasets.kitti00 import load_kitti00

    seq = load_kitti00(Path(args.data) / "kitti00", 15, 796, seed=0)
    prep = prepare(seq, config)
    cals = _candidates(seq.truth_calibration, args.batch, seed=0)
    prof = cProfile.Profile()
    prof.runcall(run, seq, cals, config, prep)
    pstats.Stats(prof).sort_stats("tottime").print_stats(20)


def _makespan(costs, bounds, n_threads: int = 2) -> float:
    """Wall time of tasks [bounds[i], bounds[i+1]) taken in order by whichever thread is free."""
    import heapq

    free = [0.0] * n_threads
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        heapq.heappush(free, heapq.heappop(free) + sum(costs[lo:hi]))
    return max(free)


#: One job of the default problem at issue 30's size (psoga, instance 0, 500 evaluations), not the
#: default sweep (python -m bench alone runs 12 instances x 6 optimisers since the design of
#: docs/guide/verdicts.md); the same command as benchmarks/README.md's default-job rows.


def schedule(args) -> None:
    import json

    from bench.problems.synthetic import Synthetic

    with tempfile.TemporaryDirectory() as tmp:
        if args.evals:
            path = Path(args.evals)
        else:
            _subprocess_s([sys.executable, "-m", "bench", *DEFAULT_JOB, f"hydra.sweep.dir={tmp}/sweep"])
            path, = (Path(tmp) / "sweep" / "synthetic" / "psoga").glob("*/evals.jsonl")
        batches = [np.asarray(json.loads(line)["X"], float) for line in path.read_text().splitlines()]
    problem = Synthetic(holdout=None, space="paper", filter=_parse_set(args.set) or None)  # the default job's problem
    totals = dict.fromkeys(("one filter", "one task per filter", "four ranges per thread", "ideal", "measured"), 0.0)
    for X in batches:
        cal = problem.calibration_space.decode(problem.space.check(X))
        set_threads(1)
        costs = []
        for i in range(len(X)):
            t0 = time.perf_counter()
            problem.run_filter(cal[i:i + 1])
            costs.append(time.perf_counter() - t0)
        n, k = len(costs), min(len(costs), 8)
        totals["one filter"] += sum(costs)
        totals["one task per filter"] += _makespan(costs, range(n + 1))
        totals["four ranges per thread"] += _makespan(costs, [i * n // k for i in range(k + 1)])
        totals["ideal"] += max(sum(costs) / 2, max(costs))
        set_threads(2)
        t0 = time.perf_counter()
        problem.run_filter(cal)
        totals["measured"] += time.perf_counter() - t0
    set_threads(None)
    print(f"default job's {len(batches)} batches of {len(batches[0])} (psoga instance 0, synthetic): one filter at a time "
          f"{totals['one filter']:.2f} s; on 2 threads, from those times: one task per filter (avio.filter) "
          f"{totals['one task per filter']:.2f} s, four ranges per thread {totals['four ranges per thread']:.2f} s "
          f"({totals['four ranges per thread'] / totals['one task per filter']:.3f}x), ideal {totals['ideal']:.2f} s; "
          f"measured on 2 threads {totals['measured']:.2f} s")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=("accuracy", "outliers", "speed", "profile", "schedule"))
    p.add_argument("--evals", help="schedule: a job's evals.jsonl (default: run the default job first)")
    p.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--sequences", nargs="+", default=["sim540", "kitti540", "sim928", "kitti928"])
    p.add_argument("--batches", type=int, nargs="+", default=[1, 8, 64, 256])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--job-repeats", type=int, default=3)
    p.add_argument("--skip", nargs="*", default=[], choices=("scaling", "harness", "job", "compile"),
                   help="speed: parts not to run")
    p.add_argument("--memory-batch", type=int, default=64)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--set", nargs="*", help="FilterConfig overrides, key=value")
    args = p.parse_args(argv)
    config = replace(FilterConfig(), **_parse_set(args.set))
    print(f"FilterConfig: {config}")
    if args.what == "accuracy":
        accuracy(args, config)
    elif args.what == "outliers":
        for mode in ("both", "ransac", "mahalanobis", "none"):
            accuracy(args, replace(config, outlier_rejection=mode), label=f"[{mode:11s}] ")
    elif args.what == "speed":
        speed(args, config)
    elif args.what == "schedule":
        schedule(args)
    else:
        profile(args, config)


if __name__ == "__main__":
    main()
