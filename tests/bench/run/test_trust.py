"""Records you can trust (issue 14), at the level of one job: identity, one writer, checked replay,
failures that stay in their job. Each test reproduces a defect of the harness before the fix."""

from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.problems.analytic import AnalyticProblem
from bench.records import JOB_FILE, EvalLog, read_eval_log, read_record
from bench.run import loop as run_module
from bench.run.identity import identity_differences
from bench.run.job import run_configured_job
from bench.run.loop import Budget, RunError, _replay, run_job
from optimizers.random_search import RandomSearch


def _identity(seed=0, evals=100, **extra):
    return {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {"batch_size": 32}},
            "seed": seed, "budget": {"evals": evals, "seconds": None}, **extra}


def _make(problem, seed=0, cls=RandomSearch):
    return lambda: cls(problem.space.lower, problem.space.upper, seed=seed, batch_size=32)


def _run(job, evals=100, seed=0, problem=None, identity=None, cls=RandomSearch, budget=None):
    problem = problem or AnalyticProblem("sphere")
    return run_job(problem, _make(problem, seed, cls), budget or Budget(evals=evals), job,
                   identity or _identity(seed, evals), progress=False)


def _kill_after(job: Path, n_batches: int, torn: bool = True) -> None:
    """Imitate a kill after ``n_batches`` logged batches, mid-way through writing the next line."""
    path = job / "evals.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:n_batches]) + (lines[n_batches][:25] if torn else ""))
    (job / "record.json").unlink()


def _snapshot(folder: Path) -> dict:
    """Content and mtime of every file but the lock file (which names its latest holder)."""
    return {p.relative_to(folder).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".lock"}


def test_every_log_sits_beside_the_jobs_identity(tmp_path):
    record = _run(tmp_path / "job")
    header = json.loads((tmp_path / "job" / JOB_FILE).read_text())
    assert header["identity"] == _identity()
    assert header["config_hash"] == record["config_hash"] and header["job_key"] == record["job_key"]
    assert header["data"] == AnalyticProblem("sphere").identity
    assert len(header["code"]["sources"]) == 16 and "git_commit" in header["code"]


def test_resume_with_a_smaller_budget_is_refused_and_nothing_changes(tmp_path):
    # defect 1: a job killed at 224 evals and resumed with budget.evals=100 recorded 224 evals, status ok
    job = tmp_path / "job"
    _run(job, evals=256)
    _kill_after(job, 7)
    before = _snapshot(job)
    with pytest.raises(RunError, match=r"its config differs: budget.evals: 256 -> 100"):
        _run(job, evals=100)
    assert _snapshot(job) == before  # not even the torn tail was cut


def test_resume_with_other_problem_data_is_refused(tmp_path):
    # defect 1: a job resumed with another data seed mixed evaluations of two drives into one record
    class OtherDrive(AnalyticProblem):
        @property
        def identity(self):
            return {**super().identity, "data_seed": 1}

    job = tmp_path / "job"
    _run(job, evals=256)
    _kill_after(job, 3)
    before = _snapshot(job)
    with pytest.raises(RunError, match=r"its data differ: data_seed: '<unset>' -> 1"):
        _run(job, evals=256, problem=OtherDrive("sphere"))
    assert _snapshot(job) == before


def test_a_finished_job_with_other_drives_is_refused_naming_the_drive_that_differs(tmp_path):
    # a drive simulated with other vector extensions (README: bit-exact on one machine) differs
    # only in its content hash: the refusal says which drive's, not only that the job keys differ
    def drives(hashes):
        class Drives(AnalyticProblem):
            @property
            def identity(self):
                return {**super().identity, "drives": [{"name": "sim", "content_hash": h} for h in hashes]}
        return Drives("sphere")

    job = tmp_path / "job"
    _run(job, evals=64, problem=drives(["aa", "bb"]))
    with pytest.raises(RunError, match=r"finished \(its data differ: drives\[1\]\.content_hash: 'bb' -> 'cc'\)"):
        _run(job, evals=64, problem=drives(["aa", "cc"]))
    assert identity_differences({"fixed": ["dy", "dz"]}, {"fixed": ["dz"]}) == "fixed: ['dy', 'dz'] -> ['dz']"


