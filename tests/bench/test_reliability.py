"""Scale and reliability: kill and resume, parallel launchers, failures inside a sweep."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from bench.records import read_eval_log

pytestmark = pytest.mark.slow

FAST = ["problem=sphere", "budget.evals=96"]


def bench(*args: str, cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300, **kwargs)


def _comparable(record: dict) -> dict:
    keys = ("status", "best_f", "best_x", "best_metrics", "n_evals", "n_batches", "stop_reason", "job_key")
    return {k: record[k] for k in keys}


def test_a_killed_job_resumes_from_its_log_to_the_identical_record(tmp_path):
    args = ["problem=sphere", "problem.params.delay_s_per_batch=0.05", "optimizer=random", "seed=0",
            "budget.evals=960"]
    job = tmp_path / "cut" / "sphere" / "random" / "seed0"
    proc = subprocess.Popen([sys.executable, "-m", "bench", *args, f"hydra.sweep.dir={tmp_path / 'cut'}"],
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and len(read_eval_log(job)) < 5:
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    n_logged = len(read_eval_log(job))
    assert 5 <= n_logged < 30 and not (job / "record.json").exists()

    assert bench(*args, f"hydra.sweep.dir={tmp_path / 'cut'}", cwd=tmp_path).returncode == 0
    assert bench(*args, f"hydra.sweep.dir={tmp_path / 'full'}", cwd=tmp_path).returncode == 0
    resumed = json.loads((job / "record.json").read_text())
    full = json.loads((tmp_path / "full" / "sphere" / "random" / "seed0" / "record.json").read_text())
    assert _comparable(resumed) == _comparable(full)
    assert [e["f"] for e in read_eval_log(job)] == [
        e["f"] for e in read_eval_log(tmp_path / "full" / "sphere" / "random" / "seed0")]


def test_rerunning_a_finished_sweep_skips_its_jobs(tmp_path):
    args = [*FAST, "optimizer=random", "seed=range(2)", f"hydra.sweep.dir={tmp_path / 's'}"]
    assert bench(*args, cwd=tmp_path).returncode == 0
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "s").rglob("record.json")}
    again = bench(*args, cwd=tmp_path)
    assert again.returncode == 0 and "already finished" in again.stderr + again.stdout
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "s").rglob("record.json")} == before


_BOARD_KEYS = ["problem", "optimizer", "n_runs", "n_failed", "best_f_median", "best_f_iqr", "rank"]


def test_serial_and_joblib_parallel_sweeps_give_identical_leaderboards(tmp_path):
    common = [*FAST, "optimizer=random,one_plus_one", "seed=range(2)"]
    serial = bench(*common, f"hydra.sweep.dir={tmp_path / 'serial'}", cwd=tmp_path)
    parallel = bench(*common, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                     f"hydra.sweep.dir={tmp_path / 'parallel'}", cwd=tmp_path)
    assert serial.returncode == 0 and parallel.returncode == 0, parallel.stderr[-2000:]
    a = pd.read_csv(tmp_path / "serial" / "report" / "leaderboard.csv")
    b = pd.read_csv(tmp_path / "parallel" / "report" / "leaderboard.csv")
    keys = [k for k in _BOARD_KEYS if k in a.columns]
    pd.testing.assert_frame_equal(a[keys], b[keys])


def test_submitit_local_sweep_runs(tmp_path):
    proc = bench(*FAST, "optimizer=random", "seed=range(2)", "hydra/launcher=submitit_local",
                 "hydra.launcher.timeout_min=5", f"hydra.sweep.dir={tmp_path / 's'}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    records = [json.loads(p.read_text()) for p in (tmp_path / "s").rglob("record.json")]
    assert sorted(r["seed"] for r in records) == [0, 1] and all(r["status"] == "ok" for r in records)


FAILING_PLUGIN = '''
from optimizers.random_search import RandomSearch
from optimizers.registry import register

@register("failing")
class Failing(RandomSearch):
    def tell(self, X, f):
        raise RuntimeError("deliberate failure after the first batch")
'''


def test_a_failing_optimizer_fails_only_its_jobs_and_the_leaderboard_shows_it(tmp_path):
    (tmp_path / "failing_plugin.py").write_text(FAILING_PLUGIN)
    (tmp_path / "conf" / "optimizer").mkdir(parents=True)
    (tmp_path / "conf" / "optimizer" / "failing.yaml").write_text("name: failing\nparams:\n  batch_size: 8\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = bench(*FAST, "optimizer=failing,random", "seed=range(2)", "plugins=[failing_plugin]",
                 f"hydra.searchpath=[file://{tmp_path / 'conf'}]", f"hydra.sweep.dir={tmp_path / 's'}",
                 cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    failed = json.loads((tmp_path / "s" / "sphere" / "failing" / "seed1" / "record.json").read_text())
    assert failed["status"] == "failed" and "deliberate failure" in failed["error"]["message"]
    assert failed["n_evals"] == 8  # its evaluated batch is kept
    board = pd.read_csv(tmp_path / "s" / "report" / "leaderboard.csv").set_index("optimizer")
    assert board.loc["failing", "n_failed"] == 2 and board.loc["random", "n_failed"] == 0
    assert board.loc["random", "n_runs"] == 2


def test_two_sweeps_started_in_the_same_second_never_share_a_folder(tmp_path):
    cmd = [sys.executable, "-m", "bench", *FAST, "optimizer=random", "seed=0"]
    procs = [subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for _ in range(2)]
    assert [p.wait(timeout=300) for p in procs] == [0, 0]
    folders = sorted((tmp_path / "runs").iterdir())
    assert len(folders) == 2
    assert all((f / "sphere" / "random" / "seed0" / "record.json").exists() for f in folders)
