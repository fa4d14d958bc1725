"""``python -m bench.status``: a sweep's jobs by state, read from its folder while it runs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bench.status import sweep_status

pytestmark = pytest.mark.slow

SLOW = ["problem=sphere", "problem.params.delay_s_per_batch=0.15", "optimizer=random", "instance=range(3)",
        "budget.evals=400", "report=false", "progress=false"]


def status_cli(folder, *extra):
    return subprocess.run([sys.executable, "-m", "bench.status", str(folder), *extra], capture_output=True,
                          text=True, timeout=60)


def test_status_of_a_running_then_killed_sweep(tmp_path):
    sweep = tmp_path / "s"
    proc = subprocess.Popen([sys.executable, "-m", "bench", *SLOW, f"hydra.sweep.dir={sweep}"], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        counts = {}
        while time.time() < deadline:  # the second job running: one finished, one not started
            if (sweep / ".jobs.txt").exists():
                counts = sweep_status(sweep).counts()
                if counts["running"] == 1 and counts["finished"] == 1:
                    break
            time.sleep(0.05)
        assert counts == {"finished": 1, "running": 1, "failed": 0, "refused": 0, "interrupted": 0,
                          "not started": 1}
        shown = status_cli(sweep)  # from another process, as from another shell
        assert shown.returncode == 0, shown.stderr
        assert "1 finished, 1 running, 0 failed, 0 refused, 0 interrupted, 1 not started" in shown.stdout
        assert "sphere/random/i1 (running)" in shown.stdout
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    status = sweep_status(sweep)  # the lock went with the process: the cut job is interrupted, not running
    assert status.jobs["interrupted"] == ["sphere/random/i1"] and status.jobs["not started"] == [
        "sphere/random/i2"]
    record = sweep / "sphere" / "random" / "i0" / "record.json"
    data = json.loads(record.read_text())
    record.write_text(json.dumps({**data, "status": "failed", "error": {"type": "X", "message": "deliberate"}}))
    shown = status_cli(sweep, "--json")
    listed = json.loads(shown.stdout)
    assert listed["jobs"]["failed"] == ["sphere/random/i0"] and listed["messages"] == {
        "sphere/random/i0": "X: deliberate"}


@pytest.mark.parametrize("make", ["missing", "file", "empty"])
def test_a_folder_that_is_not_a_sweep_is_one_message_and_exit_2(tmp_path, make):
    target = tmp_path / "x"
    if make == "file":
        target.write_text("")
    elif make == "empty":
        target.mkdir()
    proc = status_cli(target)
    assert proc.returncode == 2 and proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1 and str(target) in proc.stderr
