"""hydra/launcher=bench_local (the packing launcher on submitit's local executor), its settings checked
before any work, and Hydra's own job set-up failing under a submitit launcher (bench/run/hydra_guard.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

FAST = ["problem=sphere", "optimizer=random", "budget.evals=32", "report=false", "progress=false"]


def bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def comparable(sweep: Path) -> dict:
    keys = ("status", "best_f", "best_x", "n_evals", "n_batches", "job_key")
    return {str(p.parent.relative_to(sweep)): {k: json.loads(p.read_text())[k] for k in keys}
            for p in sweep.rglob("record.json")}


def test_packed_local_jobs_keep_their_own_folders_and_equal_the_serial_run(tmp_path):
    packed = bench(*FAST, "instance=range(3)", "hydra/launcher=bench_local", "hydra.launcher.pack=2",
                   "hydra.launcher.timeout_min=5", f"hydra.sweep.dir={tmp_path / 'p'}", cwd=tmp_path)
    assert packed.returncode == 0, packed.stderr[-3000:]
    assert "Submitted 3 jobs in 2 array tasks (2 per task)" in packed.stdout + packed.stderr
    serial = bench(*FAST, "instance=range(3)", f"hydra.sweep.dir={tmp_path / 's'}", cwd=tmp_path)
    assert serial.returncode == 0
    assert comparable(tmp_path / "p") == comparable(tmp_path / "s") and len(comparable(tmp_path / "s")) == 3
    for seed in range(3):  # each job its own folder, identity and lock
        assert {".lock", "job.json", "evals.jsonl", "record.json"} <= {
            p.name for p in (tmp_path / "p" / "sphere" / "random" / f"i{seed}").iterdir()}


@pytest.mark.parametrize("setting, message", [
    ("hydra.launcher.pack=0", "hydra.launcher.pack must be an integer >= 1, got 0"),
    ("hydra.launcher.max_array_size=-3", "hydra.launcher.max_array_size must be an integer >= 1, got -3"),
    ("hydra.launcher.pakc=2", "hydra.launcher.pakc: not a setting of hydra/launcher=bench_local"),
    ("hydra.launcher.wait=false", "hydra.launcher.wait=false needs a cluster"),
])
def test_a_bad_launcher_setting_is_one_message_naming_it_and_exit_2_before_any_work(tmp_path, setting, message):
    proc = bench(*FAST, "instance=range(2)", "hydra/launcher=bench_local", setting, f"hydra.sweep.dir={tmp_path / 's'}",
                 cwd=tmp_path)
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and message in errors[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "s").exists()


def test_hydra_failing_to_set_up_a_job_under_submitit_fails_that_job_only(tmp_path):
    # Hydra's run_job makes <job>/.hydra/ before the job's code runs; a file in its place fails that set-up
    # in the submitit worker (preflight does not look at .hydra)
    sweep = tmp_path / "s"
    (sweep / "sphere" / "random" / "i1").mkdir(parents=True)
    (sweep / "sphere" / "random" / "i1" / ".hydra").write_text("in the way")
    proc = bench(*FAST, "instance=range(3)", "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=5",
                 f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "Jobs: 3 in all, 2 ok, 1 failed (exit code 1)" in proc.stdout
    assert "failed: job 2/3 sphere/random/i1: Hydra could not set up the job folder" in proc.stdout
    records = {s: json.loads((sweep / "sphere" / "random" / f"i{s}" / "record.json").read_text())
               for s in range(3)}
    assert [records[s]["status"] for s in range(3)] == ["ok", "failed", "ok"]
    assert records[1]["error"]["type"] == "JobSetupError"