def test_resume_after_a_code_change_is_refused(tmp_path):
    job = tmp_path / "job"
    _run(job, evals=256)
    _kill_after(job, 3)
    header = json.loads((job / JOB_FILE).read_text())
    header["code"]["sources"] = "0" * 16
    (job / JOB_FILE).write_text(json.dumps(header))
    # a job made by other code (e.g. before the package move) says why, and how its report still builds
    with pytest.raises(RunError, match=r"the code that asks and scores points changed.*python -m bench\.report DIR"):
        _run(job, evals=256)


def test_a_log_without_identity_is_not_resumed(tmp_path):
    job = tmp_path / "job"
    _run(job, evals=256)
    _kill_after(job, 3)
    (job / JOB_FILE).unlink()
    with pytest.raises(RunError, match="an evaluation log without job.json"):
        _run(job, evals=256)


class _StopsAfterTwo(RandomSearch):
    @property
    def stop(self):
        return "converged: two batches told" if getattr(self, "_told", 0) >= 2 else None

    def _tell(self, X, f):
        self._told = getattr(self, "_told", 0) + 1


def test_replay_applies_the_optimizers_stop_to_each_batch(tmp_path):
    # defect 1: a psoga job resumed with a tighter stop rule recorded 600 evals where a genuine run stops at 380
    job = tmp_path / "job"
    _run(job, evals=256)
    _kill_after(job, 5)
    problem = AnalyticProblem("sphere")
    entries = read_eval_log(job)
    state = {"n_evals": 0, "n_batches": 0, "eval_s": 0.0, "best_f": np.inf, "best_x": None,
             "best_metrics": {}, "offset_s": 0.0}
    with pytest.raises(RunError, match=r"holds 5 batches \(160 evals\) but this job stops after 2 \(64 evals: "
                                       r"optimizer: converged"):
        _replay(_make(problem, cls=_StopsAfterTwo)(), entries, job / "evals.jsonl", Budget(evals=256), state)


def test_a_log_longer_than_the_budget_is_refused(tmp_path):
    job = tmp_path / "job"
    _run(job, evals=256)
    problem = AnalyticProblem("sphere")
    state = {"n_evals": 0, "n_batches": 0, "eval_s": 0.0, "best_f": np.inf, "best_x": None,
             "best_metrics": {}, "offset_s": 0.0}
    with pytest.raises(RunError, match=r"this job stops after 3 \(96 evals: budget_evals\)"):
        _replay(_make(problem)(), read_eval_log(job), job / "evals.jsonl", Budget(evals=96), state)
    state.update(n_evals=0, n_batches=0, offset_s=0.0)
    # a budget that ends inside a logged full batch: the genuine run would have trimmed it
    with pytest.raises(RunError, match=r"batch 2 holds 32 of the 32 points asked, which this job's budget"):
        _replay(_make(problem)(), read_eval_log(job), job / "evals.jsonl", Budget(evals=80), state)


def test_unchanged_resume_is_bit_identical_and_cuts_only_the_torn_tail(tmp_path):
    full = _run(tmp_path / "full", evals=256)
    job = tmp_path / "cut"
    _run(job, evals=256)
    _kill_after(job, 3)
    kept = (job / "evals.jsonl").read_bytes().rsplit(b"\n", 1)[0] + b"\n"
    resumed = _run(job, evals=256)
    for key in ("best_f", "best_x", "n_evals", "n_batches", "stop_reason", "status", "job_key"):
        assert resumed[key] == full[key]
    log = (job / "evals.jsonl").read_bytes()
    assert log.startswith(kept)  # the complete lines were not rewritten
    assert [e["f"] for e in read_eval_log(job)] == [e["f"] for e in read_eval_log(tmp_path / "full")]


def test_a_refused_replay_leaves_the_log_untouched(tmp_path):
    # defect 2: the replay rewrote evals.jsonl before validating anything, even when it then refused the job
    job = tmp_path / "job"
    _run(job, evals=256, seed=0)
    _kill_after(job, 3)
    before = _snapshot(job)
    header = json.loads((job / JOB_FILE).read_text())
    problem = AnalyticProblem("sphere")
    # same identity on disk, but an optimiser that asks other points (non-deterministic plugin)
    with pytest.raises(RunError, match="batch 0 differs from what the optimiser asks again"):
        run_job(problem, _make(problem, seed=5), Budget(evals=256), job, header["identity"], progress=False)
    assert _snapshot(job) == before


