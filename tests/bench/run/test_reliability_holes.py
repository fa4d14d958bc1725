"""The reliability catalogue's weak items ("The front door…"): a log that is not this job's, Hydra's
own per-job set-up failing, a calibration window that is the held-out one, bounds of a frozen
variable, files written through symbolic links. Each test failed before its fix."""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest

from bench.problems import ProblemError
from bench.problems.analytic import AnalyticProblem
from bench.records import EVAL_LOG, JOB_FILE, RECORD, EvalLog, RecordError, read_eval_log, write_json_atomic
from bench.run.loop import Budget, RunError, run_job
from optimizers.random_search import RandomSearch


def _identity(evals=256, **extra):
    return {"problem": {"name": "sphere", "params": {}}, "optimizer": {"name": "random", "params": {"batch_size": 32}},
            "seed": 0, "budget": {"evals": evals, "seconds": None}, **extra}


class _OtherDrive(AnalyticProblem):
    """Another job's data: the optimiser asks the very same points (random search ignores f)."""

    @property
    def identity(self):
        return {**super().identity, "data_seed": 1}

    def evaluate(self, X):
        f, metrics = super().evaluate(X)
        return f + 1.0, metrics


def _run(job, problem=None, evals=256, identity=None):
    problem = problem or AnalyticProblem("sphere")
    return run_job(problem, lambda: RandomSearch(problem.space.lower, problem.space.upper, seed=0, batch_size=32),
                   Budget(evals=evals), job, identity or _identity(evals), progress=False)


def _snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and p.name != ".lock"}


# --- 1. every log line carries the job's key --------------------------------------------------------


def test_every_log_line_carries_the_jobs_key(tmp_path):
    record = _run(tmp_path / "job")
    assert {e["job_key"] for e in read_eval_log(tmp_path / "job")} == {record["job_key"]}


def _job_with_a_copied_log(tmp_path: Path) -> Path:
    """Job B, finished, whose evaluation log was then replaced by job A's (same asks, other data)."""
    _run(tmp_path / "a", problem=_OtherDrive("sphere"))
    b = tmp_path / "b"
    _run(b)
    shutil.copy(tmp_path / "a" / EVAL_LOG, b / EVAL_LOG)
    return b


def test_a_log_copied_from_another_job_is_not_resumed_into_a_wrong_record(tmp_path):
    # before: job B, resumed from job A's log (same asks, other data), finished "ok" with A's values
    b = _job_with_a_copied_log(tmp_path)
    (b / RECORD).unlink()
    before = _snapshot(b)
    with pytest.raises(RunError) as refused:
        _run(b)
    message = str(refused.value)
    assert str(b / EVAL_LOG) in message and str(b / JOB_FILE) in message and "another job folder" in message
    assert _snapshot(b) == before


def test_a_finished_record_beside_another_jobs_log_is_not_skipped(tmp_path):
    b = _job_with_a_copied_log(tmp_path)
    before = _snapshot(b)
    with pytest.raises(RunError, match="copied from another job folder"):
        _run(b)
    assert _snapshot(b) == before


def _strip_keys(log: Path) -> None:
    log.write_text("".join(json.dumps({k: v for k, v in json.loads(line).items() if k != "job_key"}) + "\n"
                           for line in log.read_text().splitlines()))


@pytest.mark.parametrize("finished", [False, True])
def test_a_keyless_log_copied_from_another_job_is_refused_on_resume_and_on_skip(tmp_path, finished):
    # before: an older harness's keyless log was trusted on job.json alone, so job A's log, copied into
    # job B's folder, replayed (or was skipped) into B's record with A's values
    b = _job_with_a_copied_log(tmp_path)
    _strip_keys(b / EVAL_LOG)
    if not finished:
        (b / RECORD).unlink()
    before = _snapshot(b)
    with pytest.raises(RunError) as refused:
        _run(b)
    message = str(refused.value)
    assert str(b / EVAL_LOG) in message and str(b / JOB_FILE) in message and "carry no job key" in message
    assert _snapshot(b) == before


@pytest.mark.parametrize("damage", ["missing", "empty", "shortened"])
def test_a_finished_record_without_its_whole_log_is_not_skipped(tmp_path, damage):
    # before: skipped without a word, and the report then read a log that is not the record's
    job = tmp_path / "job"
    _run(job)
    log = job / EVAL_LOG
    if damage == "missing":
        log.unlink()
    elif damage == "empty":
        log.write_bytes(b"")
    else:
        log.write_bytes(b"".join(log.read_bytes().splitlines(keepends=True)[:3]))
    before = _snapshot(job)
    with pytest.raises(RunError) as refused:
        _run(job)
    message = str(refused.value)
    assert str(job / RECORD) in message and str(log) in message and "records 8 batches (256 evals)" in message
    assert {"missing": "is missing", "empty": "is empty", "shortened": "holds 3 batches (96 evals)"}[damage] in message
    assert _snapshot(job) == before


