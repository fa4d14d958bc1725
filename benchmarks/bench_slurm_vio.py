"""A VIO sweep through the test SLURM cluster against the same sweep run serially: equal records, equal leaderboard.

    python benchmarks/bench_slurm_vio.py [--instances 50] [--optimizers random,cmaes,pso,tpe] [--evals 10] [--pack 10]

Issue 34's "a 200-job VIO sweep through the cluster gives the same leaderboard as the serial run":
`synthetic` (the default problem; drives shortened to --duration seconds so that 200 jobs fit in
minutes on 2 cores) x optimisers x instances, once with Hydra's basic launcher and once with
``hydra/launcher=bench_slurm`` (packed, not waiting), on the single-node cluster of
tests/bench/cluster/conftest.py (root, slurm-wlm and munge needed). Prints the wall seconds of each,
whether every record (best f and x, metrics, evaluations, job key; timings aside) and every
evaluation log are equal, and whether the two reports' leaderboards are equal but for their
wall-time columns.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_slurm_sweep import running_cluster  # the same test cluster, started the same way

#: what a record holds that does not depend on when or where it ran
RECORD_KEYS = ("status", "best_f", "best_x", "best_metrics", "n_evals", "n_batches", "stop_reason", "job_key",
               "config_hash")


def records(sweep: Path) -> dict[str, dict]:
    return {str(p.parent.relative_to(sweep)): {k: json.loads(p.read_text())[k] for k in RECORD_KEYS}
            for p in sweep.rglob("record.json")}


def logs(sweep: Path) -> dict[str, list]:
    from bench.records import read_eval_log

    return {str(p.parent.relative_to(sweep)): [(e["X"], e["f"]) for e in read_eval_log(p.parent)]
            for p in sweep.rglob("record.json")}


def leaderboard(sweep: Path, env: dict) -> pd.DataFrame:
    subprocess.run([sys.executable, "-m", "bench.report", str(sweep)], env=env, check=True, capture_output=True)
    board = pd.read_csv(sweep / "report" / "leaderboard.csv")
    return board.drop(columns=[c for c in board.columns if "seconds" in c or "wall" in c])  # timings differ


def run(argv: list[str], env: dict, cwd: Path) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bench", *argv], env=env, capture_output=True, text=True, cwd=cwd)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=50)
    parser.add_argument("--optimizers", default="random,cmaes,pso,tpe")
    parser.add_argument("--evals", type=int, default=10)
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of each simulated drive")
    parser.add_argument("--pack", type=int, default=10)
    args = parser.parse_args()
    argv = ["problem=synthetic", f"optimizer={args.optimizers}", f"instance=range({args.instances})",
            f"budget.evals={args.evals}", f"problem.params.sim={{duration_s: {args.duration}}}", "report=false",
            "progress=false"]
    n_jobs = args.instances * len(args.optimizers.split(","))
    with tempfile.TemporaryDirectory(prefix="bench-slurm-vio-") as tmp:
        tmp = Path(tmp)
        with running_cluster(tmp) as cluster:
            env = {**cluster.env, "PYTHONPATH": str(ROOT)}
            serial_s = run([*argv, f"hydra.sweep.dir={tmp / 'serial'}"], env, tmp)
            t0 = time.perf_counter()
            run([*argv, "hydra/launcher=bench_slurm", f"hydra.launcher.pack={args.pack}", "hydra.launcher.timeout_min=30",
                 "hydra.launcher.use_srun=false", "hydra.launcher.wait=false", f"hydra.sweep.dir={tmp / 'slurm'}"],
                env, tmp)
            cluster.idle(timeout=3600)
            slurm_s = time.perf_counter() - t0
            serial, slurm = records(tmp / "serial"), records(tmp / "slurm")
            same_logs = logs(tmp / "serial") == logs(tmp / "slurm")
            boards = leaderboard(tmp / "serial", env), leaderboard(tmp / "slurm", env)
    print(f"{n_jobs} jobs (synthetic, {args.duration:g} s drives, {args.optimizers} x {args.instances} instances, "
          f"{args.evals} evaluations): serial {serial_s:.0f} s, SLURM (pack {args.pack}) {slurm_s:.0f} s wall")
    print(f"records: {len(serial)} serial, {len(slurm)} on SLURM, {sum(r['status'] == 'ok' for r in slurm.values())} ok; "
          f"equal (timings aside): {serial == slurm}; evaluation logs equal: {same_logs}")
    print(f"leaderboards equal but for wall times: {boards[0].equals(boards[1])} ({len(boards[0])} rows, "
          f"{len(boards[0].columns)} columns compared)")


if __name__ == "__main__":
    main()