_HOLD_LOCK = """
import sys, time
from bench.records import FolderLock
lock = FolderLock(sys.argv[1]).acquire()
print("locked", flush=True)
time.sleep(60)
"""


def test_a_second_process_on_a_running_job_fails_fast_naming_the_holder(tmp_path):
    job = tmp_path / "job"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK, str(job)], stdout=subprocess.PIPE, text=True,
                              cwd=Path(__file__).resolve().parents[3])
    try:
        assert holder.stdout.readline().strip() == "locked"
        t0 = time.perf_counter()
        with pytest.raises(RunError, match=rf"in use by pid {holder.pid} on host "):
            _run(job)
        assert time.perf_counter() - t0 < 2.0
        assert not (job / "evals.jsonl").exists() and not (job / JOB_FILE).exists()
    finally:
        holder.kill()
        holder.wait()
    assert _run(job)["status"] == "ok"  # the lock dies with its holder


@pytest.mark.parametrize("content", ["{not json", "[]", "{}"])
def test_a_corrupt_record_fails_its_job_with_a_message_and_the_next_run_resumes(tmp_path, content):
    # defect 5: a corrupt record.json escaped as a traceback
    job = tmp_path / "job"
    full = _run(job, evals=96)
    (job / "record.json").write_text(content)
    failed = _run(job, evals=96)
    assert failed["status"] == "failed" and "record.json: corrupt record" in failed["error"]["message"]
    assert (job / "record.json.corrupt").read_text() == content
    again = _run(job, evals=96)
    assert again["status"] == "ok" and again["best_f"] == full["best_f"] and again["n_evals"] == 96


def test_on_a_full_disk_the_close_error_does_not_hide_the_jobs_failure(tmp_path, monkeypatch):
    calls = {"n": 0}
    real_append = EvalLog.append

    def append(self, entry):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_append(self, entry)

    def close(self):
        self._fh = None
        raise OSError(errno.ENOSPC, "No space left on device (flush on close)")

    monkeypatch.setattr(EvalLog, "append", append)
    monkeypatch.setattr(EvalLog, "close", close)
    record = _run(tmp_path / "job", evals=256)
    assert record["status"] == "failed" and record["error"]["type"] == "OSError"
    assert "No space left on device" in record["error"]["message"]
    assert "closing" in record["error"]["also"] and record["n_evals"] == 64


def test_an_unwritable_job_folder_is_reported_as_the_jobs_failure(tmp_path, monkeypatch):
    # defect 5: a read-only job folder aborted the rest of the sweep
    def refuse(path, payload):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(run_module, "write_json_atomic", refuse)
    cfg = {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {"batch_size": 8}},
           "seed": 0, "budget": {"evals": 16, "seconds": None}, "progress": False, "plugins": []}
    outcome = run_configured_job(cfg, tmp_path / "job")
    assert outcome["status"] == "failed" and outcome["error"]["type"] == "JobFolderError"
    assert "cannot write" in outcome["error"]["message"] and "Permission denied" in outcome["error"]["message"]


def test_a_job_that_cannot_run_is_an_outcome_not_an_exception(tmp_path):
    cfg = {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {"batch_size": 8}},
           "seed": 0, "budget": {"evals": 16, "seconds": None}, "progress": False, "plugins": []}
    assert run_configured_job(cfg, tmp_path / "job")["status"] == "ok"
    outcome = run_configured_job({**cfg, "budget": {"evals": 8, "seconds": None}}, tmp_path / "job")
    assert outcome["status"] == "refused" and "a different job" in outcome["error"]["message"]


def test_record_json_is_mode_0644(tmp_path):
    _run(tmp_path / "job")
    for name in ("record.json", JOB_FILE, "evals.jsonl"):
        assert stat.S_IMODE((tmp_path / "job" / name).stat().st_mode) & 0o777 == 0o644 & ~_umask(), name


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_boolean_budget_is_refused():
    # defect 6: budget.evals=true ran one evaluation
    with pytest.raises(RunError, match="budget.evals must be a positive integer or null, got True"):
        Budget(evals=True)
    with pytest.raises(RunError, match="budget.seconds must be a positive number or null, got False"):
        Budget(evals=None, seconds=False)


def test_provenance_names_numba_and_the_cpu_model(tmp_path):
    record = read_record(tmp_path / "job") or _run(tmp_path / "job")
    import numba

    assert record["versions"]["numba"] == numba.__version__
    assert record["machine"]["cpu_model"] and record["machine"]["cpu_model"] != "unknown"
    assert set(record["machine"]["cpu_features"]) == {"numpy", "openblas", "llvm"}