def test_a_log_of_an_older_harness_without_keys_still_resumes_on_its_job_file(tmp_path):
    # the choice of bench/records.py's docstring: keyless lines are trusted on job.json, as before
    full = _run(tmp_path / "full")
    job = tmp_path / "old"
    _run(job)
    lines = [json.loads(line) for line in (job / EVAL_LOG).read_text().splitlines()[:3]]
    (job / EVAL_LOG).write_text("".join(json.dumps({k: v for k, v in e.items() if k != "job_key"}) + "\n"
                                        for e in lines))
    (job / RECORD).unlink()
    resumed = _run(job)
    assert resumed["status"] == "ok" and resumed["best_f"] == full["best_f"] and resumed["n_evals"] == 256
    keys = [e.get("job_key") for e in read_eval_log(job)]
    assert keys[:3] == [None] * 3 and set(keys[3:]) == {full["job_key"]}
    assert _run(job)["job_key"] == full["job_key"]  # and is skipped once finished
    # but a keyless line after keyed ones is not an old log: refused
    mixed = (job / EVAL_LOG).read_text().splitlines(keepends=True)
    (job / EVAL_LOG).write_text("".join(mixed[3:5] + mixed[:1]))
    (job / RECORD).unlink()
    with pytest.raises(RunError, match="batch 2 was written by a line without a job key after keyed ones"):
        _run(job)


# --- 2. Hydra's own per-job set-up --------------------------------------------------------------------


def test_hydra_failing_to_set_up_one_job_fails_that_job_and_the_sweep_reaches_its_summary(tmp_path, capsys,
                                                                                             monkeypatch):
    # before: a traceback, seed2 never ran, no "Jobs:" line. A read-only job folder cannot be made here:
    # the tests run as root, which ignores permission bits, and a job folder that is a file is refused by
    # the preflight (exit 2) before Hydra runs. So Hydra's own writer of .hydra/*.yaml fails in-process,
    # for one job, as a full disk or a read-only folder makes it fail.
    import logging

    import hydra.core.utils

    from bench.__main__ import main

    handlers, level = logging.root.handlers[:], logging.root.level  # Hydra's job logging, undone below
    monkeypatch.setattr(logging.root, "handlers", handlers)
    monkeypatch.setattr(logging.root, "level", level)

    real = hydra.core.utils._save_config

    def full_disk(cfg, filename, output_dir):
        if "i1" in Path(str(output_dir)).parts:
            raise OSError(errno.ENOSPC, "No space left on device", str(output_dir / filename))
        return real(cfg, filename, output_dir)

    monkeypatch.setattr(hydra.core.utils, "_save_config", full_disk)
    sweep = tmp_path / "s"
    with pytest.raises(SystemExit) as exit_info:
        main(["problem=sphere", "optimizer=random", "instance=range(3)", "budget.evals=16", "report=false",
              "progress=false", f"hydra.sweep.dir={sweep}"])
    out = capsys.readouterr()
    assert exit_info.value.code == 1
    # the sweep's summary, then where its records are (bench/run/callbacks.py)
    assert "Jobs: 3 in all, 2 ok, 1 failed (exit code 1)" in out.out.strip().splitlines(), out.out + out.err[-3000:]
    assert "failed: job 2/3 sphere/random/i1: Hydra could not set up the job folder" in out.out
    assert "Traceback" not in out.out + out.err
    records = {s: json.loads((sweep / "sphere" / "random" / f"i{s}" / RECORD).read_text()) for s in range(3)}
    assert [records[s]["status"] for s in range(3)] == ["ok", "failed", "ok"]
    assert records[1]["error"]["type"] == "JobSetupError" and "No space left" in records[1]["error"]["message"]


# --- 3. a calibration window is never the held-out one -------------------------------------------------


@pytest.mark.parametrize("problem, params, message", [
    ("euroc", {"drives": [[0, 20]]}, r"drives\[0\] = \[0, 20\] s overlaps the held-out window holdout = \[0, 20\] s"),
    ("euroc", {"drives": [[20, 30], [15, 25]]}, r"drives\[1\] = \[15, 25\] s overlaps .* holdout = \[0, 20\] s"),
    ("kitti00", {"drives": ["clean_928m"]},
     r"drives\[0\] = clean_928m \(frames 3000-4077\) overlaps the held-out window holdout = clean_928m"),
    ("kitti00", {"drives": [[3500, 3600]], "holdout": "clean_928m"}, r"drives\[0\] = frames 3500-3600 overlaps"),
])
def test_a_calibration_window_overlapping_the_held_out_one_is_refused_before_any_data_is_read(tmp_path, problem,
                                                                                              params, message):
    from bench import problems

    with pytest.raises(ProblemError, match=message):
        problems.get(problem).preflight(data_dir=str(tmp_path / "no-data"), **params)


