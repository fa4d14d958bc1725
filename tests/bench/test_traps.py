"""Newcomer traps at the front door: Ctrl-C says how to resume, a key added with ``+`` must exist, bad
input goes to stderr, and a sweep's last line names report.html."""

from __future__ import annotations

import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.__main__ import main
from bench.run.preflight import preflight_plan

ROOT = Path(__file__).resolve().parents[2]


def test_ctrl_c_ends_with_one_line_naming_the_folder_and_the_command_that_resumes_it(tmp_path):
    args = ["problem=sphere", "problem.params.delay_s_per_batch=0.2", "optimizer=random", "instance=range(2)",
            "budget.evals=400", "report=false"]
    # SIGINT as a terminal delivers it: a shell without job control (`cmd &`, nohup) starts its children with
    # SIGINT ignored, and Python then installs no KeyboardInterrupt handler
    proc = subprocess.Popen([sys.executable, "-m", "bench", *args], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 60
    while time.time() < deadline and not list((tmp_path / "runs").glob("*/sphere/random/i0/evals.jsonl")):
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err + out
    [sweep] = (tmp_path / "runs").iterdir()  # the default folder: runs/<time>_<pid>-<random>
    last = err.strip().splitlines()[-1]
    folder = f"runs/{sweep.name}"
    assert last.startswith(f"Interrupted: the sweep in {folder} resumes with: python -m bench ")
    command = shlex.split(last.split("resumes with: ", 1)[1])
    assert command == ["python", "-m", "bench", *args, f"hydra.sweep.dir={folder}"]
    assert not (sweep / "sphere" / "random" / "i0" / "record.json").exists()  # it was cut mid-job

    again = subprocess.run([sys.executable, *command[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "resum" in again.stderr and list((tmp_path / "runs").iterdir()) == [sweep]  # no new folder
    for seed in range(2):
        assert '"n_evals": 400' in (sweep / "sphere" / "random" / f"i{seed}" / "record.json").read_text()


def test_a_fixed_sweep_folder_is_resumed_by_the_same_command():
    from bench.__main__ import resume_hint
    from bench.run import callbacks

    callbacks.LAST_SWEEP.clear()
    assert resume_hint(["seed=0"]) == "Interrupted before the sweep started: nothing was run or written."
    callbacks.LAST_SWEEP["sweep_dir"] = Path("mine")
    assert resume_hint(["instance=range(3)", "hydra.sweep.dir=mine"], "/venv/bin/avio-bench") == \
        "Interrupted: the sweep in mine resumes with: avio-bench 'instance=range(3)' hydra.sweep.dir=mine"
    callbacks.LAST_SWEEP.clear()
    callbacks.LAST_SWEEP["run_dir"] = Path("/r/one")
    assert resume_hint(["hydra.mode=RUN"]) == \
        "Interrupted: the job in /r/one resumes with: python -m bench hydra.mode=RUN hydra.run.dir=/r/one"
    callbacks.LAST_SWEEP.clear()


@pytest.mark.parametrize("override, key, nearest", [
    ("+objective=foo", "objective", "problem.params.objective"),
    ("objective=foo", "objective", "problem.params.objective"),  # Hydra itself would suggest +objective=foo
    ("++optimiser=pso", "optimiser", "optimizer"),
    ("+evals=100", "evals", "budget.evals"),
    ("+pop_size=8", "pop_size", "optimizer.params.pop_size"),
    ("+budgets.evals=100", "budgets", "budget.evals"),
])
def test_a_key_the_config_does_not_have_is_refused_naming_the_nearest(tmp_path, capsys, override, key, nearest):
    with pytest.raises(SystemExit) as exit_info:
        main(["problem=sphere", "optimizer=random", override, f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    assert exit_info.value.code == 2
    out = capsys.readouterr()
    assert out.out == "" and len(out.err.strip().splitlines()) == 1
    assert out.err.startswith(f"error: {override}: the config has no key {key!r}")
    assert f"did you mean {nearest}?" in out.err and "Top-level keys: budget, filter_block, instance, log_metrics, optimizer" in out.err
    assert not (tmp_path / "sweep").exists()


def test_keys_hydra_adds_with_plus_still_work(tmp_path, capsys):
    sweep = f"hydra.sweep.dir={tmp_path / 'sweep'}"
    base = ["problem=sphere", "optimizer=random", "instance=0", sweep]
    assert preflight_plan([*base, "hydra/launcher=joblib"])[0] == 0  # a Hydra config group
    assert preflight_plan([*base, "+hydra.job.env_set.X=1"])[0] == 0  # a Hydra key
    # a group of a plugin's search path, added with +
    (tmp_path / "conf" / "extra").mkdir(parents=True)
    (tmp_path / "conf" / "extra" / "thing.yaml").write_text("level: 3\n")
    assert preflight_plan([*base, "+extra=thing", f"hydra.searchpath=[file://{tmp_path / 'conf'}]"])[0] == 0
    # a key under a known section passes to the job's own checks, as before
    assert preflight_plan([*base, "+optimizer.params.speed=3"])[0] == 2
    assert "cannot be built as RandomSearch" in capsys.readouterr().err


BAD_INPUT = [
    (["bench", "optimizer=nope"], "Could not find 'optimizer/nope'"),
    (["bench", "+objective=foo"], "the config has no key 'objective'"),
    (["bench", "--nope"], "unrecognized arguments"),
    (["bench.report", "nowhere"], "bench.report: error: nowhere"),
    (["bench.report"], "the following arguments are required: dirs"),
    (["bench.report", "nowhere", "--alpha", "2"], "error"),
    (["bench.export", "nowhere", "--format", "tum"], "bench.export: error: nowhere"),
    (["bench.export", "nowhere", "--format", "csv"], "invalid choice: 'csv'"),
    (["bench.report.paper", "nowhere", "--out", "out"], "bench.report.paper: error: nowhere"),
    (["bench.report.paper", "nowhere", "--out", "out", "--profile-points", "1"], "--profile-points must be at least 2"),
]


@pytest.mark.parametrize("args, message", BAD_INPUT, ids=[" ".join(a) for a, _ in BAD_INPUT])
def test_every_entry_point_writes_bad_input_to_stderr_and_nothing_to_stdout(tmp_path, args, message):
    proc = subprocess.run([sys.executable, "-m", *args], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert message in proc.stderr and proc.stdout == ""
    assert "Traceback" not in proc.stderr


def test_a_sweeps_last_line_names_report_html(tmp_path):
    out = tmp_path / "s"
    proc = subprocess.run([sys.executable, "-m", "bench", "problem=sphere", "optimizer=random", "instance=0",
                           "budget.evals=32", f"hydra.sweep.dir={out}"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == f"Report:      {out / 'report' / 'report.html'}" and (out / "report" / "report.html").is_file()
    assert "Jobs: 1 in all, 1 ok, 0 failed" in lines
