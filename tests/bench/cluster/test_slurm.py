"""Sweeps through a real SLURM cluster (started by ``conftest.slurm_cluster``), against serial runs."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.records import read_eval_log

pytestmark = pytest.mark.slow

SPHERE = ["problem=sphere", "optimizer=random", "budget.evals=64", "report=false", "progress=false"]
SLOW = ["problem=sphere", "problem.params.delay_s_per_batch=0.3", "optimizer=random", "budget.evals=320",
        "report=false", "progress=false"]  # 10 batches of 32: 3 s a job
ON_SLURM = ["hydra.launcher.timeout_min=5"]
# bench_slurm on this cluster: no cgroups, so a task under srun survives scancel (conftest.py)
NO_SRUN = "hydra.launcher.use_srun=false"


def bench(cluster, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, env=cluster.env, capture_output=True,
                          text=True, timeout=300)


def records(sweep: Path) -> dict[str, dict]:
    """The comparable part of every record under ``sweep`` (timings aside), by job folder."""
    keys = ("status", "best_f", "best_x", "best_metrics", "n_evals", "n_batches", "stop_reason", "job_key",
            "config_hash")
    return {str(p.parent.relative_to(sweep)): {k: json.loads(p.read_text())[k] for k in keys}
            for p in sweep.rglob("record.json")}


def logs(sweep: Path) -> dict[str, list]:
    return {str(p.parent.relative_to(sweep)): [(e["X"], e["f"]) for e in read_eval_log(p.parent)]
            for p in sweep.rglob("record.json")}


@pytest.fixture(scope="module")
def serial(tmp_path_factory, slurm_cluster):
    """The serial (basic launcher) runs the cluster sweeps are compared with."""
    root = tmp_path_factory.mktemp("serial")
    for name, args in (("fast", [*SPHERE, "instance=range(4)"]), ("slow", [*SLOW, "instance=range(3)"])):
        proc = bench(slurm_cluster, *args, f"hydra.sweep.dir={root / name}", cwd=root)
        assert proc.returncode == 0, proc.stderr[-2000:]
    return root


def test_a_submitit_slurm_sweep_equals_the_serial_run(slurm_cluster, serial, tmp_path):
    sweep = tmp_path / "s"
    proc = bench(slurm_cluster, *SPHERE, "instance=range(4)", "hydra/launcher=submitit_slurm", *ON_SLURM,
                 f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Jobs: 4 in all, 4 ok, 0 failed" in proc.stdout
    assert records(sweep) == records(serial / "fast") and len(records(sweep)) == 4
    assert logs(sweep) == logs(serial / "fast")


def test_packed_jobs_split_into_arrays_equal_the_serial_run(slurm_cluster, serial, tmp_path):
    sweep = tmp_path / "s"
    proc = bench(slurm_cluster, *SPHERE, "instance=range(4)", "hydra/launcher=bench_slurm", *ON_SLURM,
                 "hydra.launcher.pack=3", "hydra.launcher.max_array_size=1", f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    # 4 jobs, 3 a task: 2 tasks; at most 1 task an array: 2 arrays (SLURM jobs)
    line = next(x for x in (proc.stdout + proc.stderr).splitlines() if "Submitted 4 jobs in 2 array tasks (3 per task)" in x)
    assert len(line.rsplit("job(s) ", 1)[1].split(", ")) == 2
    assert len({p.parent for p in (sweep / ".submitit").rglob("*_log.out")}) == 2  # one log per task
    assert records(sweep) == records(serial / "fast")


def _wait_for(predicate, timeout: float = 120.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError("timed out")


def test_scancel_then_the_same_command_skips_finished_jobs_and_resumes_killed_ones(slurm_cluster, serial, tmp_path):
    sweep = tmp_path / "s"
    args = [*SLOW, "instance=range(3)", "hydra/launcher=bench_slurm", *ON_SLURM, NO_SRUN, f"hydra.sweep.dir={sweep}"]
    started = time.time()
    proc = bench(slurm_cluster, *args, "hydra.launcher.wait=false", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert time.time() - started < 60 and "Submitted: 3 jobs in 3 array tasks" in proc.stdout
    job_id = proc.stdout.split("SLURM job(s) ")[1].split(")")[0]
    # the node's 2 CPUs run seeds 0 and 1, then seed 2: cancel the array once seed 2 has logged 2 batches
    last = sweep / "sphere" / "random" / "i2"
    _wait_for(lambda: (last / "evals.jsonl").exists() and len(read_eval_log(last)) >= 2)
    assert slurm_cluster.run("scancel", job_id).returncode == 0
    slurm_cluster.idle()
    done = {p.parent.name: p.stat().st_mtime_ns for p in sweep.rglob("record.json")}
    assert sorted(done) == ["i0", "i1"]
    assert 2 <= len(read_eval_log(last)) < 10

    again = bench(slurm_cluster, *args, cwd=tmp_path)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-3000:]
    assert {p.parent.name: p.stat().st_mtime_ns for p in sweep.rglob("record.json") if p.parent.name in done} == done
    assert records(sweep) == records(serial / "slow") and logs(sweep) == logs(serial / "slow")


def test_two_array_tasks_on_one_job_folder_the_second_is_refused_and_nothing_is_lost(slurm_cluster, serial,
                                                                                      tmp_path):
    sweep = tmp_path / "s"
    # instance=1,1: two jobs, one folder; the node's 2 CPUs run both tasks at once
    proc = bench(slurm_cluster, *SLOW, "instance=1,1", "hydra/launcher=bench_slurm", *ON_SLURM,
                 f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Jobs: 2 in all, 1 ok, 1 failed (exit code 1)" in proc.stdout
    assert "refused: job" in proc.stdout and "is in use by pid" in proc.stdout
    job = "sphere/random/i1"
    assert records(sweep) == {job: records(serial / "slow")[job]}
    assert logs(sweep) == {job: logs(serial / "slow")[job]}


def refused(cluster, tmp_path: Path, setting: str) -> str:
    """The one error line of a small sweep the launcher ``setting`` makes refused: exit 2, nothing submitted."""
    cluster.idle()  # the jobs of earlier tests gone: the queue stays empty if nothing is submitted
    sweep = tmp_path / "s"
    proc = bench(cluster, *SPHERE, "instance=range(2)", "hydra/launcher=bench_slurm", setting,
                 f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-3000:]
    errors = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert not sweep.exists() and cluster.run("squeue", "-h").stdout.strip() == ""
    return errors[0]


@pytest.mark.parametrize("setting, named", [
    ("hydra.launcher.partition=nowhere", "partition=nowhere"),
    ("hydra.launcher.timeout_min=600", "timeout_min=600"),
    ("hydra.launcher.pack=0", "hydra.launcher.pack"),
    ("hydra.launcher.colour=red", "hydra.launcher.colour"),
])
def test_a_setting_the_cluster_refuses_is_one_message_exit_2_and_nothing_submitted(slurm_cluster, tmp_path,
                                                                                   setting, named):
    assert named in refused(slurm_cluster, tmp_path, setting)


def test_an_account_without_association_is_refused_before_submission_and_one_with_it_runs(
        slurm_accounting_cluster, tmp_path):
    cluster = slurm_accounting_cluster  # associations enforced: root may charge benchacct (and root) only
    error = refused(cluster, tmp_path, "hydra.launcher.account=nosuchaccount")
    assert "account=nosuchaccount" in error and "Invalid account" in error

    sweep = tmp_path / "ok"
    proc = bench(cluster, *SPHERE, "instance=range(2)", "hydra/launcher=bench_slurm", *ON_SLURM,
                 "hydra.launcher.account=benchacct", f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Jobs: 2 in all, 2 ok, 0 failed" in proc.stdout and len(records(sweep)) == 2
    # the sweep's jobs were charged to the account asked for (sacct answers: slurmdbd runs)
    line = next(x for x in (proc.stdout + proc.stderr).splitlines() if "SLURM/submitit job(s) " in x)
    job = line.rsplit("job(s) ", 1)[1]
    # slurmctld hands finished tasks to slurmdbd asynchronously: wait (bounded) until both are on the books
    deadline = time.monotonic() + 60
    while True:
        charged = cluster.run("sacct", "-X", "-n", "-P", "-o", "Account", "-j", job)
        if len(charged.stdout.split()) >= 2 or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert charged.returncode == 0 and charged.stdout.split() == ["benchacct"] * 2, charged.stdout + charged.stderr