def test_the_default_windows_that_only_touch_are_apart_and_null_holdout_is_fine(shared_data):
    from bench.problems.euroc import Euroc
    from bench.problems.kitti00 import Kitti00

    Euroc.preflight(data_dir=str(shared_data))  # 20-30 s against 0-20 s: they touch at 20 s
    Euroc.preflight(data_dir=str(shared_data), drives=[[0, 20]], holdout=None)
    Kitti00.preflight(data_dir=str(shared_data), drives=["clean_928m"], holdout=None)


def test_a_synthetic_drive_with_the_held_out_seed_is_refused():
    # drives have seeds of their own, (data_seed, i); only drive 1000 would get the held-out seed
    from bench.problems.synthetic import Synthetic

    with pytest.raises(ProblemError, match=r"drives\[1000\] = 'paper_928m' is the held-out drive itself"):
        Synthetic.preflight(drives=["paper_540m"] * 1000 + ["paper_928m"], holdout="paper_928m")
    Synthetic.preflight(drives=["paper_928m"] * 3, holdout="paper_928m")  # same preset, other seeds: apart


def test_an_overlapping_window_is_exit_2_at_preflight(tmp_path, capsys):
    from bench.__main__ import main

    with pytest.raises(SystemExit) as exit_info:
        main(["problem=euroc", "optimizer=random", "problem.params.drives=[[0,20]]",
              f"problem.params.data_dir={tmp_path / 'no-data'}", f"hydra.sweep.dir={tmp_path / 's'}"])
    out = capsys.readouterr().err  # bad input: one message on stderr
    assert exit_info.value.code == 2 and "overlaps the held-out window holdout = [0, 20] s" in out
    assert len([line for line in out.splitlines() if line.startswith("error:")]) == 1
    assert not (tmp_path / "s").exists()


# --- 4. bounds of a fixed or tied variable -------------------------------------------------------------


@pytest.mark.parametrize("params, message", [
    ({"fixed": ["dz"], "bounds": {"dz": [-0.1, 0.1]}}, r"bounds.dz given, but dz is fixed"),
    ({"tie_focal": True, "bounds": {"fy": [700, 740]}}, r"bounds.fy given, but tie_focal makes fy equal fx"),
])
def test_bounds_of_a_fixed_or_tied_variable_are_refused(params, message):
    from bench.problems.synthetic import Synthetic

    with pytest.raises(ProblemError, match=message):
        Synthetic.preflight(space="local", **params)
    Synthetic.preflight(space="local", fixed=["dz"], tie_focal=True, bounds={"fx": [700, 740], "dy": [-0.1, 0.1]})


def test_bounds_of_a_fixed_variable_are_exit_2_naming_it(tmp_path, capsys):
    from bench.__main__ import main

    with pytest.raises(SystemExit) as exit_info:
        main(["problem=synthetic", "optimizer=random", "problem.params.fixed=[tz]", "problem.params.bounds={tz:[0,1]}",
              f"hydra.sweep.dir={tmp_path / 's'}"])
    assert exit_info.value.code == 2 and "bounds.tz given, but tz is fixed" in capsys.readouterr().err


# --- 5. never written through a symbolic link ----------------------------------------------------------


@pytest.mark.parametrize("name", [EVAL_LOG, RECORD, JOB_FILE])
def test_a_job_file_that_is_a_symbolic_link_is_refused_and_its_target_untouched(tmp_path, name):
    job = tmp_path / "sweep" / "job"
    _run(job, evals=64)
    (job / RECORD).unlink()  # a killed job, to be resumed
    outside = tmp_path / "outside.txt"
    outside.write_text("the user's file\n")
    (job / name).unlink(missing_ok=True)
    (job / name).symlink_to(outside)
    with pytest.raises(RunError, match=rf"{name} is a symbolic link \(to {outside}\)"):
        _run(job, evals=64)
    assert outside.read_text() == "the user's file\n" and (job / name).is_symlink()


