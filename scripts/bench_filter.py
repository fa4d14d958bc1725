"""Accuracy and speed figures of the batched trifocal VIO filter (avio/filter.py).

    python scripts/bench_filter.py accuracy [--seeds 0 1 2] [--set key=value ...]
    python scripts/bench_filter.py outliers [--seeds 0 1 2]
    python scripts/bench_filter.py speed [--batches 1 8 32 64 128] [--repeats 3]
    python scripts/bench_filter.py profile [--batch 64]

accuracy: position/velocity/attitude RMSE, mean, std (avio.metrics) with the truth calibration
    on the simulated paper drives (avio.simulator, SimConfig.paper_540m / paper_928m) and on the
    kitti00 windows (real IMU, simulated camera; frames 15–796 and 2404–3553), one line per seed.
outliers: the same for each outlier_rejection mode (how the default was chosen).
speed: complete evaluations per second on kitti00 frames 15–796 (782 frames) for each batch
    size (median of --repeats runs, the calibration-independent preparation and the first
    call's numba compile/cache load excluded and reported separately), the speed-up per
    evaluation over batch 1, and the peak memory.
profile: cProfile of one batch, top functions by own time.
The data folder is --data (default ../shared/data relative to the repository root).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from avio.filter import FilterConfig, prepare, run  # noqa: E402
from avio.geometry import so3_exp  # noqa: E402
from avio.metrics import pose_errors  # noqa: E402
from avio.sequence import Calibration  # noqa: E402


def _sequences(names, seed, data_dir):
    for name in names:
        if name.startswith("sim"):
            from avio.simulator import SimConfig, simulate

            cfg = SimConfig.paper_540m() if name == "sim540" else SimConfig.paper_928m()
            yield name, simulate(cfg, seed)
        else:
            from avio.kitti00 import WINDOWS, load_kitti00

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


def speed(args, config: FilterConfig) -> None:
    from avio.kitti00 import load_kitti00

    seq = load_kitti00(Path(args.data) / "kitti00", 15, 796, seed=0)
    t0 = time.perf_counter()
    prep = prepare(seq, config)
    t_prep = time.perf_counter() - t0
    print(f"kitti00 15-796: {seq.n_frames} frames, {seq.tracks.n_features.mean():.1f} tracked features per "
          f"triplet, {int(prep.valid.sum(1).mean())} used per update; prepare() {t_prep:.2f} s (once per sequence)")
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start")
    # The filter is a numba kernel: the first call in a process compiles it (no cache yet,
    # ~25 s on this machine) or loads it from avio/__pycache__ (~1 s); not part of the figures.
    t0 = time.perf_counter()
    run(seq, _candidates(seq.truth_calibration, 1, seed=0), config, prep)
    print(f"first call (numba compile or cache load): {time.perf_counter() - t0:.2f} s")
    per_eval = {}
    for n in args.batches:
        cals = _candidates(seq.truth_calibration, n, seed=n)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            run(seq, cals, config, prep)
            times.append(time.perf_counter() - t0)
        t = float(np.median(times))
        per_eval[n] = t / n
        print(f"batch {n:4d}: {t:7.3f} s per batch (median of {args.repeats}), {n / t:8.1f} evaluations/s, "
              f"speed-up per evaluation over batch 1: {per_eval[args.batches[0]] / per_eval[n]:6.1f}x", flush=True)
    n = args.memory_batch
    tracemalloc.start()
    run(seq, _candidates(seq.truth_calibration, n, seed=1), config, prep)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak traced numpy/python memory at batch {n}: {peak / 2**20:.1f} MiB; process max RSS {rss:.0f} MiB")
    print(f"load average at end {os.getloadavg()[0]:.2f}")


def profile(args, config: FilterConfig) -> None:
    from avio.kitti00 import load_kitti00

    seq = load_kitti00(Path(args.data) / "kitti00", 15, 796, seed=0)
    prep = prepare(seq, config)
    cals = _candidates(seq.truth_calibration, args.batch, seed=0)
    prof = cProfile.Profile()
    prof.runcall(run, seq, cals, config, prep)
    pstats.Stats(prof).sort_stats("tottime").print_stats(20)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=("accuracy", "outliers", "speed", "profile"))
    p.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--sequences", nargs="+", default=["sim540", "kitti540", "sim928", "kitti928"])
    p.add_argument("--batches", type=int, nargs="+", default=[1, 8, 32, 64, 128])
    p.add_argument("--repeats", type=int, default=3)
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
    else:
        profile(args, config)


if __name__ == "__main__":
    main()
