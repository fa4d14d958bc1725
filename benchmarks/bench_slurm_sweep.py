"""A sweep of N sphere x random-search jobs through the test SLURM cluster: preflight, submission, overhead, files.

    python benchmarks/bench_slurm_sweep.py --jobs 1000 --pack 50 --evals 20

Starts the single-node cluster of tests/bench/cluster/conftest.py (root, slurm-wlm and munge needed),
submits with ``hydra/launcher=bench_slurm hydra.launcher.wait=false``, waits until every record is
written, and prints: the submitting command's wall seconds (preflight included), the preflight's own
CPU seconds, the sweep's wall seconds until the last record, the overhead per job (sweep wall / jobs
minus the mean evaluation seconds of a job, as issue 34 defines it) and the files per job.
"""

import argparse
import contextlib
import importlib.util
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def cluster_class():
    spec = importlib.util.spec_from_file_location("bench_cluster", ROOT / "tests" / "bench" / "cluster" / "conftest.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.Cluster


@contextlib.contextmanager
def running_cluster(tmp: Path):
    """The single-node cluster of tests/bench/cluster/conftest.py, started under ``tmp/cluster``, stopped after."""
    (tmp / "cluster").mkdir()
    cluster = cluster_class()(tmp / "cluster")
    cluster.start(socket.gethostname().split(".")[0])
    try:
        yield cluster
    finally:
        cluster.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=1000)
    parser.add_argument("--pack", type=int, default=50)
    parser.add_argument("--evals", type=int, default=20)
    parser.add_argument("--submit-only", action="store_true", help="cancel the jobs once submitted: time the submission")
    args = parser.parse_args()
    from bench.run.preflight import plan

    with tempfile.TemporaryDirectory(prefix="bench-slurm-sweep-") as tmp:
        tmp = Path(tmp)
        with running_cluster(tmp) as cluster:
            sweep = tmp / "s"
            argv = ["problem=sphere", "optimizer=random", f"instance=range({args.jobs})", f"budget.evals={args.evals}",
                    "report=false", "progress=false", f"hydra.sweep.dir={sweep}"]
            cpu0 = time.process_time()
            plan(argv)
            preflight_cpu = time.process_time() - cpu0
            env = {**cluster.env, "PYTHONPATH": str(ROOT)}
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "bench", *argv, "hydra/launcher=bench_slurm",
                                   f"hydra.launcher.pack={args.pack}", "hydra.launcher.timeout_min=30",
                                   "hydra.launcher.use_srun=false", "hydra.launcher.wait=false"],
                                  env=env, capture_output=True, text=True, cwd=tmp)
            submit_s = time.perf_counter() - t0
            if proc.returncode:
                raise SystemExit(proc.stderr[-3000:])
            if args.submit_only:
                cluster.run("scancel", "--user", os.environ.get("USER", "root"))
                cluster.idle()
                print(f"jobs {args.jobs} (pack {args.pack}): preflight CPU {preflight_cpu:.1f} s; submitting command "
                      f"(preflight + submission) {submit_s:.1f} s wall; {proc.stdout.strip().splitlines()[0]}")
                return
            cluster.idle(timeout=3600)
            records = [json.loads(p.read_text()) for p in sweep.rglob("record.json")]
            last = max(p.stat().st_mtime for p in sweep.rglob("record.json"))
            wall = last - (time.time() - (time.perf_counter() - t0))
            files = sum(len(f) for _, _, f in os.walk(sweep))
    n = len(records)
    eval_s = sum(r["eval_s"] for r in records) / max(n, 1)
    print(f"jobs {args.jobs} (pack {args.pack}, {args.evals} evals): {n} records, "
          f"{sum(r['status'] == 'ok' for r in records)} ok")
    print(f"preflight CPU {preflight_cpu:.1f} s; submitting command (preflight + submission) {submit_s:.1f} s wall")
    print(f"sweep wall {wall:.1f} s; {1000 * wall / n:.1f} ms per job; evaluations {1000 * eval_s:.2f} ms per job; "
          f"overhead {1000 * (wall / n - eval_s):.1f} ms per job ({os.cpu_count()} CPUs)")
    print(f"files {files} ({files / n:.1f} per job)")


if __name__ == "__main__":
    main()