def test_the_writers_never_follow_a_link(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep\n")
    job = tmp_path / "job"
    job.mkdir()
    for name in (EVAL_LOG, RECORD, ".lock"):
        (job / name).symlink_to(outside)
    log = EvalLog(job)
    with pytest.raises(RecordError, match="is a symbolic link"):
        log.append({"X": [[0.0]], "f": [0.0], "t_end_s": 0.0})
    with pytest.raises(RecordError, match="is a symbolic link"):
        write_json_atomic(job / RECORD, {"status": "ok"})
    from bench.records import FolderLock

    with pytest.raises(OSError, match="is a symbolic link"):
        FolderLock(job).acquire()
    assert outside.read_text() == "keep\n" and all((job / n).is_symlink() for n in (EVAL_LOG, RECORD, ".lock"))


@pytest.mark.parametrize("name", [".hydra/config.yaml", ".hydra", "__main__.log"])
def test_hydras_files_as_links_are_refused_before_anything_is_written(tmp_path, name):
    # before: Hydra wrote .hydra/*.yaml and the job's log through the link, outside the sweep
    from bench.run import hydra_guard
    from bench.run.log_checks import linked_file

    job = tmp_path / "sweep" / "sphere" / "random" / "seed0"
    (job / ".hydra").mkdir(parents=True)
    outside = tmp_path / "outside"
    outside.write_text("keep\n")
    if name == ".hydra":
        (job / ".hydra").rmdir()
    (job / name).symlink_to(outside)
    assert f"{job / name} is a symbolic link" in linked_file(job)
    from hydra import compose, initialize_config_module

    with initialize_config_module("bench.conf", version_base=None):
        config = compose("config", overrides=["problem=sphere", "optimizer=random", f"hydra.sweep.dir={tmp_path / 'sweep'}",
                                              "hydra.sweep.subdir=sphere/random/seed0"], return_hydra_config=True)
    with pytest.raises(hydra_guard.JobSetupError, match=rf"{name} is a symbolic link"):
        hydra_guard._refuse_links(config, "hydra.sweep.dir", "hydra.sweep.subdir")
    assert outside.read_text() == "keep\n"


def test_the_sweeps_outcome_list_is_never_written_or_read_through_a_link(tmp_path, caplog):
    from bench.run.callbacks import OUTCOMES, note_outcome, read_outcomes

    outside = tmp_path / "outside.jsonl"
    outside.write_text('{"num": 0, "label": "forged", "status": "ok", "message": "", "job_dir": null}\n')
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / OUTCOMES).symlink_to(outside)
    note_outcome(sweep, 1, "job 2/2", {"status": "ok", "job_dir": str(sweep)})
    assert read_outcomes(sweep) == []  # every job then counts as "did not report"
    assert outside.read_text().count("\n") == 1 and "is a symbolic link" in caplog.text


def test_a_linked_job_file_is_exit_2_at_preflight(tmp_path, capsys):
    from bench.run.preflight import ConfigError, check_job_dir

    job = tmp_path / "job"
    job.mkdir()
    (job / EVAL_LOG).symlink_to(tmp_path / "elsewhere.jsonl")
    with pytest.raises(ConfigError, match=rf"{EVAL_LOG} is a symbolic link"):
        check_job_dir(job, {"problem": {"name": "sphere"}})
    assert not os.path.exists(tmp_path / "elsewhere.jsonl")


@pytest.mark.slow
@pytest.mark.parametrize("launcher", [[], ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]])
def test_a_job_folder_hydra_cannot_set_up_fails_that_job_under_each_launcher(tmp_path, launcher):
    # without monkeypatching, in the launcher's own processes: a file where Hydra makes the job's .hydra/
    # folder (root writes into read-only folders, so a file in the way stands for them). The preflight
    # lets it pass: the job folder holds neither a log nor a record.
    import subprocess
    import sys

    sweep = tmp_path / "s"
    (sweep / "sphere" / "random" / "i1").mkdir(parents=True)
    (sweep / "sphere" / "random" / "i1" / ".hydra").write_text("")
    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}  # this checkout
    proc = subprocess.run([sys.executable, "-m", "bench", "problem=sphere", "optimizer=random", "instance=range(3)",
                           "budget.evals=16", "report=false", "progress=false", *launcher, f"hydra.sweep.dir={sweep}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Jobs: 3 in all, 2 ok, 1 failed (exit code 1)" in proc.stdout.strip().splitlines()
    assert "Traceback" not in proc.stdout + proc.stderr
    failed = json.loads((sweep / "sphere" / "random" / "i1" / RECORD).read_text())
    assert failed["status"] == "failed" and "File exists" in failed["error"]["message"]
    assert all(json.loads((sweep / "sphere" / "random" / f"i{s}" / RECORD).read_text())["status"] == "ok"
               for s in (0, 2))


def test_a_linked_hydra_file_is_exit_2_at_preflight(tmp_path):
    from bench.run.preflight import ConfigError, check_job_dir

    job = tmp_path / "job"
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").symlink_to(tmp_path / "elsewhere.yaml")
    with pytest.raises(ConfigError, match=r"overrides.yaml is a symbolic link"):
        check_job_dir(job, {"problem": {"name": "sphere"}})
    assert not os.path.exists(tmp_path / "elsewhere.yaml")