def test_progress_bar_shows_evaluations_best_f_and_is_redrawn_during_a_long_batch(tmp_path, capsys):
    slow = AnalyticProblem("sphere", delay_s_per_batch=1.5)
    problem = slow
    run_job(problem, _make(problem), Budget(evals=64), tmp_path / "job", _identity(evals=64), label="job 2/7 demo",
            progress_every_s=0.5)
    err = capsys.readouterr().err
    frames = [f for f in err.replace("\r", "\n").splitlines() if f.startswith("job 2/7 demo")]
    assert any("64/64" in f and "best f" in f for f in frames)
    # two batches of 1.5 s each, redrawn every 0.5 s: several frames, not only one per batch
    assert len(frames) >= 5, frames


def test_a_problem_that_fails_to_build_records_a_failure_without_blocking_a_later_run(tmp_path, monkeypatch):
    from bench.problems import ProblemError
    from bench.run import job as job_module

    cfg = {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {"batch_size": 8}},
           "seed": 0, "budget": {"evals": 16, "seconds": None}, "progress": False, "plugins": []}
    real = job_module.build_problem

    def broken(cfg):
        raise ProblemError("data folder vanished")

    monkeypatch.setattr(job_module, "build_problem", broken)
    failed = run_configured_job(cfg, tmp_path / "job")
    assert failed["status"] == "failed" and failed["error"]["message"] == "data folder vanished"
    monkeypatch.setattr(job_module, "build_problem", real)
    done = run_configured_job(cfg, tmp_path / "job")
    assert done["status"] == "ok" and done["n_evals"] == 16  # the failed record did not block the job
    monkeypatch.setattr(job_module, "build_problem", broken)
    before = (tmp_path / "job" / "record.json").read_bytes()
    refused = run_configured_job(cfg, tmp_path / "job")
    assert refused["status"] == "refused" and "finished record is left unchanged" in refused["error"]["message"]
    assert (tmp_path / "job" / "record.json").read_bytes() == before


def test_data_identity_with_nan_still_matches_itself(tmp_path):
    class NanMeta(AnalyticProblem):
        @property
        def identity(self):
            return {**super().identity, "meta": {"gap_s": float("nan")}}

    job = tmp_path / "job"
    _run(job, evals=256, problem=NanMeta("sphere"))
    _kill_after(job, 3)
    assert _run(job, evals=256, problem=NanMeta("sphere"))["n_evals"] == 256


class _SlowToAsk(RandomSearch):
    def _ask(self):
        time.sleep(0.3)
        return super()._ask()


def test_a_long_replay_says_how_far_it_got(tmp_path, capsys):
    job = tmp_path / "job"
    problem = AnalyticProblem("sphere")
    run_job(problem, _make(problem, cls=_SlowToAsk), Budget(evals=256), job, _identity(evals=256), progress=False)
    _kill_after(job, 6)
    capsys.readouterr()
    run_job(problem, _make(problem, cls=_SlowToAsk), Budget(evals=256), job, _identity(evals=256), progress=False,
            progress_every_s=0.5, label="job 1/1 slow")
    err = capsys.readouterr().err
    assert "job 1/1 slow: resuming: replaying 6 logged batches" in err
    assert "job 1/1 slow: replayed " in err  # 6 x 0.3 s: said at least once while replaying


_WATCH = """
import os, time
from bench.run.job import exit_with_the_sweep, _watching
exit_with_the_sweep()
time.sleep(1.5)
print("alive", _watching.is_set())
"""


@pytest.mark.parametrize("host, pid", [("another-node", "1"), ("here", "999999999")])
def test_a_job_elsewhere_than_under_the_sweep_never_watches_it(host, pid):
    # a SLURM job inherits BENCH_SWEEP_PID on another host: it must not take that pid for its dead parent
    import socket

    env = {**os.environ, "BENCH_SWEEP_PID": pid,
           "BENCH_SWEEP_HOST": socket.gethostname() if host == "here" else host}
    out = subprocess.run([sys.executable, "-c", _WATCH], env=env, capture_output=True, text=True, timeout=60,
                         cwd=Path(__file__).resolve().parents[3])
    assert out.returncode == 0 and out.stdout.strip() == "alive False", out.stderr
